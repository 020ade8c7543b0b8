//! Helpers of the stability tests: primitives with the BVH the CPU executor builds; closed
//! meshes with shared vertices; random numbers from the kernels' own streams; units in the
//! last place; and a chi-square critical value.
#![allow(dead_code)]

use raytrace::bvh::MortonBits;
use shared::glam::Vec3;
use shared::rng::Rng;
use shared::traverse::Scene;
use shared::types::{Node, Sphere, Triangle, FEATURES_ALL};
use std::collections::HashMap;

/// Primitives and the 30-bit LBVH over them.
pub struct World {
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
    pub nodes: Vec<Node>,
}

impl World {
    /// The primitives with the 30-bit LBVH of the CPU executor (the kernels the GPU runs).
    pub fn new(tris: Vec<Triangle>, spheres: Vec<Sphere>) -> World {
        let nodes = raytrace::cpu::build(&tris, &spheres, MortonBits::B30).0.nodes;
        World { tris, spheres, nodes }
    }

    /// The scene traversed through the BVH.
    pub fn scene(&self) -> Scene<'_> {
        Scene {
            tris: &self.tris,
            spheres: &self.spheres,
            nodes: &self.nodes,
            n_tris: self.tris.len() as u32,
            n_prims: (self.tris.len() + self.spheres.len()) as u32,
            features: FEATURES_ALL,
        }
    }
}

/// A triangle mesh with shared vertices.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub verts: Vec<Vec3>,
    pub faces: Vec<[u32; 3]>,
}

impl Mesh {
    /// Triangles of the mesh moved by `offset` (each vertex once, so shared ones stay shared).
    pub fn triangles(&self, offset: Vec3) -> Vec<Triangle> {
        let v: Vec<[f32; 4]> = self.moved(offset).iter().map(|p| [p.x, p.y, p.z, 0.0]).collect();
        self.faces
            .iter()
            .map(|f| Triangle {
                v0: v[f[0] as usize],
                v1: v[f[1] as usize],
                v2: v[f[2] as usize],
            })
            .collect()
    }

    /// Vertices moved by `offset`, rounded to `f32` as the triangles' are.
    pub fn moved(&self, offset: Vec3) -> Vec<Vec3> {
        self.verts.iter().map(|&p| p + offset).collect()
    }

    /// Every undirected edge once.
    pub fn edges(&self) -> Vec<[u32; 2]> {
        let mut e: Vec<[u32; 2]> = self
            .faces
            .iter()
            .flat_map(|f| [[f[0], f[1]], [f[1], f[2]], [f[2], f[0]]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        e.sort_unstable();
        e.dedup();
        e
    }

    /// Whether every edge is shared by exactly two faces (a closed manifold surface).
    pub fn is_closed(&self) -> bool {
        let mut count: HashMap<[u32; 2], u32> = HashMap::new();
        for f in &self.faces {
            for [a, b] in [[f[0], f[1]], [f[1], f[2]], [f[2], f[0]]] {
                *count.entry([a.min(b), a.max(b)]).or_default() += 1;
            }
        }
        count.values().all(|&c| c == 2)
    }
}

/// Icosahedron subdivided `levels` times, vertices pushed onto the unit sphere.
pub fn icosphere(levels: u32) -> Mesh {
    let t = (1.0 + 5.0f32.sqrt()) / 2.0;
    let mut verts: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|&p| Vec3::from(p).normalize())
    .collect();
    let mut faces: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(faces.len() * 4);
        let mut midpoint = |a: u32, b: u32, verts: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                verts.push(((verts[a as usize] + verts[b as usize]) * 0.5).normalize());
                verts.len() as u32 - 1
            })
        };
        for [a, b, c] in faces {
            let ab = midpoint(a, b, &mut verts);
            let bc = midpoint(b, c, &mut verts);
            let ca = midpoint(c, a, &mut verts);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    Mesh { verts, faces }
}

/// Vertex indices of a mesh built on an integer lattice: each lattice point once.
#[derive(Default)]
struct Lattice {
    index: HashMap<[i32; 3], u32>,
    mesh: Mesh,
}

impl Lattice {
    fn vertex(&mut self, p: [i32; 3], scale: f32) -> u32 {
        let mesh = &mut self.mesh;
        *self.index.entry(p).or_insert_with(|| {
            mesh.verts
                .push(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) * scale);
            mesh.verts.len() as u32 - 1
        })
    }
}

