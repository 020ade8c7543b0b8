//! Ray sets of the stability suite that more than one test file shoots: axis-aligned rays
//! with either sign of zero at meshes with flat boxes, non-finite rays and bad ranges, rays
//! at the edge of the float range (`stability.rs`, `driver.rs`).
use super::{cube, octahedron, Mesh, World};
use shared::glam::Vec3;
use shared::types::{Hit, Sphere, Triangle, INVALID};

const INF: f32 = f32::INFINITY;

/// Every direction with components in {-1, -0, +0, 1}, except the zero vectors.
pub fn signed_zero_directions() -> Vec<Vec3> {
    let c = [-1.0, -0.0, 0.0, 1.0f32];
    let mut out = Vec::new();
    for x in c {
        for y in c {
            for z in c {
                if x != 0.0 || y != 0.0 || z != 0.0 {
                    out.push(Vec3::new(x, y, z));
                }
            }
        }
    }
    out
}

/// A flat grid of `n * n` squares at height `z` over `[-1, 1]^2`: every leaf box is flat.
pub fn floor(n: i32, z: f32) -> Mesh {
    let mut verts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            verts.push(Vec3::new(
                2.0 * i as f32 / n as f32 - 1.0,
                2.0 * j as f32 / n as f32 - 1.0,
                z,
            ));
        }
    }
    let mut faces = Vec::new();
    let w = n as u32 + 1;
    for j in 0..n as u32 {
        for i in 0..n as u32 {
            let a = j * w + i;
            faces.extend([[a, a + 1, a + w + 1], [a, a + w + 1, a + w]]);
        }
    }
    Mesh { verts, faces }
}

/// Origin coordinates of the axis-aligned ray tests: on, between and beside the meshes'
/// vertices and edges.
pub const AXIS_RAY_COORDS: [f32; 8] = [-2.0, -1.0, -0.5, 0.0, 0.25, 0.5, 1.0, 2.0];

/// The closed and open meshes the axis-aligned rays are shot at.
pub fn axis_ray_meshes() -> [(&'static str, Vec<Triangle>); 3] {
    [
        ("cube", cube(4).triangles(Vec3::ZERO)),
        ("octahedron", octahedron(4).triangles(Vec3::ZERO)),
        ("floor", floor(4, 0.25).triangles(Vec3::ZERO)),
    ]
}

/// A cube of triangles, a sphere inside it and one beside it.
pub fn mixed_world() -> World {
    World::new(
        cube(2).triangles(Vec3::ZERO),
        vec![
            Sphere {
                center_radius: [0.0, 0.0, 0.0, 0.5],
            },
            Sphere {
                center_radius: [3.0, 0.0, 0.0, 1.0],
            },
        ],
    )
}

/// `v` with component `k` replaced by `x`.
pub fn with(v: Vec3, k: usize, x: f32) -> Vec3 {
    let mut v = v;
    v[k] = x;
    v
}

/// A hit must be a miss or lie in `(0, t_max)`, and name a primitive exactly when it is a hit.
pub fn sane(h: &Hit, n_prims: u32, t_max: f32) -> bool {
    if h.prim == INVALID {
        h.t == INF
    } else {
        h.prim < n_prims && h.t > 0.0 && h.t < t_max && h.u.is_finite() && h.v.is_finite()
    }
}

/// A ray that hits [`mixed_world`], and the bad ranges tried with it.
pub const GOOD_RAY: (Vec3, Vec3) = (Vec3::new(0.1, 0.2, -3.0), Vec3::new(0.01, 0.02, 1.0));
pub const BAD_T_MAX: [f32; 5] = [f32::NAN, -INF, -1.0, 0.0, -0.0];

/// [`GOOD_RAY`] with NaN or infinite components in its origin, direction or both, and zero
/// directions of either sign: every query must miss.
pub fn non_finite_rays() -> Vec<(Vec3, Vec3)> {
    let (o0, d0) = GOOD_RAY;
    let mut rays = Vec::new();
    for bad in [f32::NAN, INF, -INF] {
        for k in 0..3 {
            rays.push((with(o0, k, bad), d0));
            rays.push((o0, with(d0, k, bad)));
            rays.push((with(o0, k, bad), with(d0, (k + 1) % 3, bad)));
        }
        rays.push((Vec3::splat(bad), d0));
        rays.push((o0, Vec3::splat(bad)));
    }
    for zero in [Vec3::ZERO, -Vec3::ZERO, Vec3::new(0.0, -0.0, 0.0)] {
        rays.push((o0, zero));
    }
    rays
}

/// Finite rays at the edge of the range: tiny and huge directions, huge origins.
pub const EXTREME_RAYS: [(Vec3, Vec3); 5] = [
    (Vec3::new(0.1, 0.2, -3.0), Vec3::new(0.0, 0.0, 1e-40)),
    (Vec3::new(0.1, 0.2, -3.0), Vec3::new(1e-30, 1e-38, 1e-39)),
    (Vec3::new(0.1, 0.2, -3.0), Vec3::new(1e38, 3e38, f32::MAX)),
    (Vec3::new(-f32::MAX, 0.2, 0.1), Vec3::new(1.0, 0.0, 0.0)),
    (Vec3::new(1e30, 1e30, -1e30), Vec3::new(-1.0, -1.0, 1.0)),
];
