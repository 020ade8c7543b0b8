//! What a path sees where it hits: the point, the geometric normal, the shading normal
//! interpolated from the mesh's vertex normals, and the texture coordinates; and the shading
//! frame a path scatters in.
//!
//! Shading normals and the geometric surface (pbrt-v4 section 9.1 and Falcor's
//! `adjustShadingNormal`, combined): an interpolated normal may face away from the viewer
//! or let a sampled direction pass below the geometric surface, which leaks light through
//! closed meshes and darkens silhouettes. Two rules keep every path on the geometric side it
//! belongs to:
//! 1. [`facing`] flips the shading normal to the side of the geometric normal that faces the
//!    incoming ray, then bends it toward the viewer until the viewer is at least
//!    [`MIN_COS_VIEW`] above it, so a BSDF never sees its viewer below the surface.
//! 2. A reflected direction (scattered or sampled toward a light) must leave on the
//!    geometric side the ray came from, a refracted one on the other; anything else is
//!    absorbed (`material::scatter`) or carries no light (`path`'s next-event estimation).
use crate::instance::Placed;
use crate::math::finite3;
use crate::math::sqrt;
use crate::sync::at;
use crate::texture::{self, TextureInfo};
use crate::traverse::{self, Scene};
use crate::types::{
    xyz, Hit, Material, Object, VertexAttrs, FEATURE_NORMAL_MAPS, FEATURE_SHADING_NORMALS, FEATURE_TEXTURES, INVALID,
    TEX_BASE_COLOR, TEX_EMISSIVE, TEX_METAL_ROUGH, TEX_NORMAL,
};
use spirv_std::glam::{Vec2, Vec3, Vec4};

/// Smallest cosine between the viewer and the bent shading normal.
pub const MIN_COS_VIEW: f32 = 1e-3;

/// A hit point and what shades it.
#[derive(Copy, Clone, Debug)]
pub struct SurfacePoint {
    pub p: Vec3,
    /// Unit geometric normal as the primitive faces (triangles: the counter-clockwise front;
    /// spheres: outward). Emitters emit on this side.
    pub ng: Vec3,
    /// Unit shading normal on `ng`'s side; `ng` where the mesh has no vertex normals.
    pub ns: Vec3,
    /// Texture coordinates (zero where the mesh has none).
    pub uv: Vec2,
    /// The triangle's texture level-of-detail constant in texture-coordinate units
    /// (`texture::triangle_lod_constant` with a 1x1 texture).
    pub lod_constant: f32,
    /// Direction of increasing `u` on the triangle (unnormalised; zero without coordinates):
    /// the tangent of normal maps.
    pub dpdu: Vec3,
    /// The primitive's scale for `intersect::offset_origin`.
    pub scale: f32,
}

/// The surface at hit `h` of the ray `(origin, dir)` on primitive `at.prim` as `at` places
/// it (object `objects[at.object]`), with vertex attributes from `attrs`.
pub fn surface_point(
    s: &Scene,
    objects: &[Object],
    attrs: &[VertexAttrs],
    at_: Placed,
    origin: Vec3,
    dir: Vec3,
    h: &Hit,
) -> SurfacePoint {
    let (p, ng, scale) = traverse::surface_at(s, objects, at_, origin, dir, h);
    let mut sp = SurfacePoint {
        p,
        ng,
        ns: ng,
        uv: Vec2::ZERO,
        lod_constant: 0.0,
        dpdu: Vec3::ZERO,
        scale,
    };
    if s.features & (FEATURE_SHADING_NORMALS | FEATURE_TEXTURES) == 0 || !s.is_triangle(at_.prim) {
        return sp;
    }
    let o = at(objects, at_.object);
    if o.attrs == INVALID {
        return sp;
    }
    let a = at(attrs, o.attrs + (at_.prim - o.first_prim));
    let b = Vec3::new(1.0 - h.u - h.v, h.u, h.v);
    if s.features & FEATURE_TEXTURES != 0 {
        let uv = |k: usize| Vec2::new(a.normal_u[k][3], a.v[k]);
        let (uv0, uv1, uv2) = (uv(0), uv(1), uv(2));
        sp.uv = uv0 * b.x + uv1 * b.y + uv2 * b.z;
        let t = traverse::triangle_at(s, objects, at_);
        let (p0, p1, p2) = (xyz(t.v0), xyz(t.v1), xyz(t.v2));
        sp.lod_constant = texture::triangle_lod_constant(uv0, uv1, uv2, p0, p1, p2, 1, 1);
        // dp/du from the edges: solve [dp1 dp2] = [dpdu dpdv] [duv1 duv2].
        let (e1, e2) = (p1 - p0, p2 - p0);
        let (d1, d2) = (uv1 - uv0, uv2 - uv0);
        let det = d1.x * d2.y - d2.x * d1.y;
        if det != 0.0 && det.is_finite() {
            sp.dpdu = (e1 * d2.y - e2 * d1.y) / det;
        }
    }
    if s.features & FEATURE_SHADING_NORMALS == 0 {
        return sp;
    }
    let n = xyz(a.normal_u[0]) * b.x + xyz(a.normal_u[1]) * b.y + xyz(a.normal_u[2]) * b.z;
    let world = Vec3::new(
        xyz(o.normal_rows[0]).dot(n),
        xyz(o.normal_rows[1]).dot(n),
        xyz(o.normal_rows[2]).dot(n),
    );
    let len2 = world.length_squared();
    // No normals at these vertices (zeros), or normals cancelling: the geometric one shades.
    if len2 > 0.0 && finite3(world) {
        let ns = world / sqrt(len2);
        sp.ns = if ns.dot(ng) < 0.0 { -ns } else { ns };
    }
    sp
}

