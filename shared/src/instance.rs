//! Instancing: a top-level BVH over instances, each a mesh's own BVH (the bottom level,
//! built once in the mesh's model space by the same builder) placed in the world by a 3x4
//! transform. The top level is built by the same builder too: an instance enters it as its
//! world box written as a degenerate triangle ([`box_triangle`]), whose box is that box, so
//! both levels keep the builder's exactness (GPU = CPU bit for bit).
//!
//! A query walks the top level with the world ray; at an instance it takes the ray to the
//! mesh's model space ([`Instance::ray_to_model`]: the same parameter `t` names the same
//! point, so distances compare across instances) and walks the mesh's BVH on the same stack
//! (`traverse::closest`). The watertight triangle test then runs on model-space triangles
//! and one model-space ray, so a closed mesh stays closed whatever its transform.
use crate::math::fma;
use crate::sync::{at, at_mut};
use crate::transform::row;
use crate::types::{Object, Triangle, INVALID};
use bytemuck::{Pod, Zeroable};
use spirv_std::glam::Vec3;

/// A primitive as shading meets it: the object that shows it, and whether the primitive is
/// stored in that object's model space (a mesh of an instance, taken to world space by the
/// object's transform where it is shaded) or already in world space (a flattened scene).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Placed {
    pub prim: u32,
    pub object: u32,
    pub model: bool,
}

impl Placed {
    /// Primitive `prim` of the world-space primitives: its object from `prim_object`.
    pub fn world(prim_object: &[u32], prim: u32) -> Placed {
        Placed {
            prim,
            object: *at(prim_object, prim),
            model: false,
        }
    }

    /// Primitive `prim` shown in its model space by `object`, or ([`INVALID`]) a world-space
    /// primitive (its object from `prim_object`).
    pub fn shown(prim_object: &[u32], object: u32, prim: u32) -> Placed {
        if object == INVALID {
            Placed::world(prim_object, prim)
        } else {
            Placed {
                prim,
                object,
                model: true,
            }
        }
    }

    /// Primitive `prim` hit through instance `instance` of `instances` ([`INVALID`]: not
    /// through an instance, a flattened scene).
    pub fn hit(instances: &[Instance], prim_object: &[u32], instance: u32, prim: u32) -> Placed {
        let object = if instance == INVALID {
            INVALID
        } else {
            at(instances, instance).object
        };
        Placed::shown(prim_object, object, prim)
    }
}

/// One instance of a mesh (96 bytes). Its bottom level is the mesh's BVH, nodes
/// `nodes..nodes + 2 n - 1` of the bottom-level node buffer (each mesh's tree numbered from
/// 0, as the builder leaves it), over the mesh's `n = n_tris + n_spheres` primitives: its
/// triangles are `tri0..tri0 + n_tris` of the triangle buffer (in model space), its spheres
/// `sphere0..` of the sphere buffer.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Instance {
    /// World to model space (3x4, row-major): the inverse of the object's transform.
    pub to_model: [[f32; 4]; 3],
    /// The mesh's box in model space (its BVH's root box).
    pub lo: [f32; 3],
    /// The object it shows: its transform to world (`Object::rows`, what [`instance_box`]
    /// reads), material and vertex attributes; [`INVALID`] for the world-space group of a
    /// mixed scene (world-space primitives of several objects, each primitive's object in
    /// `prim_object`, as in a flattened scene; placed by [`IDENTITY`]).
    pub object: u32,
    pub hi: [f32; 3],
    /// The mesh's first node in the bottom-level node buffer.
    pub nodes: u32,
    pub tri0: u32,
    pub n_tris: u32,
    pub sphere0: u32,
    pub n_spheres: u32,
}

const _: () = assert!(size_of::<Instance>() == 96);

/// What a walk through an instance keeps of it once the ray is in model space: where its
/// mesh's nodes and primitives are, and its object (six words, not the instance's 24: the
/// walk holds it in registers).
#[derive(Copy, Clone, Debug, Default)]
pub struct MeshRef {
    pub nodes: u32,
    pub tri0: u32,
    pub n_tris: u32,
    pub sphere0: u32,
    pub n_spheres: u32,
    pub object: u32,
}

impl MeshRef {
    /// Primitives of the mesh.
    pub fn prims(&self) -> u32 {
        self.n_tris + self.n_spheres
    }

