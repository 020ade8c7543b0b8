//! Hard cases stay stable, on the CPU (DESIGN.md sections 3 and 4): the intersection,
//! traversal, offset, scattering and sampling code the GPU runs, fed the inputs that break
//! naive ray tracers.
//!
//! 1. Closed meshes near and far from the origin do not leak at shared vertices and edges.
//! 2. Rays spawned from hits (Wachter & Binder offsets) never re-hit their own surface.
//! 3. Axis-aligned rays with either sign of zero, flat boxes, origins on slab planes, and
//!    non-finite rays or primitives: a miss or the right hit, never NaN, always returning.
//! 4. Small far and large near spheres agree with an f64 reference to a few ulp.
//! 5. Every material conserves energy; every sampling routine passes a chi-square test.
mod common;

/// Whether this run of the suite traces through the wide BVH (`stability_wide.rs` runs this
/// file again with it set).
#[allow(dead_code)]
const WIDE: bool = false;

use common::rays::*;
use common::*;
use raytrace::inputs::hard_cases::closed_meshes;
use shared::glam::{DVec3, Vec3};
use shared::intersect::{self, offset_origin, TriRay};
use shared::material::{self, reflect};
use shared::sampling;
use shared::traverse;
use shared::types::{Hit, Material, MaterialKind, Sphere, Triangle, FEATURES_ALL, INVALID};

const INF: f32 = f32::INFINITY;

// ---------------------------------------------------------------------------------------------
// 1. Watertightness
// ---------------------------------------------------------------------------------------------

/// Rays of [`shoot_at_vertices_and_edges`] that found nothing, by query.
#[derive(Debug, Default)]
struct Leaks {
    rays: usize,
    brute: usize,
    bvh: usize,
    any_brute: usize,
    any_bvh: usize,
    /// Rays whose closest hit through the BVH is more than [`TIE_ULPS`] farther than by
    /// brute force.
    farther: usize,
    /// Rays whose closest hits differ by at most [`TIE_ULPS`]: two triangles sharing the edge
    /// or vertex hit, whose distances round differently; the BVH may skip the nearer one when
    /// its box's entry distance rounds above the other's hit.
    ties: usize,
    first: Option<String>,
}

/// Distances of two hits of one ray at a shared edge or vertex may differ by this many ulps.
const TIE_ULPS: f64 = 4.0;

/// Rays from interior points aimed exactly at every vertex and every edge midpoint of a
/// closed mesh, placed at each of [`OFFSETS`]; every ray must hit.
fn shoot_at_vertices_and_edges(name: &str, mesh: &Mesh) -> Leaks {
    assert!(mesh.is_closed(), "{name} is not a closed mesh");
    let mut l = Leaks::default();
    for s in OFFSETS {
        let offset = Vec3::new(s, -s, s);
        let world = World::new(mesh.triangles(offset), vec![]);
        let scene = world.scene();
        for (o, d) in rays_at_vertices_and_edges(mesh, offset) {
            l.rays += 1;
            let brute = traverse::closest_brute(&scene, o, d, INF);
            let bvh = traverse::closest(&scene, o, d, INF);
            let (any_brute, any_bvh) = (traverse::any_brute(&scene, o, d, INF), traverse::any(&scene, o, d, INF));
            let tie = brute.t != bvh.t && ulps(bvh.t, brute.t as f64) <= TIE_ULPS;
            let farther = brute.t != bvh.t && !tie;
            l.brute += (brute.prim == INVALID) as usize;
            l.bvh += (bvh.prim == INVALID) as usize;
            l.any_brute += !any_brute as usize;
            l.any_bvh += !any_bvh as usize;
            l.ties += tie as usize;
            l.farther += farther as usize;
            if brute.prim == INVALID || bvh.prim == INVALID || !any_brute || !any_bvh || farther {
                l.first.get_or_insert_with(|| {
                    format!("from {o} along {d}: brute {brute:?}, BVH {bvh:?}, any {any_brute} / {any_bvh}")
                });
            }
        }
    }
    eprintln!("{name}: {l:?}");
    l
}

fn assert_watertight(name: &str, mesh: &Mesh) {
    let l = shoot_at_vertices_and_edges(name, mesh);
    assert!(
        l.brute + l.bvh + l.any_brute + l.any_bvh + l.farther == 0,
        "{name}: leaks of {} rays: brute force {}, BVH {}, any-hit brute force {}, any-hit BVH {}; \
         BVH hit farther than brute force (> {TIE_ULPS} ulp) on {}; first: {}",
        l.rays,
        l.brute,
        l.bvh,
        l.any_brute,
        l.any_bvh,
        l.farther,
        l.first.unwrap_or_default()
    );
}

#[test]
fn icosphere_does_not_leak_at_vertices_or_edges() {
    assert_watertight("icosphere (1280 triangles)", &icosphere(3));
}

#[test]
fn flat_subdivided_octahedron_does_not_leak_at_vertices_or_edges() {
    assert_watertight("octahedron, faces cut in 64", &octahedron(8));
}

#[test]
fn cubes_of_triangles_do_not_leak_at_vertices_or_edges() {
    assert_watertight("cube of 12 triangles", &cube(1));
    assert_watertight("cube, faces cut in 8x8 squares", &cube(8));
}

/// The watertightness rays on the GPU: every closed mesh at every offset, built and traced
/// by the GPU (the kernels as the driver compiled them: fused or reordered arithmetic would
/// show here), closest and any hit, through the BVH and by brute force.
#[test]
fn closed_meshes_do_not_leak_on_the_gpu() {
    let Some(mut g) = GpuWorld::open("closed_meshes_do_not_leak_on_the_gpu") else {
        return;
    };
    let mut failures = Vec::new();
    for (name, mesh) in closed_meshes() {
        let mut l = Leaks::default();
        for s in OFFSETS {
            let offset = Vec3::new(s, -s, s);
            g.load(&World::new(mesh.triangles(offset), vec![]));
            let rays: Vec<_> = rays_at_vertices_and_edges(&mesh, offset)
                .into_iter()
                .map(|(o, d)| (o, d, INF))
                .collect();
            g.set_mode(true, 0);
            let (bvh, any_bvh) = (g.closest(&rays), g.any(&rays));
            g.set_mode(false, 0);
            let (brute, any_brute) = (g.closest(&rays), g.any(&rays));
            for i in 0..rays.len() {
                let (b, h) = (brute[i], bvh[i]);
                let tie = b.t != h.t && ulps(h.t, b.t as f64) <= TIE_ULPS;
                let farther = b.t != h.t && !tie;
                l.rays += 1;
                l.brute += (b.prim == INVALID) as usize;
                l.bvh += (h.prim == INVALID) as usize;
                l.any_brute += !any_brute[i] as usize;
                l.any_bvh += !any_bvh[i] as usize;
                l.ties += tie as usize;
                l.farther += farther as usize;
                if b.prim == INVALID || h.prim == INVALID || !any_brute[i] || !any_bvh[i] || farther {
                    let (o, d, _) = rays[i];
                    l.first.get_or_insert_with(|| {
                        format!(
                            "offset {s}, from {o} along {d}: brute {b:?}, BVH {h:?}, any {} / {}",
                            any_brute[i], any_bvh[i]
                        )
                    });
                }
            }
        }
        eprintln!("GPU, {name}: {l:?}");
        if l.brute + l.bvh + l.any_brute + l.any_bvh + l.farther > 0 {
            failures.push(format!("{name}: {l:?}"));
        }
    }
    g.assert_no_validation_errors();
    assert!(failures.is_empty(), "leaks on the GPU:\n{}", failures.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// 2. Reintersection
// ---------------------------------------------------------------------------------------------

/// A surface to spawn secondary rays from.
struct Surface {
    name: String,
    world: World,
    /// Which surface each primitive belongs to (coplanar triangles share one).
    part: Vec<u32>,
    /// Closed and convex: a ray leaving it outward must miss everything. (One entering may
    /// still leave at once through a neighbouring face where it starts on an edge.)
    convex: bool,
    center: Vec3,
    /// Primary rays start `3 * reach` from `aim_at` and aim within `reach` of it.
    aim_at: Vec3,
    reach: f32,
}

impl Surface {
    /// The surface with primary rays aimed within `reach` of `at`.
    fn aimed(self, at: Vec3, reach: f32) -> Surface {
        Surface {
            name: format!("{}, hits within {reach} of {at}", self.name),
            aim_at: at,
            reach,
            ..self
        }
    }
}

fn mesh_surface(name: &str, mesh: &Mesh, scale: f32, center: Vec3, convex: bool, part: Vec<u32>) -> Surface {
    let m = Mesh {
        verts: mesh.verts.iter().map(|&v| v * scale).collect(),
        faces: mesh.faces.clone(),
    };
    Surface {
        name: format!("{name} x{scale} at {center}"),
        world: World::new(m.triangles(center), vec![]),
        part,
        convex,
        center,
        aim_at: center,
        reach: scale,
    }
}

fn sphere_surface(r: f32, center: Vec3) -> Surface {
    Surface {
        name: format!("sphere r={r} at {center}"),
        world: World::new(
            vec![],
            vec![Sphere {
                center_radius: [center.x, center.y, center.z, r],
            }],
        ),
        part: vec![0],
        convex: true,
        center,
        aim_at: center,
        reach: r,
    }
}

/// A tilted square of two triangles (one surface), `2 * half` wide.
fn tilted_square(half: f32, center: Vec3) -> Surface {
    let n = Vec3::new(0.3, 0.8, -0.52).normalize();
    let (u, v) = sampling::basis(n);
    let c = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(a, b)| (u * a + v * b) * half);
    let mesh = Mesh {
        verts: c.to_vec(),
        faces: vec![[0, 1, 2], [0, 2, 3]],
    };
    Surface {
        name: format!("tilted square {half} at {center}"),
        world: World::new(mesh.triangles(center), vec![]),
        part: vec![0, 0],
        convex: false,
        center,
        aim_at: center,
        reach: half,
    }
}

/// A bumpy height field of `n * n` squares over `[-half, half]^2` (not convex: every triangle
/// is its own surface).
fn height_field(n: usize, half: f32, center: Vec3) -> Surface {
    let mut rnd = Random::new(99);
    let mut verts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32 * 2.0 - 1.0, j as f32 / n as f32 * 2.0 - 1.0);
            verts.push(Vec3::new(x, rnd.range(-0.3, 0.3), y) * half);
        }
    }
    let mut faces = Vec::new();
    for j in 0..n as u32 {
        for i in 0..n as u32 {
            let a = j * (n as u32 + 1) + i;
            let (b, c, d) = (a + 1, a + n as u32 + 2, a + n as u32 + 1);
            faces.extend([[a, b, c], [a, c, d]]);
        }
    }
    let part = (0..faces.len() as u32).collect();
    let mesh = Mesh { verts, faces };
    Surface {
        name: format!("height field {half} at {center}"),
        world: World::new(mesh.triangles(center), vec![]),
        part,
        convex: false,
        center,
        aim_at: center,
        reach: half,
    }
}