/// Material `m` at surface point `sp` with its textures applied (glTF's metallic-roughness
/// texture semantics): the base colour texture multiplies the albedo, the metallic-roughness
/// texture's blue and green channels the metallic and roughness factors, the emissive
/// texture the emission; a normal map replaces `sp.ns` (tangent space: `dp/du` made
/// orthogonal to the shading normal, and the bitangent `ns x t`, as glTF's sample viewer
/// does for meshes without tangents). Levels of detail come from a ray cone `cone_width` wide
/// at the hit, arriving at unit direction `d` (`texture::ray_cone_lod`).
pub fn textured(
    m: &Material,
    sp: &mut SurfacePoint,
    d: Vec3,
    cone_width: f32,
    textures: &[TextureInfo],
    texels: &[u32],
    features: u32,
) -> Material {
    let mut out = *m;
    if features & FEATURE_TEXTURES == 0 {
        return out;
    }
    let uv = transformed_uv(m, sp.uv);
    let cos = d.dot(sp.ng);
    let slots = m.textures;
    let base = slots[TEX_BASE_COLOR];
    if base != 0 {
        let c = lookup(textures, texels, base, uv, sp.lod_constant, cone_width, cos);
        out.albedo = [m.albedo[0] * c.x, m.albedo[1] * c.y, m.albedo[2] * c.z, m.albedo[3]];
    }
    let metal_rough = slots[TEX_METAL_ROUGH];
    if metal_rough != 0 {
        let c = lookup(textures, texels, metal_rough, uv, sp.lod_constant, cone_width, cos);
        out.roughness = m.roughness * c.y;
        out.metallic = m.metallic * c.z;
    }
    let emissive = slots[TEX_EMISSIVE];
    if emissive != 0 {
        let c = lookup(textures, texels, emissive, uv, sp.lod_constant, cone_width, cos);
        out.emission = [
            m.emission[0] * c.x,
            m.emission[1] * c.y,
            m.emission[2] * c.z,
            m.emission[3],
        ];
    }
    let normal = slots[TEX_NORMAL];
    if features & FEATURE_NORMAL_MAPS != 0 && normal != 0 {
        let c = lookup(textures, texels, normal, uv, sp.lod_constant, cone_width, cos);
        sp.ns = mapped_normal(sp.ns, sp.ng, sp.dpdu, c, m.normal_scale);
    }
    out
}

/// `uv` through material `m`'s texture transform.
pub fn transformed_uv(m: &Material, uv: Vec2) -> Vec2 {
    let r = m.uv_delta;
    uv + Vec2::new(
        r[0][0] * uv.x + r[0][1] * uv.y + r[0][2],
        r[1][0] * uv.x + r[1][1] * uv.y + r[1][2],
    )
}

/// Texture `slot` (index + 1) at `uv`, its level of detail from the triangle's constant, the
/// texture's size and the ray cone.
fn lookup(
    textures: &[TextureInfo],
    texels: &[u32],
    slot: u32,
    uv: Vec2,
    lod_constant: f32,
    cone_width: f32,
    cos: f32,
) -> Vec4 {
    let info = at(textures, slot - 1);
    let lod = texture::ray_cone_lod(lod_constant + texture::resolution_lod(info), cone_width, cos);
    texture::sample(info, texels, uv, lod)
}