    /// The scene's primitive id of the mesh's primitive `local` (triangles `0..n_tris` of
    /// the triangle buffer, then spheres: `n_tris_all + k` is sphere `k`).
    pub fn global(&self, local: u32, n_tris_all: u32) -> u32 {
        if local < self.n_tris {
            self.tri0 + local
        } else {
            n_tris_all + self.sphere0 + (local - self.n_tris)
        }
    }
}

impl Instance {
    /// Its mesh and object.
    pub fn mesh(&self) -> MeshRef {
        MeshRef {
            nodes: self.nodes,
            tri0: self.tri0,
            n_tris: self.n_tris,
            sphere0: self.sphere0,
            n_spheres: self.n_spheres,
            object: self.object,
        }
    }

    /// The world ray `origin + t dir` in model space, with the same `t` along it.
    pub fn ray_to_model(&self, origin: Vec3, dir: Vec3) -> (Vec3, Vec3) {
        let m = &self.to_model;
        let o = [origin.x, origin.y, origin.z, 1.0];
        let p = |r: [f32; 4]| row(r, o);
        let d = |r: [f32; 4]| fma(r[0], dir.x, fma(r[1], dir.y, r[2] * dir.z));
        (
            Vec3::new(p(m[0]), p(m[1]), p(m[2])),
            Vec3::new(d(m[0]), d(m[1]), d(m[2])),
        )
    }
}

/// `2^-21`: four units of roundoff, the relative margin [`world_box`] adds.
const MARGIN: f32 = 1.0 / 2_097_152.0;

/// A box that holds the model-space box `[lo, hi]` taken to world space by `rows` (3x4,
/// row-major): per axis the translation plus the smaller (larger) of each column's products
/// with the box's ends (Arvo 1990), widened by four units of roundoff of the terms' sum of
/// magnitudes, more than the rounding of the sums and of any world-space point of the box.
/// Plain products and sums (no `fma`), so every backend computes the same bits.
pub fn world_box(rows: &[[f32; 4]; 3], lo: Vec3, hi: Vec3) -> (Vec3, Vec3) {
    let axis = |r: [f32; 4]| {
        let (a, b, c) = (r[0] * lo.x, r[1] * lo.y, r[2] * lo.z);
        let (d, e, f) = (r[0] * hi.x, r[1] * hi.y, r[2] * hi.z);
        let min = r[3] + a.min(d) + b.min(e) + c.min(f);
        let max = r[3] + a.max(d) + b.max(e) + c.max(f);
        let size = r[3].abs() + a.abs().max(d.abs()) + b.abs().max(e.abs()) + c.abs().max(f.abs());
        let m = size * MARGIN;
        (min - m, max + m)
    };
    let (x, y, z) = (axis(rows[0]), axis(rows[1]), axis(rows[2]));
    (Vec3::new(x.0, y.0, z.0), Vec3::new(x.1, y.1, z.1))
}

/// The transform of an instance of no object (the world-space group of a mixed scene).
pub const IDENTITY: [[f32; 4]; 3] = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];

/// The top level's input for instance `i` of `n`: its mesh's box taken to world space by its
/// object's transform ([`world_box`]; an instance of no object, the world-space group, by
/// [`IDENTITY`]), as a [`box_triangle`] (the `instance_boxes` kernel; the CPU executor calls
/// it for every instance).
pub fn instance_box(i: u32, n: u32, instances: &[Instance], objects: &[Object], out: &mut [Triangle]) {
    if i < n {
        *at_mut(out, i) = world_triangle(i, instances, objects);
    }
}

/// Instance `i`'s world box as a [`box_triangle`] (what [`instance_box`] stores).
pub fn world_triangle(i: u32, instances: &[Instance], objects: &[Object]) -> Triangle {
    let inst = at(instances, i);
    let rows = if inst.object == INVALID {
        IDENTITY
    } else {
        at(objects, inst.object).rows
    };
    let (lo, hi) = world_box(&rows, Vec3::from(inst.lo), Vec3::from(inst.hi));
    box_triangle(lo, hi)
}

