//! Alpha-tested and blended triangles (glTF `alphaMode` MASK and BLEND): which points of a
//! triangle ray queries hit. A point's coverage is the material's alpha factor times the
//! base colour texture's alpha at its texture coordinates (level 0, bilinear, the material's
//! texture transform applied; alpha alone is read, so the traversal, where this is inlined
//! at every primitive test, carries no colour decoding). MASK surfaces are hit where the coverage reaches the cutoff; BLEND
//! surfaces with probability equal to the coverage, decided by a hash of the ray and the
//! primitive (stochastic transparency, as pbrt-v4 treats alpha: the same ray always decides
//! the same way, so CPU and GPU agree, and averaging many paths blends). Closest-hit and
//! any-hit queries both skip what is not covered, so light passes through holes and shadows
//! have their shape. Spheres have no texture coordinates and are always opaque.
use crate::rng::pcg_hash;
use crate::shading::{transformed_uv, uv_at};
use crate::sync::at;
use crate::texture::{self, TextureInfo};
use crate::types::{
    Material, Object, VertexAttrs, ALPHA_MASK, ALPHA_OPAQUE, FEATURE_TEXTURES, INVALID, TEX_BASE_COLOR,
};
use spirv_std::glam::Vec3;

/// What coverage depends on: each primitive's object and material, the meshes' texture
/// coordinates and the textures (the scene's buffers of the same names).
#[derive(Copy, Clone)]
pub struct Coverage<'a> {
    pub objects: &'a [Object],
    pub prim_object: &'a [u32],
    pub materials: &'a [Material],
    pub attrs: &'a [VertexAttrs],
    pub textures: &'a [TextureInfo],
    pub texels: &'a [u32],
}

impl Coverage<'_> {
    /// No materials: every primitive opaque (queries over bare primitives).
    pub const NONE: Coverage<'static> = Coverage {
        objects: &[],
        prim_object: &[],
        materials: &[],
        attrs: &[],
        textures: &[],
        texels: &[],
    };
}

/// Whether the hit `(b1, b2)` of the ray `origin + t dir` on triangle `prim`, shown by
/// `object` ([`INVALID`]: its own, `prim_object`'s), counts: false where the object's
/// material leaves a hole there.
#[allow(clippy::too_many_arguments)]
pub fn covers(c: &Coverage, prim: u32, object: u32, b1: f32, b2: f32, origin: Vec3, dir: Vec3, features: u32) -> bool {
    if prim >= c.prim_object.len() as u32 {
        return true;
    }
    let object = if object == INVALID {
        *at(c.prim_object, prim)
    } else {
        object
    };
    let m = at(c.materials, at(c.objects, object).material);
    if m.alpha_mode == ALPHA_OPAQUE {
        return true;
    }
    let mut a = m.alpha;
    let slot = m.textures[TEX_BASE_COLOR];
    if features & FEATURE_TEXTURES != 0 && slot != 0 {
        let uv = transformed_uv(m, uv_at(c.objects, c.attrs, object, prim, b1, b2));
        a *= texture::alpha(at(c.textures, slot - 1), c.texels, uv);
    }
    if m.alpha_mode == ALPHA_MASK {
        a >= m.alpha_cutoff
    } else {
        a > blend_threshold(origin, dir, prim)
    }
}

/// A number in `[0, 1)` fixed by the ray and the primitive: a BLEND surface of coverage `a`
/// is hit where it is below `a`.
pub fn blend_threshold(origin: Vec3, dir: Vec3, prim: u32) -> f32 {
    let mut h = pcg_hash(prim);
    h = pcg_hash(h ^ origin.x.to_bits());
    h = pcg_hash(h ^ origin.y.to_bits());
    h = pcg_hash(h ^ origin.z.to_bits());
    h = pcg_hash(h ^ dir.x.to_bits());
    h = pcg_hash(h ^ dir.y.to_bits());
    h = pcg_hash(h ^ dir.z.to_bits());
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::ALPHA_BLEND;

    fn world(mode: u32, alpha: f32, cutoff: f32) -> ([Object; 1], [u32; 1], [Material; 1]) {
        let object = Object {
            attrs: INVALID,
            ..Default::default()
        };
        let material = Material {
            alpha_mode: mode,
            alpha,
            alpha_cutoff: cutoff,
            ..Default::default()
        };
        ([object], [0], [material])
    }

    fn covered(mode: u32, alpha: f32, cutoff: f32, origin: Vec3) -> bool {
        let (objects, prim_object, materials) = world(mode, alpha, cutoff);
        let c = Coverage {
            objects: &objects,
            prim_object: &prim_object,
            materials: &materials,
            ..Coverage::NONE
        };
        covers(&c, 0, INVALID, 0.25, 0.25, origin, Vec3::NEG_Z, FEATURE_TEXTURES)
    }

    #[test]
    fn mask_compares_the_factor_with_the_cutoff_and_opaque_ignores_both() {
        assert!(covered(ALPHA_MASK, 0.5, 0.5, Vec3::ZERO));
        assert!(!covered(ALPHA_MASK, 0.49, 0.5, Vec3::ZERO));
        assert!(covered(ALPHA_OPAQUE, 0.0, 0.5, Vec3::ZERO));
        // Without materials (bare primitives) everything is covered.
        let c = Coverage::NONE;
        assert!(covers(&c, 7, INVALID, 0.1, 0.1, Vec3::ZERO, Vec3::X, FEATURE_TEXTURES));
    }

    #[test]
    fn blend_hits_in_proportion_to_the_coverage_and_decides_each_ray_once() {
        let n = 20_000;
        for alpha in [0.0, 0.25, 0.7, 1.0] {
            let hits = (0..n)
                .filter(|&i| covered(ALPHA_BLEND, alpha, 0.0, Vec3::new(i as f32 * 1e-3, 0.5, 2.0)))
                .count();
            let rate = hits as f32 / n as f32;
            assert!((rate - alpha).abs() < 0.015, "coverage {alpha}: hit rate {rate}");
        }
        let o = Vec3::new(0.3, 0.1, 2.0);
        assert_eq!(covered(ALPHA_BLEND, 0.5, 0.0, o), covered(ALPHA_BLEND, 0.5, 0.0, o));
    }
}