/// The shading normal a tangent-space normal map texel `c` gives to a surface of shading
/// normal `ns` (geometric `ng`, tangent `dpdu`); `ns` itself where the tangent is degenerate
/// or the mapped normal falls below the geometric surface.
fn mapped_normal(ns: Vec3, ng: Vec3, dpdu: Vec3, c: Vec4, scale: f32) -> Vec3 {
    let t = dpdu - ns * ns.dot(dpdu);
    let len2 = t.length_squared();
    if !(len2 > 0.0 && len2.is_finite()) {
        return ns;
    }
    let t = t / sqrt(len2);
    let bt = ns.cross(t);
    let n = t * ((2.0 * c.x - 1.0) * scale) + bt * ((2.0 * c.y - 1.0) * scale) + ns * (2.0 * c.z - 1.0);
    let n2 = n.length_squared();
    if n2 > 0.0 && finite3(n) && n.dot(ng) > 0.0 {
        n / sqrt(n2)
    } else {
        ns
    }
}

/// Texture coordinates of barycentric point `(b1, b2)` of triangle `prim` shown by `object`
/// (zero where its mesh has none).
pub fn uv_at(objects: &[Object], attrs: &[VertexAttrs], object: u32, prim: u32, b1: f32, b2: f32) -> Vec2 {
    let o = at(objects, object);
    if o.attrs == INVALID {
        return Vec2::ZERO;
    }
    let a = at(attrs, o.attrs + (prim - o.first_prim));
    let b0 = 1.0 - b1 - b2;
    Vec2::new(
        a.normal_u[0][3] * b0 + a.normal_u[1][3] * b1 + a.normal_u[2][3] * b2,
        a.v[0] * b0 + a.v[1] * b1 + a.v[2] * b2,
    )
}

/// Emitted radiance of material `m` at texture coordinates `uv`: its emissive texture (level
/// 0) times its emission, for next-event estimation's points on lights.
pub fn emission_at(m: &Material, uv: Vec2, textures: &[TextureInfo], texels: &[u32], features: u32) -> Vec3 {
    let e = xyz(m.emission);
    let slot = m.textures[TEX_EMISSIVE];
    if features & FEATURE_TEXTURES == 0 || slot == 0 {
        return e;
    }
    let c = texture::sample(at(textures, slot - 1), texels, transformed_uv(m, uv), 0.0);
    e * Vec3::new(c.x, c.y, c.z)
}

/// The shading frame of a path arriving along unit `d` at a surface with unit geometric
/// normal `ng` and unit shading normal `ns` on `ng`'s side: `(n, s)`, the geometric normal
/// on the side the path came from and the shading normal flipped with it and bent so the
/// viewer `-d` is at least [`MIN_COS_VIEW`] above it, or as high as above `n` (rule 1 of
/// the module's header).
pub fn facing(d: Vec3, ng: Vec3, ns: Vec3) -> (Vec3, Vec3) {
    let (n, s) = if d.dot(ng) < 0.0 { (ng, ns) } else { (-ng, -ns) };
    let wo = -d;
    let c = wo.dot(s);
    // Where the shading normal is the geometric one (or the viewer sees the shading normal
    // at least as high), nothing to bend.
    if c >= MIN_COS_VIEW.min(wo.dot(n)) {
        return (n, s);
    }
    // s + k wo has cosine c + k with the viewer before normalising; k > 0 pulls it up.
    let bent = s + (MIN_COS_VIEW - c) * wo;
    let len2 = bent.length_squared();
    if len2 > 0.0 {
        (n, bent / sqrt(len2))
    } else {
        (n, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn facing_flips_with_the_ray_and_bends_toward_the_viewer() {
        let ng = Vec3::Z;
        let ns = Vec3::new(0.6, 0.0, 0.8);
        // From above: unchanged.
        let d = Vec3::new(0.0, 0.0, -1.0);
        assert_eq!(facing(d, ng, ns), (ng, ns));
        // From below: both flip.
        assert_eq!(facing(-d, ng, ns), (-ng, -ns));
        // Without a shading normal of its own, a grazing viewer leaves it alone.
        let graze = Vec3::new(1.0, 0.0, -1e-5).normalize();
        assert_eq!(facing(graze, ng, ng), (ng, ng));
        // A grazing viewer behind the shading normal: bent until it is just above.
        let d = Vec3::new(1.0, 0.0, -0.05).normalize();
        let (n, s) = facing(d, ng, ns);
        assert_eq!(n, ng);
        assert!((s.length() - 1.0).abs() < 1e-5);
        let c = (-d).dot(s);
        assert!((MIN_COS_VIEW * 0.5..0.01).contains(&c), "cosine with the viewer {c}");
        assert!(s.dot(ng) > 0.0);
    }
}
