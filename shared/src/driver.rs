//! The driver's acceleration structures as a second tracer (`--accel driver`): the path loop
//! of [`crate::path`] with its rays traced by `OpTraceRayKHR` through the Vulkan driver's
//! structures (on GPUs with ray-tracing cores, traversed in hardware) instead of the
//! project's BVH walk. Shading, sampling, random streams, next-event estimation and MIS are
//! the same code; only where a ray stops comes from the driver.
//!
//! Bottom levels hold one kind of primitive each: triangles (straight from a triangle
//! buffer: 16-byte vertices, no index buffer) or spheres as boxes ([`sphere_box`]) that the
//! sphere intersection shader tests with [`crate::intersect::sphere`]. A flattened scene has
//! one of each over the world-space primitives, placed by the identity, instance custom index
//! [`FLAT`]; an instanced scene one of each per mesh over its model-space primitives, placed
//! by each instance's transform, custom index the instance's number (its mesh's first
//! triangle and sphere come from `instances`). The top-level instance's shader-binding-table
//! offset picks the hit group (0 triangles, 1 spheres); every ray uses miss shader 0.
//!
//! The hit a closest-hit shader returns is a [`Payload`]: a [`Hit`] as the BVH walk's (`t`,
//! the scene's primitive: triangles first, then spheres, one index space; the barycentrics
//! of `v1` and `v2`) and the instance it was found through ([`INVALID`]: none).
//! The driver's triangle test is its own, so hits agree with the BVH walk's up to ties and
//! the last bits of `t`; on CPUs (the tests' executor) this tracer does not exist.
use crate::alpha::{self, Coverage};
use crate::instance::Instance;
use crate::instance::Placed;
use crate::intersect;
use crate::path::{Found, Trace, World};
use crate::sync::at;
use crate::traverse::usable;
use crate::types::{xyz, Frame, Hit, Sphere, INVALID, VARIANT_SPLIT_PRODUCTS};
use bytemuck::{Pod, Zeroable};
use spirv_std::glam::{Vec2, Vec3};
use spirv_std::ray_tracing::{AccelerationStructure, RayFlags};

/// The custom index of the instances of a flattened scene's bottom levels (24 bits set).
pub const FLAT: u32 = 0xff_ffff;

/// The ray payload: the hit, and the instance it was found through ([`INVALID`]: a
/// flattened scene's primitive, or the world-space group's through instance 0 of a mixed
/// scene, whose object is `prim_object`'s either way).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Payload {
    pub hit: Hit,
    pub instance: u32,
}

/// Traces through the driver's top-level structure `accel`; `payload` is the ray payload
/// the hit and miss shaders write.
pub struct Driver<'a> {
    pub accel: &'a AccelerationStructure,
    pub payload: &'a mut Payload,
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
                .trace_ray(RayFlags::NONE, 0xff, 0, 1, 0, origin, 0.0, dir, t_max, self.payload);
        }
        let p = *self.payload;
        if p.hit.prim == INVALID {
            return Found::MISS;
        }
        Found {
            hit: p.hit,
            at: Placed::hit(w.scene.instances, w.prim_object, p.instance, p.hit.prim),
        }
    }

    fn closest(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
        self.found(w, origin, dir, t_max).hit
    }

    fn any(&mut self, _w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        if !usable(origin, dir, t_max) {
            return false;
        }
        // The first hit ends the ray and no closest-hit shader runs: the payload keeps
        // this mark unless the miss shader replaces it.
        self.payload.hit.prim = 0;
        let flags = RayFlags::TERMINATE_ON_FIRST_HIT | RayFlags::SKIP_CLOSEST_HIT_SHADER;
        // SAFETY: as in `found`.
        unsafe {
            self.accel
                .trace_ray(flags, 0xff, 0, 1, 0, origin, 0.0, dir, t_max, self.payload);
        }
        self.payload.hit.prim != INVALID
    }
}

