//! The driver's acceleration structures as a second tracer (`--accel driver`): the path loop
//! of [`crate::path`] with its rays traced by `OpTraceRayKHR` through the Vulkan driver's
//! structures (on GPUs with ray-tracing cores, traversed in hardware) instead of the
//! project's BVH walk. Shading, sampling, random streams, next-event estimation and MIS are
//! the same code; only where a ray stops comes from the driver.
//!
//! The bottom-level structure holds two geometries: the world-space triangles (geometry 0,
//! straight from the triangle buffer the transform stage writes: 16-byte vertices, no
//! index buffer) and the spheres as boxes (geometry 1, [`sphere_box`]) that the sphere
//! intersection shader tests with [`crate::intersect::sphere`]. Hit group `g` serves
//! geometry `g` (shader-binding-table stride 1), and every ray uses miss shader 0.
//!
//! The hit a closest-hit shader returns is a [`Hit`] as the BVH walk's: `t`, the primitive
//! (triangles first, then spheres, one index space) and the barycentrics of `v1` and `v2`.
//! The driver's triangle test is its own, so hits agree with the BVH walk's up to ties and
//! the last bits of `t`; on CPUs (the tests' executor) this tracer does not exist.
use crate::alpha::{self, Coverage};
use crate::instance::Placed;
use crate::intersect;
use crate::path::{Found, Trace, World};
use crate::sync::at;
use crate::traverse::usable;
use crate::types::{xyz, Frame, Hit, Sphere, INVALID, VARIANT_SPLIT_PRODUCTS};
use spirv_std::glam::{Vec2, Vec3};
use spirv_std::ray_tracing::{AccelerationStructure, RayFlags};

/// Traces through the driver's top-level structure `accel`; `hit` is the ray payload the
/// hit and miss shaders write.
pub struct Driver<'a> {
    pub accel: &'a AccelerationStructure,
    pub hit: &'a mut Hit,
}

impl Trace for Driver<'_> {
    fn found(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> Found {
        // A NaN or infinite ray is undefined behaviour to the driver: the walk's answer.
        if !usable(origin, dir, t_max) {
            return Found::MISS;
        }
        // SAFETY: `accel` is the top-level structure the host bound; `hit` is a ray payload.
        unsafe {
            self.accel
                .trace_ray(RayFlags::NONE, 0xff, 0, 1, 0, origin, 0.0, dir, t_max, self.hit);
        }
        let hit = *self.hit;
        if hit.prim == INVALID {
            return Found::MISS;
        }
        Found {
            hit,
            at: Placed::hit(w.scene.instances, w.prim_object, INVALID, hit.prim),
        }
    }

    fn any(&mut self, _w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        if !usable(origin, dir, t_max) {
            return false;
        }
        // The first hit ends the ray and no closest-hit shader runs: the payload keeps
        // this mark unless the miss shader replaces it.
        self.hit.prim = 0;
        let flags = RayFlags::TERMINATE_ON_FIRST_HIT | RayFlags::SKIP_CLOSEST_HIT_SHADER;
        // SAFETY: as in `found`.
        unsafe {
            self.accel
                .trace_ray(flags, 0xff, 0, 1, 0, origin, 0.0, dir, t_max, self.hit);
        }
        self.hit.prim != INVALID
    }
}

/// The closest-hit shader of triangles: triangle `prim` (the driver's primitive index in
/// geometry 0) at distance `t`, barycentrics `bary` of `v1` and `v2`.
pub fn triangle_hit(prim: u32, t: f32, bary: Vec2) -> Hit {
    Hit {
        t,
        prim,
        u: bary.x,
        v: bary.y,
    }
}

/// The closest-hit shader of spheres: sphere `sphere` (geometry 1's primitive index) at
/// distance `t`, numbered after the frame's triangles.
pub fn sphere_hit(frame: &Frame, sphere: u32, t: f32) -> Hit {
    Hit {
        t,
        prim: frame.n_tris + sphere,
        u: 0.0,
        v: 0.0,
    }
}

/// The intersection shader of spheres: the distance at which the ray `origin + t dir`
/// enters (or from inside leaves) sphere `sphere` within `(0, t_max)`, or `INFINITY`: the
/// BVH walk's test, with its exact products split where the device's `fma` rounds twice.
pub fn sphere_t(spheres: &[Sphere], sphere: u32, origin: Vec3, dir: Vec3, t_max: f32, features: u32) -> f32 {
    let split = features & VARIANT_SPLIT_PRODUCTS != 0;
    intersect::sphere(origin, dir, at(spheres, sphere), t_max, split)
}

/// The any-hit shader of alpha-tested triangles: whether the hit `bary` on triangle `prim`
/// counts (see [`alpha::covers`]; the same ray's hash decides a blended surface).
pub fn covers(c: &Coverage, prim: u32, bary: Vec2, origin: Vec3, dir: Vec3, features: u32) -> bool {
    alpha::covers(c, prim, INVALID, bary.x, bary.y, origin, dir, features)
}

/// The box geometry 1 gives the driver for sphere `s` (`VkAabbPositionsKHR`: low corner,
/// then high): its centre +- its radius, widened by a relative 2^-20 so that rounding in
/// `c - r` and `c + r` cannot cut off a point the sphere test reports.
pub fn sphere_box(s: &Sphere) -> [f32; 6] {
    let c = xyz(s.center_radius);
    let r = s.center_radius[3].abs();
    let pad = Vec3::splat(r) + (c.abs() + Vec3::splat(r)) * (1.0 / 1_048_576.0);
    let (lo, hi) = (c - pad, c + pad);
    [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_boxes_hold_their_spheres() {
        for cr in [[0.0, 0.0, 0.0, 1.0], [1e5, -3.0, 7.5, 0.25], [-2.0, 1e-3, 4.0, 1e-4]] {
            let s = Sphere { center_radius: cr };
            let b = sphere_box(&s);
            for axis in 0..3 {
                assert!(b[axis] <= cr[axis] - cr[3], "{cr:?} axis {axis}: {b:?}");
                assert!(b[3 + axis] >= cr[axis] + cr[3], "{cr:?} axis {axis}: {b:?}");
            }
        }
    }

    #[test]
    fn spheres_are_numbered_after_triangles() {
        let f = Frame {
            n_tris: 12,
            ..Default::default()
        };
        assert_eq!(sphere_hit(&f, 2, 1.5).prim, 14);
        let h = triangle_hit(3, 0.5, Vec2::new(0.25, 0.5));
        assert_eq!((h.prim, h.u, h.v), (3, 0.25, 0.5));
    }
}