/// Secondary rays of [`spawn_from_hits`] and those that re-hit their surface.
#[derive(Debug, Default)]
struct Spawned {
    hits: usize,
    rays: usize,
    failures: usize,
    first: Option<String>,
}

/// The directions spawned from a hit with geometric normal `ng` by a ray along `d`: the
/// mirror direction and two cosine-distributed ones on each side of the surface.
fn spawned_dirs(d: Vec3, ng: Vec3, rnd: &mut Random) -> Vec<Vec3> {
    let facing = if d.dot(ng) < 0.0 { ng } else { -ng };
    let mut dirs = vec![reflect(d, facing)];
    for _ in 0..2 {
        let (u1, u2) = (rnd.f32(), rnd.f32());
        dirs.push(sampling::cosine_hemisphere(facing, u1, u2));
        let (u1, u2) = (rnd.f32(), rnd.f32());
        dirs.push(sampling::cosine_hemisphere(-facing, u1, u2));
    }
    dirs
}

/// Spawns secondary rays from `primaries` random hits as the path tracer does: origin offset
/// to the side the new ray leaves to, direction reflected, cosine-distributed on the side of
/// the incoming ray, or cosine-distributed through the surface. Rays that cross a convex
/// surface spawn once more from its far side. Every ray is traced by brute force and through
/// the BVH.
fn spawn_from_hits(s: &Surface, primaries: usize, seed: u32) -> Spawned {
    let scene = s.world.scene();
    let mut rnd = Random::new(seed);
    let mut out = Spawned::default();
    for _ in 0..primaries {
        let from = s.aim_at + rnd.unit() * (3.0 * s.reach);
        let to = s.aim_at + rnd.unit() * (0.9 * s.reach * rnd.f32());
        let d = (to - from).normalize();
        let h = traverse::closest_brute(&scene, from, d, INF);
        if h.prim == INVALID {
            continue;
        }
        out.hits += 1;
        let mut queue = vec![(from, d, h, 0)];
        while let Some((o, d, h, depth)) = queue.pop() {
            let (p, ng, scale) = traverse::surface(&scene, h.prim, o, d, &h);
            for d2 in spawned_dirs(d, ng, &mut rnd) {
                let o2 = offset_origin(p, if d2.dot(ng) > 0.0 { ng } else { -ng }, scale);
                for (how, h2) in [
                    ("brute force", traverse::closest_brute(&scene, o2, d2, INF)),
                    ("BVH", traverse::closest(&scene, o2, d2, INF)),
                ] {
                    out.rays += 1;
                    if let Some(why) = self_hit(s, h.prim, p, ng, d2, &h2) {
                        out.failures += 1;
                        out.first.get_or_insert_with(|| {
                            format!("{how}: from {p} (prim {}, normal {ng}) along {d2}: {why}", h.prim)
                        });
                    } else if s.convex && depth == 0 && h2.prim != INVALID && how == "BVH" {
                        queue.push((o2, d2, h2, depth + 1));
                    }
                }
            }
        }
    }
    out
}

/// Why the secondary ray from `p` on primitive `own` along `d2` with closest hit `h2` is
/// wrong, if it is.
fn self_hit(s: &Surface, own: u32, p: Vec3, ng: Vec3, d2: Vec3, h2: &Hit) -> Option<String> {
    let hit = h2.prim != INVALID;
    if s.world.tris.is_empty() {
        // A sphere: outward rays leave it, inward ones cross it, never re-hitting the start.
        let r = s.world.spheres[0].center_radius[3] as f64;
        let cos = d2.as_dvec3().dot(ng.as_dvec3());
        let chord = -2.0 * r * cos;
        return if cos > 0.0 && hit {
            Some(format!("outward ray hit the sphere at t = {}", h2.t))
        } else if cos < 0.0 && !hit {
            Some("inward ray escaped the sphere".into())
        } else if cos < 0.0 && (h2.t as f64) < 0.5 * chord {
            Some(format!("re-hit at t = {} on a chord of {chord}", h2.t))
        } else {
            None
        };
    }
    if hit && s.part[h2.prim as usize] == s.part[own as usize] {
        return Some(format!("re-hit its own surface (prim {}) at t = {}", h2.prim, h2.t));
    }
    if s.convex {
        let outward = if (p - s.center).dot(ng) > 0.0 { ng } else { -ng };
        if d2.dot(outward) > 0.0 && hit {
            return Some(format!("outward ray hit prim {} at t = {}", h2.prim, h2.t));
        }
    }
    None
}

/// Spawns from `primaries` hits on `s`; returns a line for the failure report if any
/// secondary ray went wrong.
fn self_hits(s: &Surface, primaries: usize, seed: u32) -> Option<String> {
    let r = spawn_from_hits(s, primaries, seed);
    eprintln!(
        "{}: {} hits, {} secondary rays, {} wrong",
        s.name, r.hits, r.rays, r.failures
    );
    if r.hits <= primaries / 4 {
        return Some(format!("{}: only {} of {primaries} primary rays hit", s.name, r.hits));
    }
    (r.failures > 0).then(|| {
        format!(
            "{}: {} of {} secondary rays wrong; first: {}",
            s.name,
            r.failures,
            r.rays,
            r.first.unwrap_or_default()
        )
    })
}

const FAR: Vec3 = Vec3::new(1e4, -1e4, 1e4);

