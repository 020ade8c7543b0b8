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
use crate::math::finite3;
use crate::math::sqrt;
use crate::sync::at;
use crate::traverse::{self, Scene};
use crate::types::{xyz, Hit, Object, VertexAttrs, FEATURE_SHADING_NORMALS, INVALID};
use spirv_std::glam::{Vec2, Vec3};

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
    /// The primitive's scale for `intersect::offset_origin`.
    pub scale: f32,
}

/// The surface at hit `h` of the ray `(origin, dir)` on primitive `h.prim` of object
/// `objects[prim_object[h.prim]]`, with vertex attributes from `attrs`.
pub fn surface_point(
    s: &Scene,
    objects: &[Object],
    prim_object: &[u32],
    attrs: &[VertexAttrs],
    origin: Vec3,
    dir: Vec3,
    h: &Hit,
) -> SurfacePoint {
    let (p, ng, scale) = traverse::surface(s, h.prim, origin, dir, h);
    let mut sp = SurfacePoint {
        p,
        ng,
        ns: ng,
        uv: Vec2::ZERO,
        scale,
    };
    if s.features & FEATURE_SHADING_NORMALS == 0 || !s.is_triangle(h.prim) {
        return sp;
    }
    let o = at(objects, *at(prim_object, h.prim));
    if o.attrs == INVALID {
        return sp;
    }
    let a = at(attrs, o.attrs + (h.prim - o.first_prim));
    let b = Vec3::new(1.0 - h.u - h.v, h.u, h.v);
    let n = xyz(a.normal_u[0]) * b.x + xyz(a.normal_u[1]) * b.y + xyz(a.normal_u[2]) * b.z;
    sp.uv = Vec2::new(
        a.normal_u[0][3] * b.x + a.normal_u[1][3] * b.y + a.normal_u[2][3] * b.z,
        a.v[0] * b.x + a.v[1] * b.y + a.v[2] * b.z,
    );
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