/// The box `[lo, hi]` as a degenerate triangle whose box is that box (what the builder
/// takes for an instance of the top level).
pub fn box_triangle(lo: Vec3, hi: Vec3) -> Triangle {
    let v = |p: Vec3| [p.x, p.y, p.z, 0.0];
    Triangle {
        v0: v(lo),
        v1: v(hi),
        v2: v(lo),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotation about z by 30 degrees, scaled by -2 in x (mirrored), moved to 1e5.
    fn rows() -> [[f32; 4]; 3] {
        let (s, c) = (0.5f32, 0.866_025_4f32);
        [[-2.0 * c, -s, 0.0, 1e5], [-2.0 * s, c, 0.0, -3.0], [0.0, 0.0, 1.0, 7.5]]
    }

    fn apply(rows: &[[f32; 4]; 3], p: Vec3) -> [f64; 3] {
        let r = |k: usize| {
            let q = rows[k];
            q[0] as f64 * p.x as f64 + q[1] as f64 * p.y as f64 + q[2] as f64 * p.z as f64 + q[3] as f64
        };
        [r(0), r(1), r(2)]
    }

    #[test]
    fn the_world_box_holds_every_corner_rounded_either_way() {
        let rows = rows();
        let (lo, hi) = (Vec3::new(-1.0, -0.25, 2.0), Vec3::new(3.0, 0.5, 2.5));
        let (wlo, whi) = world_box(&rows, lo, hi);
        let (mut elo, mut ehi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for k in 0..8 {
            let p = Vec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            let exact = apply(&rows, p);
            // The corner as the transform stage's fma chain rounds it.
            let f = |r: [f32; 4]| fma(r[0], p.x, fma(r[1], p.y, fma(r[2], p.z, r[3])));
            let rounded = [f(rows[0]), f(rows[1]), f(rows[2])];
            for a in 0..3 {
                elo[a] = elo[a].min(exact[a]);
                ehi[a] = ehi[a].max(exact[a]);
                assert!(
                    wlo[a] as f64 <= exact[a] && exact[a] <= whi[a] as f64,
                    "corner {k} axis {a}"
                );
                assert!(
                    wlo[a] <= rounded[a] && rounded[a] <= whi[a],
                    "rounded corner {k} axis {a}"
                );
            }
        }
        // Not loose: within a few ulps of the exact box (the ulp of 1e5 is 2^-7).
        for a in 0..3 {
            assert!(
                elo[a] - wlo[a] as f64 <= 0.1 && whi[a] as f64 - ehi[a] <= 0.1,
                "axis {a}: {wlo} {whi} {elo:?} {ehi:?}"
            );
        }
    }

    #[test]
    fn a_box_triangle_has_the_box() {
        let (lo, hi) = (Vec3::new(-1.0, 2.0, -3.0), Vec3::new(4.0, 5.0, 6.0));
        let t = box_triangle(lo, hi);
        assert_eq!(crate::types::prim_box(0, 1, &[t], &[]), (lo, hi));
    }

    #[test]
    fn a_ray_in_model_space_names_the_same_points() {
        let rows = rows();
        // The inverse of `rows`, in f64, rounded.
        let m = |r: usize, c: usize| rows[r][c] as f64;
        let det = m(0, 0) * (m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1)) - m(0, 1) * (m(1, 0) * m(2, 2) - m(1, 2) * m(2, 0))
            + m(0, 2) * (m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0));
        let cof = |r: usize, c: usize| {
            let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
            let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
            m(r0, c0) * m(r1, c1) - m(r0, c1) * m(r1, c0)
        };
        let mut inv = [[0f32; 4]; 3];
        for (r, row) in inv.iter_mut().enumerate() {
            let a = [cof(0, r) / det, cof(1, r) / det, cof(2, r) / det];
            let t = -(a[0] * m(0, 3) + a[1] * m(1, 3) + a[2] * m(2, 3));
            *row = [a[0] as f32, a[1] as f32, a[2] as f32, t as f32];
        }
        let inst = Instance {
            to_model: inv,
            ..Default::default()
        };
        let (o, d) = (Vec3::new(1e5 + 3.0, 1.0, 8.0), Vec3::new(-0.5, 0.25, -1.0));
        let (mo, md) = inst.ray_to_model(o, d);
        for t in [0.0f32, 0.5, 2.0] {
            let back = apply(&rows, mo + t * md);
            let world = o + t * d;
            for a in 0..3 {
                assert!(
                    (back[a] - world[a] as f64).abs() < 0.05,
                    "t {t} axis {a}: {back:?} {world}"
                );
            }
        }
    }
}