/// The scene's primitive and the instance of primitive `local` of a bottom level of
/// triangles (`sphere` false) or spheres, placed by a top-level instance of custom index
/// `custom` ([`FLAT`]: a flattened scene's world-space primitives; else the instance's number
/// in `instances`, its mesh's primitives counted from its `tri0` or `sphere0`).
pub fn primitive(instances: &[Instance], frame: &Frame, custom: u32, local: u32, sphere: bool) -> (u32, u32) {
    let (first, instance) = if custom == FLAT {
        (0, INVALID)
    } else {
        let inst = at(instances, custom);
        (if sphere { inst.sphere0 } else { inst.tri0 }, custom)
    };
    let prim = if sphere {
        frame.n_tris + first + local
    } else {
        first + local
    };
    (prim, instance)
}

/// The closest-hit shaders: primitive `local` of a bottom level of triangles or spheres
/// (see [`primitive`]) at distance `t`, barycentrics `bary` of `v1` and `v2` (triangles).
pub fn closest_hit(
    instances: &[Instance],
    frame: &Frame,
    custom: u32,
    local: u32,
    sphere: bool,
    t: f32,
    bary: Vec2,
) -> Payload {
    let (prim, instance) = primitive(instances, frame, custom, local, sphere);
    let (u, v) = if sphere { (0.0, 0.0) } else { (bary.x, bary.y) };
    Payload {
        hit: Hit { t, prim, u, v },
        instance,
    }
}

/// The intersection shader of spheres: the distance at which the ray `origin + t dir` (in
/// the bottom level's space: the instance's model space) enters (or from inside leaves)
/// sphere `local` of the level within `(0, t_max)`, or `INFINITY`: the BVH walk's test, with
/// its exact products split where the device's `fma` rounds twice.
#[allow(clippy::too_many_arguments)]
pub fn sphere_t(
    instances: &[Instance],
    frame: &Frame,
    spheres: &[Sphere],
    custom: u32,
    local: u32,
    origin: Vec3,
    dir: Vec3,
    t_max: f32,
    features: u32,
) -> f32 {
    let (prim, _) = primitive(instances, frame, custom, local, true);
    let split = features & VARIANT_SPLIT_PRODUCTS != 0;
    intersect::sphere(origin, dir, at(spheres, prim - frame.n_tris), t_max, split)
}

/// The any-hit shader of alpha-tested triangles: whether the hit `bary` on triangle `local`
/// of the level (see [`primitive`]) counts, shown by its instance's object (see
/// [`alpha::covers`]; the world ray's hash decides a blended surface).
#[allow(clippy::too_many_arguments)]
pub fn covers(
    c: &Coverage,
    instances: &[Instance],
    frame: &Frame,
    custom: u32,
    local: u32,
    bary: Vec2,
    origin: Vec3,
    dir: Vec3,
    features: u32,
) -> bool {
    let (prim, instance) = primitive(instances, frame, custom, local, false);
    let object = if instance == INVALID {
        INVALID
    } else {
        at(instances, instance).object
    };
    alpha::covers(c, prim, object, bary.x, bary.y, origin, dir, features)
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
    fn primitives_are_numbered_as_the_walk_numbers_them() {
        let f = Frame {
            n_tris: 12,
            ..Default::default()
        };
        assert_eq!(primitive(&[], &f, FLAT, 2, true), (14, INVALID));
        assert_eq!(primitive(&[], &f, FLAT, 3, false), (3, INVALID));
        let inst = Instance {
            tri0: 5,
            sphere0: 1,
            ..Default::default()
        };
        let instances = [Instance::default(), inst];
        assert_eq!(primitive(&instances, &f, 1, 2, false), (7, 1));
        assert_eq!(primitive(&instances, &f, 1, 0, true), (13, 1));
        let p = closest_hit(&instances, &f, 1, 3, false, 0.5, Vec2::new(0.25, 0.5));
        assert_eq!((p.hit.prim, p.hit.u, p.hit.v, p.instance), (8, 0.25, 0.5, 1));
    }
}