/// Octahedron `|x| + |y| + |z| = 1` with every face cut into `n * n` coplanar triangles: many
/// edges between coplanar neighbours, and vertices on the axes.
pub fn octahedron(n: i32) -> Mesh {
    let mut l = Lattice::default();
    let s = 1.0 / n as f32;
    for sx in [-1, 1] {
        for sy in [-1, 1] {
            for sz in [-1, 1] {
                // Lattice point (i, j, k) with i + j + k = n on this face.
                let p = |i: i32, j: i32| [sx * i, sy * j, sz * (n - i - j)];
                let flip = sx * sy * sz < 0;
                let push = |l: &mut Lattice, a: [i32; 3], b: [i32; 3], c: [i32; 3]| {
                    let (a, b, c) = (l.vertex(a, s), l.vertex(b, s), l.vertex(c, s));
                    l.mesh.faces.push(if flip { [a, c, b] } else { [a, b, c] });
                };
                for i in 0..n {
                    for j in 0..n - i {
                        push(&mut l, p(i, j), p(i + 1, j), p(i, j + 1));
                        if i + j + 1 < n {
                            push(&mut l, p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                        }
                    }
                }
            }
        }
    }
    l.mesh
}

/// The cube `[-1, 1]^3` with every face cut into `n * n` squares of two triangles each (the
/// diagonal alternating), so every box of a face's triangles is flat.
pub fn cube(n: i32) -> Mesh {
    let mut l = Lattice::default();
    let s = 1.0 / n as f32;
    for axis in 0..3 {
        for side in [0, n] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let p = |i: i32, j: i32| {
                let mut q = [0; 3];
                q[axis] = side;
                q[u] = i;
                q[v] = j;
                // Lattice 0..n maps to -1..1 as (2 q - n) / n.
                [2 * q[0] - n, 2 * q[1] - n, 2 * q[2] - n]
            };
            for i in 0..n {
                for j in 0..n {
                    let (a, b, c, d) = (p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                    let q = [a, b, c, d].map(|x| l.vertex(x, s));
                    let tris = if (i + j) % 2 == 0 {
                        [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
                    } else {
                        [[q[0], q[1], q[3]], [q[1], q[2], q[3]]]
                    };
                    for t in tris {
                        // Counter-clockwise seen from outside.
                        l.mesh.faces.push(if side == 0 { [t[0], t[2], t[1]] } else { t });
                    }
                }
            }
        }
    }
    l.mesh
}

/// Uniform numbers from the kernels' own stream (fixed seed per test).
pub struct Random(Rng);

impl Random {
    pub fn new(seed: u32) -> Random {
        Random(Rng::new(seed, 0, 0x5eed))
    }
    pub fn f32(&mut self) -> f32 {
        self.0.next_f32()
    }
    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.0.next_f32()
    }
    /// Uniform in `[0, 1)` with 53 random bits, for f64 references.
    pub fn f64(&mut self) -> f64 {
        let hi = (self.0.next_u32() >> 5) as u64;
        let lo = (self.0.next_u32() >> 6) as u64;
        ((hi << 26) | lo) as f64 / (1u64 << 53) as f64
    }
    pub fn rng(&mut self) -> &mut Rng {
        &mut self.0
    }
    /// Uniform unit vector.
    pub fn unit(&mut self) -> Vec3 {
        let (u1, u2) = (self.f32(), self.f32());
        shared::sampling::uniform_sphere(u1, u2)
    }
}

/// Spacing of `f32` values at `x` (the ulp of `x` rounded to `f32`).
pub fn ulp_f32(x: f64) -> f64 {
    let a = (x as f32).abs();
    if a == 0.0 {
        return f32::from_bits(1) as f64;
    }
    let next = f32::from_bits(a.to_bits() + 1);
    (next - a) as f64
}

/// Distance of `x` from the reference `reference` in units of `f32` spacing at `reference`.
pub fn ulps(x: f32, reference: f64) -> f64 {
    (x as f64 - reference).abs() / ulp_f32(reference)
}

/// Upper standard normal quantile: `z` with `P(Z > z) = p`, for `p <= 0.5` (Abramowitz &
/// Stegun 26.2.23, absolute error below 4.5e-4).
pub fn normal_quantile_upper(p: f64) -> f64 {
    let t = (-2.0 * p.ln()).sqrt();
    t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t * t * t)
}

/// Chi-square value exceeded with probability `p` at `dof` degrees of freedom
/// (Wilson & Hilferty 1931: the cube root of chi-square / dof is nearly normal).
pub fn chi_square_critical(dof: f64, p: f64) -> f64 {
    let z = normal_quantile_upper(p);
    let h = 2.0 / (9.0 * dof);
    dof * (1.0 - h + z * h.sqrt()).powi(3)
}

/// Pearson's chi-square of observed `counts` against equal expected counts.
pub fn chi_square_uniform(counts: &[u64]) -> f64 {
    let n: u64 = counts.iter().sum();
    let e = n as f64 / counts.len() as f64;
    counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum()
}

/// Runs `f` on a thread and fails if it has not returned after `secs` seconds: a guard that
/// turns a hang into a failure, not a timing measurement.
pub fn returns_within<T: Send + 'static>(secs: u64, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(secs))
        .unwrap_or_else(|e| panic!("{what}: did not return ({e})"))
}
