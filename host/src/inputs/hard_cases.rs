//! Inputs that break naive ray tracers, shared by the stability tests and `raytrace bench
//! accuracy`: closed triangle meshes with shared vertices (every edge in exactly two
//! triangles), and rays from inside them aimed exactly at every vertex and edge midpoint,
//! the mesh at the origin or moved far from it. A watertight intersector hits every one.
use crate::scene::{CameraSpec, Scene, SceneObject, Settings, Shape, Transform};
use glam::Vec3;
use shared::types::{Material, Sphere, Triangle};
use std::collections::HashMap;

/// Interior points of the unit meshes (also inside the octahedron `|x| + |y| + |z| < 1`).
pub const INSIDE: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [0.1, -0.23, 0.31],
    [-0.37, 0.05, -0.11],
    [0.29, 0.33, -0.2],
];
/// Distances the meshes are moved by (along `(1, -1, 1)`), the rays' origins with them.
pub const OFFSETS: [f32; 3] = [0.0, 1e3, 1e5];

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

/// Rays (origin, direction) from every [`INSIDE`] point aimed exactly at every vertex and
/// every edge midpoint of the closed `mesh` moved by `offset`: every one must hit.
pub fn rays_at_vertices_and_edges(mesh: &Mesh, offset: Vec3) -> Vec<(Vec3, Vec3)> {
    let edges = mesh.edges();
    let v = mesh.moved(offset);
    let targets: Vec<Vec3> = v
        .iter()
        .copied()
        .chain(edges.iter().map(|&[a, b]| (v[a as usize] + v[b as usize]) * 0.5))
        .collect();
    INSIDE
        .iter()
        .flat_map(|&o| {
            let o = Vec3::from(o) + offset;
            targets.iter().map(move |&t| (o, t - o))
        })
        .collect()
}

/// The closed meshes of the watertightness tests, by name.
pub fn closed_meshes() -> Vec<(&'static str, Mesh)> {
    vec![
        ("icosphere (1280 triangles)", icosphere(3)),
        ("octahedron, faces cut in 64", octahedron(8)),
        ("cube of 12 triangles", cube(1)),
        ("cube, faces cut in 8x8 squares", cube(8)),
    ]
}

/// World-space primitives as a scene the renderer can load: one mesh object holding
/// `tris` untransformed, one object per sphere translated to its centre (both exact in the
/// transform stage), all grey; a 1x1 frame.
pub fn scene_of(tris: &[Triangle], spheres: &[Sphere]) -> Scene {
    let mut objects = Vec::new();
    if !tris.is_empty() {
        objects.push(SceneObject {
            name: "mesh".into(),
            shape: Shape::Mesh(0),
            transform: Transform::IDENTITY,
            material: 0,
            animation: Default::default(),
            instance: None,
        });
    }
    for s in spheres {
        let c = s.center_radius;
        objects.push(SceneObject {
            name: "sphere".into(),
            shape: Shape::Sphere { radius: c[3] },
            transform: Transform {
                translation: Vec3::new(c[0], c[1], c[2]),
                ..Transform::IDENTITY
            },
            material: 0,
            animation: Default::default(),
            instance: None,
        });
    }
    Scene {
        name: "primitives".into(),
        punctual: Vec::new(),
        environment: None,
        textures: Default::default(),
        camera: CameraSpec {
            position: Vec3::Z,
            look_at: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 60.0,
            aperture: 0.0,
            focus_distance: None,
        },
        settings: Settings {
            width: 1,
            height: 1,
            ..Settings::default()
        },
        materials: vec![("grey".into(), Material::default())],
        meshes: vec![crate::scene::Mesh::flat("triangles", tris.to_vec())],
        objects,
    }
}