#[test]
fn secondary_rays_never_rehit_spheres() {
    let mut wrong = Vec::new();
    for (r, c) in [
        (1.0, Vec3::ZERO),
        (1.0, Vec3::new(0.2, -0.3, 0.1)),
        (0.01, Vec3::new(3.0, 0.0, -2.0)),
        (1.0, FAR),
        (100.0, FAR),
        (1e4, FAR),
    ] {
        wrong.extend(self_hits(&sphere_surface(r, c), 2000, 1));
    }
    // A ground sphere hit near the origin, far from its centre.
    for r in [1e2, 1e3, 1e4, 1e5] {
        let ground = sphere_surface(r, Vec3::new(0.0, -r, 0.0)).aimed(Vec3::ZERO, 10.0);
        wrong.extend(self_hits(&ground, 2000, 6));
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn secondary_rays_never_rehit_triangle_meshes() {
    let ico = icosphere(2);
    let ico_parts = (0..ico.faces.len() as u32).collect::<Vec<_>>();
    let cube = cube(4);
    // Each of the cube's six faces is one plane: 32 triangles in order per face.
    let cube_parts = (0..cube.faces.len() as u32).map(|i| i / 32).collect::<Vec<_>>();
    let mut wrong = Vec::new();
    for (scale, c) in [(1.0, Vec3::ZERO), (1.0, FAR), (50.0, FAR)] {
        wrong.extend(self_hits(
            &mesh_surface("icosphere", &ico, scale, c, true, ico_parts.clone()),
            2000,
            2,
        ));
        wrong.extend(self_hits(
            &mesh_surface("cube", &cube, scale, c, true, cube_parts.clone()),
            2000,
            3,
        ));
        wrong.extend(self_hits(&tilted_square(scale, c), 2000, 4));
        wrong.extend(self_hits(&height_field(6, scale, c), 2000, 5));
    }
    // A ground square far larger than the scene, hit near the origin.
    for half in [1e2, 3e2, 1e3, 1e4, 1e5] {
        wrong.extend(self_hits(
            &tilted_square(half, Vec3::ZERO).aimed(Vec3::ZERO, 10.0),
            2000,
            7,
        ));
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// [`self_hits`] on the GPU: the GPU finds the primary hits, the directions are chosen from
/// them here as [`spawn_from_hits`] does, and the GPU offsets each new origin from its hit
/// point and traces it through its BVH (`CAST_SPAWN`: the path tracer's own code).
fn gpu_self_hits(g: &mut GpuWorld, s: &Surface, primaries: usize, seed: u32) -> Option<String> {
    g.load(&s.world);
    let scene = s.world.scene();
    let mut rnd = Random::new(seed);
    let primary: Vec<(Vec3, Vec3, f32)> = (0..primaries)
        .map(|_| {
            let from = s.aim_at + rnd.unit() * (3.0 * s.reach);
            let to = s.aim_at + rnd.unit() * (0.9 * s.reach * rnd.f32());
            (from, (to - from).normalize(), INF)
        })
        .collect();
    let hits = g.closest(&primary);
    let (mut pairs, mut starts) = (Vec::new(), Vec::new());
    for (&(o, d, _), h) in primary.iter().zip(&hits) {
        if h.prim == INVALID {
            continue;
        }
        let (p, ng, _) = traverse::surface(&scene, h.prim, o, d, h);
        for d2 in spawned_dirs(d, ng, &mut rnd) {
            pairs.push(((o, d), d2));
            starts.push((*h, p, ng));
        }
    }
    let n_hits = pairs.len() / 5;
    let out = g.spawn(&pairs);
    let mut wrong = Vec::new();
    for (((_, d2), (h, p, ng)), (first, second)) in pairs.iter().zip(&starts).zip(&out) {
        if first != h {
            wrong.push(format!(
                "the spawning cast's primary hit {first:?} is not the cast's {h:?}"
            ));
        } else if let Some(why) = self_hit(s, h.prim, *p, *ng, *d2, second) {
            wrong.push(format!("from {p} (prim {}, normal {ng}) along {d2}: {why}", h.prim));
        }
    }
    eprintln!(
        "GPU, {}: {n_hits} hits, {} secondary rays, {} wrong",
        s.name,
        out.len(),
        wrong.len()
    );
    if n_hits <= primaries / 4 {
        return Some(format!("{}: only {n_hits} of {primaries} primary rays hit", s.name));
    }
    (!wrong.is_empty()).then(|| {
        format!(
            "{}: {} of {} wrong; first: {}",
            s.name,
            wrong.len(),
            out.len(),
            wrong[0]
        )
    })
}

#[test]
fn secondary_rays_never_rehit_on_the_gpu() {
    let Some(mut g) = GpuWorld::open("secondary_rays_never_rehit_on_the_gpu") else {
        return;
    };
    let mut surfaces = Vec::new();
    for (r, c) in [
        (1.0, Vec3::ZERO),
        (0.01, Vec3::new(3.0, 0.0, -2.0)),
        (1.0, FAR),
        (1e4, FAR),
    ] {
        surfaces.push(sphere_surface(r, c));
    }
    for r in [1e2, 1e3, 1e4, 1e5] {
        surfaces.push(sphere_surface(r, Vec3::new(0.0, -r, 0.0)).aimed(Vec3::ZERO, 10.0));
    }
    let ico = icosphere(2);
    let ico_parts: Vec<u32> = (0..ico.faces.len() as u32).collect();
    let cube = cube(4);
    let cube_parts: Vec<u32> = (0..cube.faces.len() as u32).map(|i| i / 32).collect();
    for (scale, c) in [(1.0, Vec3::ZERO), (50.0, FAR)] {
        surfaces.push(mesh_surface("icosphere", &ico, scale, c, true, ico_parts.clone()));
        surfaces.push(mesh_surface("cube", &cube, scale, c, true, cube_parts.clone()));
        surfaces.push(tilted_square(scale, c));
        surfaces.push(height_field(6, scale, c));
    }
    for half in [1e2, 1e3, 1e5] {
        surfaces.push(tilted_square(half, Vec3::ZERO).aimed(Vec3::ZERO, 10.0));
    }
    let wrong: Vec<String> = surfaces
        .iter()
        .enumerate()
        .filter_map(|(k, s)| gpu_self_hits(&mut g, s, 1000, 20 + k as u32))
        .collect();
    g.assert_no_validation_errors();
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// 3. Axis-aligned rays, flat boxes, non-finite input
// ---------------------------------------------------------------------------------------------

/// Entry distance of the ray into the closed box within `[0, t_max]` in exact arithmetic
/// (`d` components in {-1, 0, 1}), or `INFINITY`.
fn box_entry(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3, t_max: f32) -> f32 {
    let (mut near, mut far) = (0.0f64, t_max as f64);
    for k in 0..3 {
        let (o, d, lo, hi) = (o[k] as f64, d[k] as f64, lo[k] as f64, hi[k] as f64);
        if d == 0.0 {
            if o < lo || o > hi {
                return INF;
            }
        } else {
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            near = near.max(a.min(b));
            far = far.min(a.max(b));
        }
    }
    if near <= far {
        near as f32
    } else {
        INF
    }
}

#[test]
fn slab_is_exact_for_axis_aligned_rays_and_either_sign_of_zero() {
    let boxes = [
        (Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 2.0, 3.0)),
        (Vec3::new(0.5, 0.0, 0.0), Vec3::new(0.5, 2.0, 3.0)),
        (Vec3::new(0.0, 0.5, 0.0), Vec3::new(1.0, 0.5, 3.0)),
        (Vec3::new(0.0, 0.0, 0.5), Vec3::new(1.0, 2.0, 0.5)),
        (Vec3::new(0.0, 0.5, 0.5), Vec3::new(1.0, 0.5, 0.5)),
        (Vec3::new(0.5, 0.5, 0.5), Vec3::new(0.5, 0.5, 0.5)),
    ];
    let dirs = signed_zero_directions();
    let (mut checks, mut wrong) = (0, Vec::new());
    for (lo, hi) in boxes {
        let coords = |k: usize| [-1.0, lo[k], (lo[k] + hi[k]) * 0.5, hi[k], 4.0];
        for x in coords(0) {
            for y in coords(1) {
                for z in coords(2) {
                    let o = Vec3::new(x, y, z);
                    for &d in &dirs {
                        for t_max in [INF, 2.0] {
                            let inv = TriRay::new(o, d).inv_dir;
                            let got = intersect::slab(o, inv, lo, hi, t_max);
                            let want = box_entry(o, d, lo, hi, t_max);
                            checks += 1;
                            if got != want {
                                wrong.push(format!(
                                    "box {lo}..{hi} from {o} along {d:?} t_max {t_max}: {got}, want {want}"
                                ));
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "{} of {checks} slab tests wrong, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}

#[test]
fn axis_aligned_rays_hit_alike_through_bvh_and_brute_force() {
    let (coords, dirs) = (AXIS_RAY_COORDS, signed_zero_directions());
    let meshes = axis_ray_meshes();
    let (mut rays, mut hits, mut wrong) = (0, 0, Vec::new());
    for (name, tris) in meshes {
        let world = World::new(tris, vec![]);
        let scene = world.scene();
        for x in coords {
            for y in coords {
                for z in coords {
                    let o = Vec3::new(x, y, z);
                    for &d in &dirs {
                        rays += 1;
                        let brute = traverse::closest_brute(&scene, o, d, INF);
                        let bvh = traverse::closest(&scene, o, d, INF);
                        // The same ray with every zero component of the other sign.
                        let flipped = Vec3::select(d.cmpeq(Vec3::ZERO), -d, d);
                        let brute_flipped = traverse::closest_brute(&scene, o, flipped, INF);
                        hits += (brute.prim != INVALID) as usize;
                        let any = traverse::any(&scene, o, d, INF);
                        let any_brute = traverse::any_brute(&scene, o, d, INF);
                        if brute.t.to_bits() != bvh.t.to_bits()
                            || brute.t.to_bits() != brute_flipped.t.to_bits()
                            || any != any_brute
                            || any != (brute.prim != INVALID)
                        {
                            wrong.push(format!(
                                "{name} from {o} along {d:?}: brute {:?}, BVH {:?}, zeros flipped {:?}, any {any} / {any_brute}",
                                brute.t, bvh.t, brute_flipped.t
                            ));
                        }
                    }
                }
            }
        }
    }
    eprintln!("{rays} axis-aligned rays, {hits} hits, {} disagree", wrong.len());
    assert!(
        wrong.is_empty(),
        "{} of {rays} rays disagree, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}

#[test]
fn non_finite_rays_miss_and_return() {
    let wrong = returns_within(120, "non-finite rays", || {
        let world = mixed_world();
        let scene = world.scene();
        let rays = non_finite_rays();
        let mut wrong = Vec::new();
        for (o, d) in rays {
            let r = TriRay::new(o, d);
            let queries = [
                ("closest", traverse::closest(&scene, o, d, INF)),
                ("closest_brute", traverse::closest_brute(&scene, o, d, INF)),
            ];
            for (what, h) in queries {
                if h != Hit::MISS {
                    wrong.push(format!("{what} from {o} along {d}: {h:?}"));
                }
            }
            if traverse::any(&scene, o, d, INF) || traverse::any_brute(&scene, o, d, INF) {
                wrong.push(format!("any from {o} along {d}: true"));
            }
            for prim in 0..scene.n_prims {
                let t = traverse::primitive(&scene, &r, prim, INF).0;
                if t != INF {
                    wrong.push(format!("primitive {prim} from {o} along {d}: t = {t}"));
                }
            }
            let root = &world.nodes[0];
            let t = intersect::slab(o, r.inv_dir, Vec3::from(root.min), Vec3::from(root.max), INF);
            if t.is_nan() {
                wrong.push(format!("slab from {o} along {d}: NaN"));
            }
        }
        // A good ray with a bad range.
        for t_max in BAD_T_MAX {
            let (o, d) = GOOD_RAY;
            let r = TriRay::new(o, d);
            for h in [
                traverse::closest(&scene, o, d, t_max),
                traverse::closest_brute(&scene, o, d, t_max),
            ] {
                if h != Hit::MISS {
                    wrong.push(format!("t_max {t_max}: {h:?}"));
                }
            }
            if traverse::any(&scene, o, d, t_max) || traverse::any_brute(&scene, o, d, t_max) {
                wrong.push(format!("any with t_max {t_max}: true"));
            }
            for prim in 0..scene.n_prims {
                let t = traverse::primitive(&scene, &r, prim, t_max).0;
                if t != INF {
                    wrong.push(format!("primitive {prim} with t_max {t_max}: t = {t}"));
                }
            }
        }
        // Finite rays at the edge of the range: any answer, but a sane one, the same both ways.
        let extreme = EXTREME_RAYS;
        for (o, d) in extreme {
            let bvh = traverse::closest(&scene, o, d, INF);
            let brute = traverse::closest_brute(&scene, o, d, INF);
            if !sane(&bvh, scene.n_prims, INF) || !sane(&brute, scene.n_prims, INF) || bvh.t != brute.t {
                wrong.push(format!(
                    "extreme ray from {o} along {d}: BVH {bvh:?}, brute force {brute:?}"
                ));
            }
            let r = TriRay::new(o, d);
            for prim in 0..scene.n_prims {
                let t = traverse::primitive(&scene, &r, prim, INF).0;
                if t.is_nan() {
                    wrong.push(format!("extreme ray, primitive {prim}: NaN"));
                }
            }
        }
        wrong
    });
    assert!(wrong.is_empty(), "{} wrong answers:\n{}", wrong.len(), wrong.join("\n"));
}

/// The axis-aligned and non-finite rays on the GPU: a miss or the right hit, no NaN, the
/// same through the BVH and by brute force and as on the CPU, and every query returns.
/// (Broken primitives are left to the CPU: scenes with non-finite vertices are refused
/// before they reach the GPU.)
#[test]
fn axis_aligned_and_non_finite_rays_on_the_gpu() {
    let Some(mut g) = GpuWorld::open("axis_aligned_and_non_finite_rays_on_the_gpu") else {
        return;
    };
    let mut wrong = Vec::new();
    // Axis-aligned rays: GPU BVH == GPU brute force == the same ray with zeros flipped,
    // bit for bit; any-hit agrees; hits as on the CPU within a few ulps.
    let (coords, dirs) = (AXIS_RAY_COORDS, signed_zero_directions());
    let meshes = axis_ray_meshes();
    for (name, tris) in meshes {
        let world = World::new(tris, vec![]);
        let scene = world.scene();
        g.load(&world);
        let mut rays = Vec::new();
        for x in coords {
            for y in coords {
                for z in coords {
                    rays.extend(dirs.iter().map(|&d| (Vec3::new(x, y, z), d, INF)));
                }
            }
        }
        let flipped: Vec<_> = rays
            .iter()
            .map(|&(o, d, t)| (o, Vec3::select(d.cmpeq(Vec3::ZERO), -d, d), t))
            .collect();
        g.set_mode(true, 0);
        let (bvh, any) = (g.closest(&rays), g.any(&rays));
        g.set_mode(false, 0);
        let (brute, brute_flipped) = (g.closest(&rays), g.closest(&flipped));
        for (i, &(o, d, _)) in rays.iter().enumerate() {
            let cpu = traverse::closest_brute(&scene, o, d, INF);
            // A ray along an open mesh's boundary edge may hit on one device and not the
            // other (division rounds differently); elsewhere they agree.
            let on_edge = |h: &Hit| h.prim != INVALID && h.u.min(h.v).min(1.0 - h.u - h.v) < 1e-5;
            let same_cpu = (cpu.prim == INVALID) == (brute[i].prim == INVALID)
                && (cpu.prim == INVALID || ulps(brute[i].t, cpu.t as f64) <= TIE_ULPS)
                || on_edge(&cpu)
                || on_edge(&brute[i]);
            if brute[i].t.to_bits() != bvh[i].t.to_bits()
                || brute[i].t.to_bits() != brute_flipped[i].t.to_bits()
                || any[i] != (brute[i].prim != INVALID)
                || !same_cpu
            {
                wrong.push(format!(
                    "{name} from {o} along {d:?}: GPU brute {:?}, BVH {:?}, zeros flipped {:?}, any {}; CPU {:?}",
                    brute[i].t, bvh[i].t, brute_flipped[i].t, any[i], cpu.t
                ));
            }
        }
    }
    // Non-finite rays and bad ranges: misses; extreme rays: sane, BVH == brute force.
    let world = mixed_world();
    g.load(&world);
    let mut bad: Vec<_> = non_finite_rays().into_iter().map(|(o, d)| (o, d, INF)).collect();
    bad.extend(BAD_T_MAX.map(|t| (GOOD_RAY.0, GOOD_RAY.1, t)));
    let extreme: Vec<_> = EXTREME_RAYS.iter().map(|&(o, d)| (o, d, INF)).collect();
    let n = world.scene().n_prims;
    let mut extreme_hits = Vec::new();
    for bvh in [true, false] {
        g.set_mode(bvh, 0);
        // A kernel that never returned would fail here: `Commands::wait` gives up on it.
        let (hits, any) = (g.closest(&bad), g.any(&bad));
        for (i, r) in bad.iter().enumerate() {
            if hits[i] != Hit::MISS || any[i] {
                wrong.push(format!("BVH {bvh}: {r:?}: {:?}, any {}", hits[i], any[i]));
            }
        }
        extreme_hits.push(g.closest(&extreme));
    }
    // Any sane answer (primitives tie at these distances), the same both ways.
    for (i, r) in extreme.iter().enumerate() {
        let (bvh, brute) = (extreme_hits[0][i], extreme_hits[1][i]);
        if !sane(&bvh, n, INF) || !sane(&brute, n, INF) || bvh.t != brute.t {
            wrong.push(format!("extreme ray {r:?}: BVH {bvh:?}, brute force {brute:?}"));
        }
    }
    g.assert_no_validation_errors();
    assert!(
        wrong.is_empty(),
        "{} wrong answers on the GPU, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}

#[test]
fn broken_primitives_never_give_nan_and_traversal_returns() {
    let (rays, wrong) = returns_within(120, "broken primitives", || {
        let nan = f32::NAN;
        let tri = |a: [f32; 3], b: [f32; 3], c: [f32; 3]| Triangle {
            v0: [a[0], a[1], a[2], 0.0],
            v1: [b[0], b[1], b[2], 0.0],
            v2: [c[0], c[1], c[2], 0.0],
        };
        let mut tris = cube(2).triangles(Vec3::ZERO);
        tris.extend([
            tri([0.0, 0.0, 0.0], [nan, 0.0, 0.0], [0.0, 1.0, 0.0]),
            tri([0.0, 0.0, 0.5], [INF, 0.0, 0.5], [0.0, 1.0, 0.5]),
            tri([0.0, 0.0, -0.5], [1.0, -INF, -0.5], [0.0, 1.0, -0.5]),
            tri([0.2, 0.2, 0.2], [0.2, 0.2, 0.2], [0.2, 0.2, 0.2]),
            tri([-0.5, -0.5, 0.0], [0.0, 0.0, 0.0], [0.5, 0.5, 0.0]),
            tri([nan; 3], [nan; 3], [nan; 3]),
        ]);
        let spheres = vec![
            Sphere {
                center_radius: [0.3, 0.3, 0.3, 0.0],
            },
            Sphere {
                center_radius: [nan, 0.0, 0.0, 0.5],
            },
            Sphere {
                center_radius: [0.0, 0.0, 0.0, nan],
            },
            Sphere {
                center_radius: [-0.3, 0.2, 0.1, -0.25],
            },
        ];
        let world = World::new(tris, spheres);
        let scene = world.scene();
        let mut rnd = Random::new(7);
        let mut wrong = Vec::new();
        let rays = 20_000;
        for _ in 0..rays {
            let o = rnd.unit() * 3.0;
            let d = (rnd.unit() * 0.8 - o).normalize();
            let bvh = traverse::closest(&scene, o, d, INF);
            let brute = traverse::closest_brute(&scene, o, d, INF);
            if !sane(&bvh, scene.n_prims, INF) || !sane(&brute, scene.n_prims, INF) || bvh.t != brute.t {
                wrong.push(format!("from {o} along {d}: BVH {bvh:?}, brute force {brute:?}"));
            }
            let r = TriRay::new(o, d);
            for prim in 0..scene.n_prims {
                let t = traverse::primitive(&scene, &r, prim, INF).0;
                if t.is_nan() {
                    wrong.push(format!("from {o} along {d}: primitive {prim} gives NaN"));
                }
            }
        }
        (rays, wrong)
    });
    assert!(
        wrong.is_empty(),
        "{} wrong of {rays} rays, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}

// ---------------------------------------------------------------------------------------------
// 4. Spheres against an f64 reference
// ---------------------------------------------------------------------------------------------

/// Largest error allowed of a sphere hit distance against the f64 reference, in units of the
/// `f32` spacing at the reference distance.
const SPHERE_ULPS: f64 = 4.0;
/// The same on the GPU, whose division may be off by 2.5 ulp and square root by more
/// (Vulkan's precision table): measured worst 4.21 ulp on the H100.
const SPHERE_ULPS_GPU: f64 = 8.0;

/// Nearest hit distance in `(0, inf)` of the `f32` ray with the `f32` sphere, in f64 (exact
/// differences, products with 53-bit rounding), and the line's distance from the centre
/// over the radius.
fn sphere_reference(o: Vec3, d: Vec3, center: Vec3, r: f32) -> (Option<f64>, f64) {
    let (o, d, c, r) = (o.as_dvec3(), d.as_dvec3(), center.as_dvec3(), r as f64);
    let f = o - c;
    let a = d.dot(d);
    let perp = f.cross(d).length() / a.sqrt();
    if perp > r {
        return (None, perp / r);
    }
    let b = -f.dot(d);
    let root = (a * (r - perp) * (r + perp)).sqrt();
    let q = if b >= 0.0 { b + root } else { b - root };
    let cc = f.dot(f) - r * r;
    let (t0, t1) = (cc / q, q / a);
    let (near, far) = (t0.min(t1), t0.max(t1));
    let t = if near > 0.0 {
        Some(near)
    } else if far > 0.0 {
        Some(far)
    } else {
        None
    };
    (t, perp / r)
}

/// How the f32 sphere test did against the reference.
#[derive(Debug)]
struct SphereStats {
    /// Largest error allowed, ulps.
    bound: f64,
    rays: usize,
    checked: usize,
    worst_ulps: f64,
    worst_rel: f64,
    wrong: Vec<String>,
}

impl SphereStats {
    fn new(bound: f64) -> SphereStats {
        SphereStats {
            bound,
            rays: 0,
            checked: 0,
            worst_ulps: 0.0,
            worst_rel: 0.0,
            wrong: Vec::new(),
        }
    }

    /// Compares one ray: where the reference hits with the line at most `0.995 r` from the
    /// centre (at most 84 degrees from the normal) the test must hit within
    /// [`SPHERE_ULPS`]; where the line passes beyond `1.005 r` it must miss.
    /// Compares [`intersect::sphere`] (exact products by `fma`, or by splitting: `split`).
    fn check(&mut self, o: Vec3, d: Vec3, center: Vec3, r: f32, split: bool) {
        let s = Sphere {
            center_radius: [center.x, center.y, center.z, r],
        };
        self.compare(o, d, center, r, intersect::sphere(o, d, &s, INF, split));
    }

    /// [`SphereStats::check`] of a distance `got` found elsewhere (on the GPU).
    fn compare(&mut self, o: Vec3, d: Vec3, center: Vec3, r: f32, got: f32) {
        let (want, perp) = sphere_reference(o, d, center, r);
        self.rays += 1;
        match want {
            Some(t) if perp <= 0.995 => {
                self.checked += 1;
                let e = ulps(got, t);
                let rel = (got as f64 - t).abs() / t;
                if e.is_nan() || e > self.worst_ulps {
                    self.worst_ulps = e;
                }
                self.worst_rel = self.worst_rel.max(rel);
                if e.is_nan() || e > self.bound {
                    self.wrong.push(format!(
                        "from {o} along {d} to r={r} at {center}: t = {got}, reference {t} ({e:.1} ulp), line at {perp:.3} r"
                    ));
                }
            }
            None if perp >= 1.005 && got != INF => self.wrong.push(format!(
                "from {o} along {d} to r={r} at {center}: hit at {got}, line at {perp:.3} r"
            )),
            _ => {}
        }
    }

    fn assert_ok(&self, what: &str) {
        eprintln!(
            "{what}: {} rays, {} checked, worst {:.2} ulp, relative {:.2e}, {} wrong",
            self.rays,
            self.checked,
            self.worst_ulps,
            self.worst_rel,
            self.wrong.len()
        );
        assert!(
            self.checked > self.rays / 4,
            "{what}: only {} of {} rays checked",
            self.checked,
            self.rays
        );
        assert!(
            self.wrong.is_empty(),
            "{what}: {} of {} rays wrong (bound {} ulp), e.g.:\n{}",
            self.wrong.len(),
            self.rays,
            self.bound,
            self.wrong[..self.wrong.len().min(8)].join("\n")
        );
    }
}

/// Rays at small far spheres: (origin, direction, centre), radius [`SMALL_R`].
fn small_far_sphere_rays() -> Vec<(Vec3, Vec3, Vec3)> {
    let mut rnd = Random::new(11);
    let mut rays = Vec::new();
    for _ in 0..64 {
        let center = rnd.unit() * 1e4;
        let (u, v) = sampling::basis(center.normalize());
        for o in [Vec3::ZERO, Vec3::new(0.3, -0.7, 0.1), rnd.unit() * rnd.f32()] {
            for _ in 0..32 {
                let (x, y) = sampling::uniform_disk(rnd.f32(), rnd.f32());
                let target = center + (u * x + v * y) * (1.5 * SMALL_R);
                rays.push((o, (target - o).normalize(), center));
            }
        }
    }
    rays
}
const SMALL_R: f32 = 1e-3;

/// Rays at large spheres from just above them: (origin, direction, centre), radius
/// [`LARGE_R`]; the sphere at the origin and a ground sphere below the origin.
fn large_near_sphere_rays() -> Vec<(Vec3, Vec3, Vec3)> {
    let mut rnd = Random::new(12);
    let mut rays = Vec::new();
    let h = 1e-3;
    for _ in 0..64 {
        let n = rnd.unit();
        let ground = Vec3::new(0.0, -LARGE_R, 0.0);
        let viewer = Vec3::new(rnd.range(-1.0, 1.0), h, rnd.range(-1.0, 1.0));
        for (center, o) in [(Vec3::ZERO, n * (LARGE_R + h)), (ground, viewer)] {
            let up = (o - center).normalize();
            for _ in 0..32 {
                // Anywhere down towards the surface, grazing included.
                let (u1, u2) = (rnd.f32(), rnd.f32());
                rays.push((o, sampling::cosine_hemisphere(-up, u1, u2), center));
            }
        }
    }
    rays
}
const LARGE_R: f32 = 1e4;

/// Every ray of `rays` at its sphere of radius `r`, with products by `fma` and by splitting.
fn assert_spheres_match(what: &str, rays: &[(Vec3, Vec3, Vec3)], r: f32) {
    for split in [false, true] {
        let mut st = SphereStats::new(SPHERE_ULPS);
        for &(o, d, c) in rays {
            st.check(o, d, c, r, split);
        }
        st.assert_ok(&format!("{what}, split products {split}"));
    }
}

#[test]
fn small_far_spheres_match_the_f64_reference() {
    assert_spheres_match("radius 1e-3 at 1e4", &small_far_sphere_rays(), SMALL_R);
}

#[test]
fn large_near_spheres_match_the_f64_reference() {
    assert_spheres_match("radius 1e4 from 1e-3 above", &large_near_sphere_rays(), LARGE_R);
}

/// The same sphere rays on the GPU, each sphere alone in its scene, traced through the
/// GPU's BVH: within the same few ulps of the f64 reference.
#[test]
fn spheres_match_the_f64_reference_on_the_gpu() {
    let Some(mut g) = GpuWorld::open("spheres_match_the_f64_reference_on_the_gpu") else {
        return;
    };
    for (what, rays, r) in [
        ("GPU, radius 1e-3 at 1e4", small_far_sphere_rays(), SMALL_R),
        ("GPU, radius 1e4 from 1e-3 above", large_near_sphere_rays(), LARGE_R),
    ] {
        let mut st = SphereStats::new(SPHERE_ULPS_GPU);
        let mut centers: Vec<Vec3> = Vec::new();
        for x in &rays {
            if !centers.contains(&x.2) {
                centers.push(x.2);
            }
        }
        for c in centers {
            let sphere = Sphere {
                center_radius: [c.x, c.y, c.z, r],
            };
            g.load(&World::new(vec![], vec![sphere]));
            let these: Vec<_> = rays.iter().filter(|x| x.2 == c).map(|&(o, d, _)| (o, d, INF)).collect();
            for (&(o, d, _), h) in these.iter().zip(g.closest(&these)) {
                st.compare(o, d, c, r, h.t);
            }
        }
        st.assert_ok(what);
    }
    g.assert_no_validation_errors();
}

// ---------------------------------------------------------------------------------------------
// 5. Light transport
// ---------------------------------------------------------------------------------------------

fn material(kind: MaterialKind, albedo: f32, roughness: f32, ior: f32) -> Material {
    Material {
        albedo: [albedo, albedo, albedo, 0.0],
        kind: kind as u32,
        roughness,
        ior,
        ..Default::default()
    }
}

/// Unpolarised Fresnel reflectance in f64, for light at `cos_i` going into relative index
/// `eta`.
fn fresnel_reference(cos_i: f64, eta: f64) -> f64 {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    (rs * rs + rp * rp) / 2.0
}

/// Monte Carlo albedo of material `m` for light arriving at `cos_i` to a surface with
/// normal `ng` (from outside, or from inside when `inside`): the mean throughput weight of
/// the directions `scatter` returns, with every direction checked for where it may go.
/// Returns (albedo, its standard error, fraction reflected).
fn albedo(m: &Material, cos_i: f32, ng: Vec3, inside: bool, n: usize, rnd: &mut Random) -> (f64, f64, f64) {
    let (t, _) = sampling::basis(ng);
    let sin_i = (1.0 - cos_i * cos_i).max(0.0).sqrt();
    // Arriving on the side of `facing`.
    let facing = if inside { -ng } else { ng };
    let d = (t * sin_i - facing * cos_i).normalize();
    let (mut sum, mut sum2, mut reflected) = (0.0f64, 0.0f64, 0usize);
    for _ in 0..n {
        let s = material::scatter(m, d, ng, ng, FEATURES_ALL, rnd.rng());
        let w = if s.absorbed { 0.0 } else { s.weight.x as f64 };
        assert!(w.is_finite() && w >= 0.0, "{m:?} at cos {cos_i}: weight {:?}", s.weight);
        if !s.absorbed {
            assert!(
                (s.dir.length() - 1.0).abs() < 1e-5,
                "{m:?}: direction {} not unit",
                s.dir
            );
            let up = s.dir.dot(facing);
            if m.kind == MaterialKind::Dielectric as u32 {
                let eta = if inside { 1.0 / m.ior } else { m.ior };
                if up > 0.0 {
                    let mirror = reflect(d, facing);
                    assert!(
                        (s.dir - mirror).length() < 1e-5,
                        "{m:?}: reflection {} not {mirror}",
                        s.dir
                    );
                } else {
                    // Snell: sin_t * eta = sin_i.
                    let sin_t = s.dir.cross(facing).length();
                    assert!(
                        (sin_t * eta - sin_i).abs() < 1e-4,
                        "{m:?} at cos {cos_i}: sin_t {sin_t} eta {eta}"
                    );
                }
            } else {
                assert!(
                    up > 0.0,
                    "{m:?} at cos {cos_i}: scattered through the surface: {}",
                    s.dir
                );
            }
            if m.kind == MaterialKind::Diffuse as u32 {
                // Throughput f cos / pdf with f = albedo / pi.
                let expect = m.albedo[0] as f64 * up as f64 / (std::f64::consts::PI * s.pdf as f64);
                assert!(
                    (w - expect).abs() < 1e-4 * expect.max(1.0),
                    "diffuse weight {w}, f cos / pdf {expect}"
                );
            }
            reflected += (up > 0.0) as usize;
        }
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(0.0);
    (mean, (var / n as f64).sqrt(), reflected as f64 / n as f64)
}

#[test]
fn every_material_conserves_energy() {
    let mut rnd = Random::new(21);
    let n = 40_000;
    let cosines = [1.0, 0.9, 0.7, 0.5, 0.3, 0.1, 0.02];
    let mut materials = vec![
        material(MaterialKind::Diffuse, 1.0, 0.0, 1.0),
        material(MaterialKind::Diffuse, 0.6, 0.0, 1.0),
    ];
    for rough in [0.0, 0.1, 0.3, 0.6, 1.0] {
        materials.push(material(MaterialKind::Metal, 1.0, rough, 1.0));
    }
    for ior in [1.33, 1.5, 2.4] {
        materials.push(material(MaterialKind::Dielectric, 1.0, 0.0, ior));
    }
    let mut worst = 0.0f64;
    for m in &materials {
        for inside in [false, true] {
            for &c in &cosines {
                let ng = rnd.unit();
                let (a, se, refl) = albedo(m, c, ng, inside, n, &mut rnd);
                let bound = m.albedo[0] as f64 + 5.0 * se + 1e-6;
                worst = worst.max(a - m.albedo[0] as f64);
                assert!(a <= bound, "{m:?} at cos {c} inside {inside}: albedo {a} > {bound}");
                assert!(a > 0.0, "{m:?} at cos {c}: absorbs everything");
                if m.kind == MaterialKind::Dielectric as u32 {
                    // Nothing absorbed; the reflected share is Fresnel's.
                    assert_eq!(a, 1.0, "{m:?}: a smooth dielectric neither absorbs nor adds");
                    let eta = if inside { 1.0 / m.ior } else { m.ior } as f64;
                    let r = fresnel_reference(c as f64, eta);
                    let (r32, _) = material::fresnel(c, eta as f32);
                    assert!(
                        (r32 as f64 - r).abs() < 1e-5,
                        "fresnel({c}, {eta}) = {r32}, reference {r}"
                    );
                    let sigma = (r * (1.0 - r) / n as f64).sqrt();
                    assert!(
                        (refl - r).abs() <= 5.0 * sigma + 1e-9,
                        "{m:?} at cos {c} inside {inside}: reflected {refl}, Fresnel {r} (sigma {sigma})"
                    );
                }
                if m.kind == MaterialKind::Metal as u32 && m.roughness == 0.0 {
                    assert_eq!(a, 1.0, "a mirror reflects everything");
                }
            }
        }
    }
    eprintln!("largest albedo above the material's: {worst:.3e}");
}

/// Asserts that `counts` (equal expected counts) pass Pearson's chi-square test at p = 1e-4.
fn assert_chi_square(what: &str, counts: &[u64]) -> f64 {
    let chi2 = chi_square_uniform(counts);
    let crit = chi_square_critical((counts.len() - 1) as f64, 1e-4);
    eprintln!(
        "{what}: chi-square {chi2:.1}, critical {crit:.1} at p = 1e-4, {} bins",
        counts.len()
    );
    assert!(
        chi2 < crit,
        "{what}: chi-square {chi2:.1} over {} bins exceeds {crit:.1} (p < 1e-4)",
        counts.len()
    );
    chi2
}

/// Bin of `x` in `[0, 1)` cut into `k` equal parts.
fn bin(x: f64, k: usize) -> usize {
    ((x * k as f64) as usize).min(k - 1)
}

/// Angle about unit `axis` of unit `d`, as a fraction of a turn, in a frame of our own.
fn turn(d: DVec3, axis: DVec3) -> f64 {
    let helper = if axis.x.abs() < 0.6 { DVec3::X } else { DVec3::Y };
    let e1 = (helper - axis * helper.dot(axis)).normalize();
    let e2 = axis.cross(e1);
    let phi = d.dot(e2).atan2(d.dot(e1));
    (phi / std::f64::consts::TAU).rem_euclid(1.0)
}

/// Counts of directions about `n` binned so that a cosine distribution fills all bins alike:
/// `cos^2` (uniform under pdf cos / pi) times the angle about `n`.
fn cosine_counts(n: Vec3, samples: usize, rnd: &mut Random, sample: impl Fn(Vec3, f32, f32) -> Vec3) -> Vec<u64> {
    let k = 16;
    let mut counts = vec![0u64; k * k];
    let nd = n.as_dvec3().normalize();
    for _ in 0..samples {
        let d = sample(n, rnd.f32(), rnd.f32());
        assert!((d.length() - 1.0).abs() < 1e-5, "not unit: {d}");
        let d = d.as_dvec3();
        let c = d.dot(nd);
        assert!(c >= -1e-6, "below the hemisphere of {n}: {d}");
        counts[bin(c * c, k) * k + bin(turn(d, nd), k)] += 1;
    }
    counts
}

#[test]
fn cosine_hemisphere_passes_chi_square() {
    let mut rnd = Random::new(31);
    let normals = [
        Vec3::Z,
        -Vec3::Z,
        Vec3::new(1e-4, 0.0, -1.0).normalize(),
        Vec3::new(0.0, 1e-3, -1.0).normalize(),
        Vec3::X,
        rnd.unit(),
        rnd.unit(),
    ];
    for n in normals {
        let counts = cosine_counts(n, 256_000, &mut rnd, sampling::cosine_hemisphere);
        assert_chi_square(&format!("cosine_hemisphere about {n}"), &counts);
    }
    // The test can fail: uniform directions over the hemisphere are rejected.
    let uniform = |n: Vec3, u1: f32, u2: f32| {
        let d = sampling::uniform_sphere(u1, u2);
        if d.dot(n) < 0.0 {
            -d
        } else {
            d
        }
    };
    let counts = cosine_counts(Vec3::Z, 256_000, &mut rnd, uniform);
    let chi2 = chi_square_uniform(&counts);
    assert!(
        chi2 > 10.0 * chi_square_critical(255.0, 1e-4),
        "uniform hemisphere not rejected: {chi2}"
    );
}

#[test]
fn uniform_sphere_passes_chi_square() {
    let mut rnd = Random::new(32);
    let k = 16;
    for axis in [DVec3::Z, DVec3::new(0.3, -0.5, 0.8).normalize()] {
        let mut counts = vec![0u64; k * k];
        for _ in 0..256_000 {
            let d = sampling::uniform_sphere(rnd.f32(), rnd.f32());
            assert!((d.length() - 1.0).abs() < 1e-5, "not unit: {d}");
            let d = d.as_dvec3();
            // Archimedes: the height along any axis is uniform in [-1, 1].
            counts[bin((d.dot(axis) + 1.0) / 2.0, k) * k + bin(turn(d, axis), k)] += 1;
        }
        assert_chi_square(&format!("uniform_sphere about {axis}"), &counts);
    }
}

#[test]
fn uniform_triangle_passes_chi_square() {
    let mut rnd = Random::new(33);
    // The triangle cut into k * k congruent triangles of equal probability.
    let k = 16;
    let cell = |b1: f32, b2: f32| {
        let (x, y) = (b1 as f64 * k as f64, b2 as f64 * k as f64);
        let (i, j) = ((x as usize).min(k - 1), (y as usize).min(k - 1));
        let upper = (x - i as f64) + (y - j as f64) >= 1.0;
        // Row j holds 2 (k - j) - 1 cells: k - j upright, k - j - 1 upside down.
        let before: usize = (0..j).map(|r| 2 * (k - r) - 1).sum();
        (before + 2 * i + upper as usize).min(k * k - 1)
    };
    let mut counts = vec![0u64; k * k];
    for _ in 0..256_000 {
        let (b1, b2) = sampling::uniform_triangle(rnd.f32(), rnd.f32());
        assert!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 + 1e-6, "outside: {b1}, {b2}");
        counts[cell(b1, b2)] += 1;
    }
    assert_chi_square("uniform_triangle", &counts);
    // The test can fail: the naive (u1, u2 (1 - u1)) crowds the corner b1 = 1.
    let mut naive = vec![0u64; k * k];
    for _ in 0..256_000 {
        let (u1, u2) = (rnd.f32(), rnd.f32());
        naive[cell(u1, u2 * (1.0 - u1))] += 1;
    }
    let chi2 = chi_square_uniform(&naive);
    assert!(
        chi2 > 10.0 * chi_square_critical(255.0, 1e-4),
        "naive triangle sampling not rejected: {chi2}"
    );
}

#[test]
fn uniform_disk_passes_chi_square() {
    let mut rnd = Random::new(34);
    let k = 16;
    let mut counts = vec![0u64; k * k];
    for _ in 0..256_000 {
        let (x, y) = sampling::uniform_disk(rnd.f32(), rnd.f32());
        let (x, y) = (x as f64, y as f64);
        let r2 = x * x + y * y;
        assert!(r2 <= 1.0 + 1e-6, "outside the disk: {x}, {y}");
        let phi = (y.atan2(x) / std::f64::consts::TAU).rem_euclid(1.0);
        counts[bin(r2, k) * k + bin(phi, k)] += 1;
    }
    assert_chi_square("uniform_disk", &counts);
}

#[test]
fn uniform_ball_passes_chi_square() {
    let mut rnd = Random::new(35);
    let k = 8;
    let mut counts = vec![0u64; k * k * k];
    for _ in 0..512_000 {
        let p = sampling::uniform_ball(rnd.f32(), rnd.f32(), rnd.f32()).as_dvec3();
        let r = p.length();
        assert!(r <= 1.0 + 1e-6, "outside the ball: {p}");
        // Uniform in the ball: r^3, the height of the direction and its angle are uniform.
        let dir = if r > 0.0 { p / r } else { DVec3::Z };
        counts[(bin(r * r * r, k) * k + bin((dir.z + 1.0) / 2.0, k)) * k + bin(turn(dir, DVec3::Z), k)] += 1;
    }
    assert_chi_square("uniform_ball", &counts);
}

#[test]
fn chi_square_critical_values_match_tables() {
    // Tabulated upper quantiles: (dof, p, value).
    for (dof, p, table) in [
        (255.0, 1e-4, 347.654),
        (511.0, 1e-4, 638.528),
        (10.0, 0.05, 18.307),
        (100.0, 0.01, 135.807),
    ] {
        let got = chi_square_critical(dof, p);
        assert!(
            (got - table).abs() / table < 0.01,
            "chi-square({dof}, {p}) = {got}, table {table}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 6. LBVH edge cases
// ---------------------------------------------------------------------------------------------

fn tri(a: Vec3, b: Vec3, c: Vec3) -> Triangle {
    Triangle {
        v0: [a.x, a.y, a.z, 0.0],
        v1: [b.x, b.y, b.z, 0.0],
        v2: [c.x, c.y, c.z, 0.0],
    }
}

/// A random small triangle near `center`.
fn small_triangle(rnd: &mut Random, center: Vec3, size: f32) -> Triangle {
    tri(
        center + rnd.unit() * size,
        center + rnd.unit() * size,
        center + rnd.unit() * size,
    )
}

/// Inputs that stress the builder: one and two primitives, all centroids equal (the Morton
/// codes all equal: only the index tie-break orders them), one far outlier (every other
/// centroid collapses into a few 30-bit codes), and zero-area triangles (points and
/// segments) among ordinary ones. The indices of the zero-area ones come last.
fn lbvh_edge_cases() -> Vec<(&'static str, World, Vec<u32>)> {
    let mut rnd = Random::new(31);
    let one = vec![tri(
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    )];
    let two = vec![
        one[0],
        tri(
            Vec3::new(-1.0, -1.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
            Vec3::new(1.0, -1.0, 1.0),
        ),
    ];
    let sphere = |c: Vec3, r: f32| Sphere {
        center_radius: [c.x, c.y, c.z, r],
    };
    // Triangles around one centroid: each is `c + a, c + b, c - a - b`.
    let same_centroid: Vec<Triangle> = (0..300)
        .map(|_| {
            let (a, b) = (rnd.unit() * rnd.range(0.1, 1.0), rnd.unit() * rnd.range(0.1, 1.0));
            let c = Vec3::new(0.5, 0.25, -0.5);
            tri(c + a, c + b, c - a - b)
        })
        .collect();
    let mut outlier: Vec<Triangle> = (0..2000)
        .map(|_| {
            let c = rnd.unit();
            small_triangle(&mut rnd, c, 0.05)
        })
        .collect();
    outlier.push(small_triangle(&mut rnd, Vec3::new(1e6, -1e6, 1e6), 0.05));
    let mut degenerate: Vec<Triangle> = (0..500)
        .map(|_| {
            let c = rnd.unit();
            small_triangle(&mut rnd, c, 0.1)
        })
        .collect();
    let n = degenerate.len() as u32;
    for _ in 0..200 {
        let p = rnd.unit();
        let q = p + rnd.unit() * 0.2;
        degenerate.push(tri(p, p, p));
        degenerate.push(tri(p, q, p + (q - p) * 0.5));
    }
    let zero_area: Vec<u32> = (n..degenerate.len() as u32).collect();
    vec![
        ("one triangle", World::new(one, vec![]), vec![]),
        ("two triangles", World::new(two, vec![]), vec![]),
        ("one sphere", World::new(vec![], vec![sphere(Vec3::ZERO, 1.0)]), vec![]),
        (
            "a triangle and a sphere",
            World::new(vec![tri(Vec3::X, Vec3::Y, Vec3::Z)], vec![sphere(Vec3::ZERO, 0.5)]),
            vec![],
        ),
        (
            "300 triangles with one centroid",
            World::new(same_centroid, vec![]),
            vec![],
        ),
        (
            "300 spheres with one centre",
            World::new(
                vec![],
                (0..300).map(|k| sphere(Vec3::ONE, 0.01 * (k + 1) as f32)).collect(),
            ),
            vec![],
        ),
        ("2000 triangles and one at 1e6", World::new(outlier, vec![]), vec![]),
        (
            "500 triangles and 400 of zero area",
            World::new(degenerate, vec![]),
            zero_area,
        ),
    ]
}

/// Random rays through the unit ball, and rays at the far outlier (`t_max` 10 for both).
fn edge_case_rays(seed: u32) -> Vec<(Vec3, Vec3, f32)> {
    let mut rnd = Random::new(seed);
    let mut rays: Vec<_> = (0..3000)
        .map(|_| {
            let o = rnd.unit() * 3.0;
            (o, rnd.unit() * 0.9 - o, 10.0)
        })
        .collect();
    let far = Vec3::new(1e6, -1e6, 1e6);
    rays.extend((0..100).map(|_| {
        // Every ray only as far as its own cluster: across 1e6 a hit on the other is
        // rounding noise (the GPU's unfused fma makes it differ between box and triangle).
        let o = far + rnd.unit() * 2.0;
        (o, far + rnd.unit() * 0.03 - o, 10.0)
    }));
    rays
}

/// The builder's hard inputs on both backends: each BVH passes the validator (the CPU
/// executor's here, the GPU's in [`GpuWorld::load`]), closest hits through it equal brute
/// force, and zero-area triangles are never hit.
#[test]
fn lbvh_edge_cases_trace_like_brute_force() {
    let mut g = GpuWorld::open("lbvh_edge_cases_trace_like_brute_force");
    let mut wrong = Vec::new();
    for (name, world, zero_area) in lbvh_edge_cases() {
        let bvh = raytrace::cpu::build(
            &world.tris,
            &world.spheres,
            raytrace::bvh::BuildOptions::lbvh(raytrace::bvh::MortonBits::B30),
        )
        .0;
        if let Err(e) = raytrace::bvh::validate(&bvh.nodes, &bvh.parents, &world.tris, &world.spheres) {
            wrong.push(format!("{name}: CPU BVH invalid: {e}"));
            continue;
        }
        let scene = world.scene();
        let rays = edge_case_rays(41);
        let brute: Vec<Hit> = rays
            .iter()
            .map(|&(o, d, t)| traverse::closest_brute(&scene, o, d, t))
            .collect();
        let hits = brute.iter().filter(|h| h.prim != INVALID).count();
        if hits < 20 {
            wrong.push(format!("{name}: only {hits} rays hit"));
        }
        // The restructured tree too (on the CPU: the GPU builds it bit for bit alike,
        // `build_gpu_vs_cpu`).
        let opts = raytrace::bvh::BuildOptions {
            treelets: true,
            ..raytrace::bvh::BuildOptions::lbvh(raytrace::bvh::MortonBits::B30)
        };
        let restructured = raytrace::cpu::build(&world.tris, &world.spheres, opts).0;
        if let Err(e) = raytrace::bvh::validate(&restructured.nodes, &restructured.parents, &world.tris, &world.spheres)
        {
            wrong.push(format!("{name}: CPU BVH with treelets invalid: {e}"));
            continue;
        }
        let treelet_nodes = restructured.traced_nodes();
        let treelet_scene = traverse::Scene {
            nodes: bytemuck::cast_slice(&treelet_nodes),
            features: scene.features & !shared::types::VARIANT_WIDE_BVH,
            ..scene
        };
        let mut backends = vec![
            (
                "CPU",
                rays.iter()
                    .map(|&(o, d, t)| traverse::closest(&scene, o, d, t))
                    .collect::<Vec<_>>(),
            ),
            (
                "CPU, treelets",
                rays.iter()
                    .map(|&(o, d, t)| traverse::closest(&treelet_scene, o, d, t))
                    .collect::<Vec<_>>(),
            ),
        ];
        // The walk of the tree alone (a device whose binding cannot hold the pairs) visits
        // the same nodes in the same order: the same hits, any-hit answers included.
        if world.spheres.len() + world.tris.len() > 1 && scene.features & shared::types::VARIANT_WIDE_BVH == 0 {
            let tree_only = traverse::Scene {
                nodes: bytemuck::cast_slice(&bvh.nodes),
                features: scene.features | shared::types::VARIANT_NO_PAIRS,
                ..scene
            };
            for (i, &(o, d, t)) in rays.iter().enumerate() {
                let (a, b) = (
                    traverse::closest(&scene, o, d, t),
                    traverse::closest(&tree_only, o, d, t),
                );
                let (any_a, any_b) = (traverse::any(&scene, o, d, t), traverse::any(&tree_only, o, d, t));
                if a != b || any_a != any_b {
                    wrong.push(format!(
                        "{name}: ray {i}: pairs {a:?} {any_a}, tree alone {b:?} {any_b}"
                    ));
                }
            }
        }
        let mut brutes = vec![brute.clone(), brute];
        if let Some(g) = g.as_mut() {
            // Against the GPU's own brute force: its division rounds differently, so rays
            // grazing a lone triangle's edge (the outlier's) may hit there and miss here.
            g.load(&world);
            backends.push(("GPU", g.closest(&rays)));
            g.set_mode(false, 0);
            brutes.push(g.closest(&rays));
        }
        for ((backend, got), brute) in backends.into_iter().zip(&brutes) {
            for (i, (h, b)) in got.iter().zip(brute).enumerate() {
                if zero_area.contains(&h.prim) {
                    wrong.push(format!("{name}, {backend}: ray {i} hit zero-area triangle {}", h.prim));
                } else if h.prim != b.prim && ulps(h.t, b.t as f64) > TIE_ULPS {
                    wrong.push(format!("{name}, {backend}: ray {i}: {h:?}, brute force {b:?}"));
                }
            }
        }
    }
    if let Some(g) = &g {
        g.assert_no_validation_errors();
    }
    assert!(
        wrong.is_empty(),
        "{} wrong, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}
