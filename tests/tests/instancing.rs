//! Instancing (`shared::instance`, `raytrace::bvh::build_levels`): both levels built by the CPU
//! executor pass the validator; queries through the two-level walk equal the same scene
//! flattened into world space; closed meshes stay closed through rotated, scaled and mirrored
//! instances near and far from the origin; bad instances are refused by name.

/// Read by the suite's helpers (`common::World`).
const WIDE: bool = false;

mod common;

use common::{cube, icosphere, octahedron, Mesh, Random, OFFSETS};
use raytrace::bvh::{
    build_levels, build_levels_coded, validate_levels, BuildOptions, Levels, MeshPrims, MortonBits, Placement,
};
use raytrace::inputs::hard_cases::{closed_meshes, INSIDE};
use shared::glam::{DVec3, Mat3, Vec3};
use shared::math::fma;
use shared::traverse::{self, Scene};
use shared::types::{Hit, Node, Sphere, Triangle, FEATURES_ALL, FEATURE_INSTANCES, INVALID};

fn opts() -> BuildOptions {
    BuildOptions::lbvh(MortonBits::B30)
}

/// Model to world: rotation by `angle` about `axis`, then scale, then translation.
fn rows(axis: Vec3, angle: f32, scale: Vec3, translation: Vec3) -> [[f32; 4]; 3] {
    let m = Mat3::from_axis_angle(axis.normalize(), angle) * Mat3::from_diagonal(scale);
    let r = |k: usize| {
        let v = m.row(k);
        [v.x, v.y, v.z, translation[k]]
    };
    [r(0), r(1), r(2)]
}

/// `rows * [p, 1]` as the transform stage rounds it.
fn apply(rows: &[[f32; 4]; 3], p: [f32; 4]) -> [f32; 4] {
    let r = |q: [f32; 4]| fma(q[0], p[0], fma(q[1], p[1], fma(q[2], p[2], q[3])));
    [r(rows[0]), r(rows[1]), r(rows[2]), 0.0]
}

/// `rows * [p, 1]` in f64.
fn apply64(rows: &[[f32; 4]; 3], p: Vec3) -> DVec3 {
    DVec3::from_array(std::array::from_fn(|k| {
        let q = rows[k];
        q[0] as f64 * p.x as f64 + q[1] as f64 * p.y as f64 + q[2] as f64 * p.z as f64 + q[3] as f64
    }))
}

fn prims(mesh: &Mesh) -> MeshPrims {
    MeshPrims {
        tris: mesh.triangles(Vec3::ZERO),
        spheres: Vec::new(),
    }
}

/// The instanced scene flattened: every instance's primitives in world space, as the
/// transform stage makes them (spheres: centre moved, radius times the uniform scale).
fn flatten(meshes: &[MeshPrims], placements: &[Placement], scales: &[f32]) -> (Vec<Triangle>, Vec<Sphere>) {
    let mut tris = Vec::new();
    let mut spheres = Vec::new();
    for (p, &scale) in placements.iter().zip(scales) {
        let m = &meshes[p.mesh];
        tris.extend(m.tris.iter().map(|t| Triangle {
            v0: apply(&p.rows, t.v0),
            v1: apply(&p.rows, t.v1),
            v2: apply(&p.rows, t.v2),
        }));
        spheres.extend(m.spheres.iter().map(|s| {
            let c = apply(&p.rows, s.center_radius);
            Sphere {
                center_radius: [c[0], c[1], c[2], s.center_radius[3] * scale],
            }
        }));
    }
    (tris, spheres)
}

fn flat_scene<'a>(tris: &'a [Triangle], spheres: &'a [Sphere]) -> Scene<'a> {
    Scene {
        tris: bytemuck::cast_slice(tris),
        spheres,
        nodes: &[],
        wide: &[],
        order: &[],
        n_tris: tris.len() as u32,
        n_prims: (tris.len() + spheres.len()) as u32,
        top: 0,
        instances: &[],
        n_instances: 0,
        coverage: shared::alpha::Coverage::NONE,
        features: FEATURES_ALL,
    }
}

/// Three meshes and a mesh of two spheres; `count` instances of them around `offset`,
/// rotated, scaled (uniformly for the spheres, per axis and mirrored for the rest).
fn instanced(offset: Vec3, count: usize, seed: u32) -> (Vec<MeshPrims>, Vec<Placement>, Vec<f32>) {
    let mut meshes = vec![prims(&icosphere(2)), prims(&cube(4)), prims(&octahedron(4))];
    meshes.push(MeshPrims {
        tris: Vec::new(),
        spheres: vec![
            Sphere {
                center_radius: [0.5, 0.0, 0.0, 0.4],
            },
            Sphere {
                center_radius: [-0.5, 0.25, 0.0, 0.3],
            },
        ],
    });
    let mut rng = Random::new(seed);
    let mut placements = Vec::new();
    let mut scales = Vec::new();
    for k in 0..count {
        let mesh = k % meshes.len();
        let axis = rng.unit();
        let angle = rng.range(0.0, std::f32::consts::TAU);
        let t = offset + Vec3::new(rng.range(-20.0, 20.0), rng.range(-20.0, 20.0), rng.range(-20.0, 20.0));
        let (scale, uniform) = if meshes[mesh].spheres.is_empty() {
            let mirror = if k % 3 == 0 { -1.0 } else { 1.0 };
            (
                Vec3::new(mirror * rng.range(0.5, 2.0), rng.range(0.5, 2.0), rng.range(0.5, 2.0)),
                0.0,
            )
        } else {
            let s = rng.range(0.5, 2.0);
            (Vec3::splat(s), s)
        };
        placements.push(Placement {
            mesh,
            object: placements.len() as u32,
            rows: rows(axis, angle, scale, t),
        });
        scales.push(uniform);
    }
    (meshes, placements, scales)
}

fn levels(meshes: &[MeshPrims], placements: &[Placement]) -> Levels {
    let l = build_levels(meshes, placements, opts()).expect("the levels build");
    validate_levels(&l, meshes, placements).expect("both levels are valid");
    l
}

#[test]
fn instanced_queries_equal_the_flattened_scene() {
    for (run, offset) in [Vec3::ZERO, Vec3::new(1e3, -1e3, 1e3)].into_iter().enumerate() {
        let (meshes, placements, scales) = instanced(offset, 48, 7 + run as u32);
        let l = levels(&meshes, &placements);
        let scene = l.scene(FEATURES_ALL);
        let (tris, spheres) = flatten(&meshes, &placements, &scales);
        let flat = flat_scene(&tris, &spheres);
        // Each instance's first primitive in the flattened scene.
        let mut firsts = Vec::new();
        let (mut nt, mut ns) = (0u32, 0u32);
        for p in &placements {
            firsts.push((nt, ns));
            nt += meshes[p.mesh].tris.len() as u32;
            ns += meshes[p.mesh].spheres.len() as u32;
        }
        let mut rng = Random::new(99 + run as u32);
        let (mut hits, mut misses, mut neighbours) = (0, 0, 0);
        let tolerance = 1e-4 * (1.0 + offset.length());
        for i in 0..3000 {
            // Rays from around the scene towards a random instance's centre (most hit), or
            // outward (most miss).
            let origin = offset + 30.0 * rng.unit();
            let target = placements[i % placements.len()].rows.map(|r| r[3]);
            let target = Vec3::from_array(target) + 0.7 * rng.unit();
            let dir = if i % 5 == 4 { origin - offset } else { target - origin };
            let (h, instance) = traverse::closest_instance(&scene, origin, dir, f32::INFINITY);
            let reference = traverse::closest_brute(&flat, origin, dir, f32::INFINITY);
            assert_eq!(
                h.prim == INVALID,
                reference.prim == INVALID,
                "offset {offset}, ray {i}: instanced {h:?} (instance {instance}), flattened {reference:?}"
            );
            if reference.prim == INVALID {
                misses += 1;
                assert_eq!(instance, INVALID);
                continue;
            }
            hits += 1;
            assert!(
                (h.t - reference.t).abs() <= tolerance * reference.t.max(1.0),
                "offset {offset}, ray {i}: t {} instanced, {} flattened",
                h.t,
                reference.t
            );
            // The same primitive of the same instance.
            let inst = l.instances[instance as usize];
            let (ft, fs) = firsts[instance as usize];
            let local = if h.prim < scene.n_tris {
                h.prim - inst.tri0
            } else {
                inst.n_tris + (h.prim - scene.n_tris - inst.sphere0)
            };
            let m = &meshes[placements[instance as usize].mesh];
            let expected = if local < m.tris.len() as u32 {
                ft + local
            } else {
                flat.n_tris + fs + (local - m.tris.len() as u32)
            };
            if expected != reference.prim {
                // A ray through an edge or vertex, which rounding moves by a few ulps between
                // model and world space: the hit is at the same distance and at an edge.
                let edge = h.u.min(h.v).min(1.0 - h.u - h.v);
                assert!(
                    edge < 1e-3 && (h.t - reference.t).abs() <= tolerance * reference.t.max(1.0),
                    "offset {offset}, ray {i}: primitive {expected} ({h:?}), the flattened scene's {reference:?}"
                );
                neighbours += 1;
            }
            // Any-hit queries agree.
            assert!(
                traverse::any(&scene, origin, dir, f32::INFINITY),
                "ray {i}: any-hit missed"
            );
            assert!(
                !traverse::any(&scene, origin, dir, reference.t * 0.999),
                "ray {i}: any-hit found something nearer than the closest hit"
            );
        }
        assert!(
            hits > 1500 && misses > 300,
            "{hits} hits, {misses} misses: the rays test too little"
        );
        assert!(
            neighbours <= 3,
            "{neighbours} rays hit another primitive than the flattened scene's"
        );
    }
}

#[test]
fn closed_meshes_stay_closed_through_instances() {
    let transforms = [
        ("rotated", rows(Vec3::new(1.0, 2.0, 3.0), 0.7, Vec3::ONE, Vec3::ZERO)),
        (
            "scaled per axis",
            rows(Vec3::Y, 0.0, Vec3::new(3.0, 0.25, 1.5), Vec3::ZERO),
        ),
        ("mirrored", rows(Vec3::Z, 0.3, Vec3::new(-1.0, 1.0, 1.0), Vec3::ZERO)),
        (
            "all three",
            rows(Vec3::new(-2.0, 1.0, 0.5), 2.1, Vec3::new(-0.5, 2.0, 1.25), Vec3::ZERO),
        ),
    ];
    let mut leaks = Vec::new();
    let mut total = 0;
    for (name, mesh) in closed_meshes() {
        let meshes = vec![prims(&mesh), prims(&cube(1))];
        for (how, base) in &transforms {
            for offset in OFFSETS {
                let mut rows = *base;
                for (k, r) in rows.iter_mut().enumerate() {
                    r[3] = offset + k as f32;
                }
                // The mesh, and two cubes beside it so the top level has inner nodes.
                let mut placements = vec![Placement {
                    mesh: 0,
                    object: 0,
                    rows,
                }];
                for k in 0..2 {
                    let mut r = rows;
                    r[0][3] += 10.0 * (k as f32 + 1.0);
                    placements.push(Placement {
                        mesh: 1,
                        object: k + 1,
                        rows: r,
                    });
                }
                let l = levels(&meshes, &placements);
                let scene = l.scene(FEATURES_ALL);
                let targets = mesh.moved(Vec3::ZERO);
                let edges = mesh.edges();
                let targets: Vec<Vec3> = targets
                    .iter()
                    .copied()
                    .chain(
                        edges
                            .iter()
                            .map(|&[a, b]| (targets[a as usize] + targets[b as usize]) * 0.5),
                    )
                    .collect();
                for inside in INSIDE {
                    let o = apply64(&rows, Vec3::from(inside));
                    for &t in &targets {
                        let d = apply64(&rows, t) - o;
                        let (o, d) = (o.as_vec3(), d.as_vec3());
                        total += 1;
                        let h = traverse::closest(&scene, o, d, f32::INFINITY);
                        if h.prim == INVALID || !traverse::any(&scene, o, d, f32::INFINITY) {
                            leaks.push(format!("{name}, {how}, offset {offset}: ray {o} -> {d} leaks ({h:?})"));
                        }
                    }
                }
            }
        }
    }
    assert!(total > 10_000, "only {total} rays");
    assert!(
        leaks.is_empty(),
        "{} of {total} rays leak:\n{}",
        leaks.len(),
        leaks[..leaks.len().min(10)].join("\n")
    );
}

#[test]
fn the_validator_checks_both_levels() {
    let (meshes, placements, _) = instanced(Vec3::ZERO, 12, 3);
    let l = levels(&meshes, &placements);
    assert_eq!(l.instances.len(), 12);
    assert_eq!(l.top_nodes().len(), 2 * 12 - 1);
    // An instance's world box that misses part of its mesh.
    let mut bad = l.clone();
    bad.boxes[5].v1[0] -= 0.5;
    let e = validate_levels(&bad, &meshes, &placements).expect_err("a shrunk instance box");
    assert!(e.contains("instance 5") || e.contains("top level"), "{e}");
    // The same for an instance of the spheres' mesh (instance 3: mesh 3).
    assert_eq!(placements[3].mesh, 3);
    let mut bad = l.clone();
    bad.boxes[3].v1[1] = (bad.boxes[3].v0[1] + bad.boxes[3].v1[1]) / 2.0;
    let e = validate_levels(&bad, &meshes, &placements).expect_err("a shrunk box of spheres");
    assert!(e.contains("instance 3"), "{e}");
    // A mesh's node box that misses its primitives.
    let mut bad = l.clone();
    let first = bad.mesh_nodes[1] as usize;
    bad.nodes[first] = Node {
        max: [0.0; 3],
        ..bad.nodes[first]
    };
    let e = validate_levels(&bad, &meshes, &placements).expect_err("a shrunk mesh node");
    assert!(e.contains("mesh 1"), "{e}");
}

#[test]
fn a_miss_of_every_instance_and_a_scene_of_one_instance_are_handled() {
    let meshes = vec![prims(&cube(1))];
    let one = vec![Placement {
        mesh: 0,
        object: 0,
        rows: rows(Vec3::X, 0.5, Vec3::splat(2.0), Vec3::new(5.0, 0.0, 0.0)),
    }];
    let l = levels(&meshes, &one);
    let scene = l.scene(FEATURES_ALL);
    let h = traverse::closest(&scene, Vec3::ZERO, Vec3::X, f32::INFINITY);
    assert!(h.prim != INVALID && (h.t - (5.0 - 2.0 * 1.0)).abs() < 0.7, "{h:?}");
    assert_eq!(
        traverse::closest(&scene, Vec3::ZERO, -Vec3::X, f32::INFINITY),
        Hit::MISS
    );
    assert!(!traverse::any(&scene, Vec3::ZERO, Vec3::X, 1.0));
    // Non-finite rays miss.
    assert_eq!(traverse::closest(&scene, Vec3::NAN, Vec3::X, f32::INFINITY), Hit::MISS);
    assert_eq!(
        traverse::closest(&scene, Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0), f32::INFINITY),
        Hit::MISS
    );
    // No instances: nothing to hit.
    let empty = levels(&meshes, &[]);
    assert_eq!(
        empty.scene(FEATURES_ALL).features & FEATURE_INSTANCES,
        FEATURE_INSTANCES
    );
    assert_eq!(
        traverse::closest(&empty.scene(FEATURES_ALL), Vec3::ZERO, Vec3::X, f32::INFINITY),
        Hit::MISS
    );
}

#[test]
fn bad_instances_are_refused_by_name() {
    let meshes = vec![prims(&cube(1)), MeshPrims::default()];
    let good = Placement {
        mesh: 0,
        object: 0,
        rows: rows(Vec3::X, 0.0, Vec3::ONE, Vec3::ZERO),
    };
    let cases = [
        (
            Placement {
                rows: rows(Vec3::X, 0.0, Vec3::new(1.0, 0.0, 1.0), Vec3::ZERO),
                ..good
            },
            "singular",
        ),
        (
            Placement {
                rows: rows(Vec3::X, 0.0, Vec3::ONE, Vec3::new(f32::NAN, 0.0, 0.0)),
                ..good
            },
            "non-finite",
        ),
        (Placement { mesh: 7, ..good }, "mesh 7"),
        (Placement { mesh: 1, ..good }, "no primitives"),
    ];
    for (bad, what) in cases {
        let e = build_levels(&meshes, &[good, Placement { object: 1, ..bad }], opts()).expect_err(what);
        assert!(e.contains("instance 1") && e.contains(what), "{what}: {e}");
    }
}

#[test]
fn gpu_queries_through_instances_equal_the_cpu_and_stay_closed() {
    let Some(mut g) = common::GpuWorld::open("gpu_queries_through_instances_equal_the_cpu_and_stay_closed") else {
        return;
    };
    // Random rays at an instanced scene: the GPU's answers are the CPU's.
    let (meshes, placements, _) = instanced(Vec3::new(1e3, 0.0, -1e3), 24, 11);
    let l = levels(&meshes, &placements);
    let scene = l.scene(FEATURES_ALL);
    g.load_levels(&l);
    let mut rng = Random::new(5);
    let rays: Vec<(Vec3, Vec3, f32)> = (0..2000)
        .map(|i| {
            let origin = Vec3::new(1e3, 0.0, -1e3) + 30.0 * rng.unit();
            let target = Vec3::from_array(placements[i % placements.len()].rows.map(|r| r[3])) + 0.7 * rng.unit();
            (origin, target - origin, f32::INFINITY)
        })
        .collect();
    let gpu = g.closest(&rays);
    let any = g.any(&rays);
    let mut hits = 0;
    for (i, (&(o, d, t_max), h)) in rays.iter().zip(&gpu).enumerate() {
        let c = traverse::closest(&scene, o, d, t_max);
        assert_eq!(h.prim, c.prim, "ray {i}: GPU {h:?}, CPU {c:?}");
        // Lavapipe's `fma` rounds twice: the model-space rays differ in their last bits.
        assert!(
            (h.t - c.t).abs() <= 2e-4 * c.t.max(1.0) || h.prim == INVALID,
            "ray {i}: GPU {h:?}, CPU {c:?}"
        );
        assert_eq!(any[i], c.prim != INVALID, "ray {i}: any-hit");
        hits += usize::from(c.prim != INVALID);
    }
    assert!(hits > 1000, "{hits} hits: the rays test too little");
    // Rays from inside a closed mesh, rotated, scaled and mirrored, at every offset, aimed
    // at its vertices and edges: every one hits.
    let mesh = icosphere(3);
    let meshes = vec![prims(&mesh), prims(&cube(1))];
    let base = rows(Vec3::new(-2.0, 1.0, 0.5), 2.1, Vec3::new(-0.5, 2.0, 1.25), Vec3::ZERO);
    for offset in OFFSETS {
        let mut r0 = base;
        for (k, r) in r0.iter_mut().enumerate() {
            r[3] = offset + k as f32;
        }
        let mut r1 = r0;
        r1[0][3] += 10.0;
        let placements = [
            Placement {
                mesh: 0,
                object: 0,
                rows: r0,
            },
            Placement {
                mesh: 1,
                object: 1,
                rows: r1,
            },
        ];
        let l = levels(&meshes, &placements);
        g.load_levels(&l);
        let rays: Vec<(Vec3, Vec3, f32)> = common::rays_at_vertices_and_edges(&mesh, Vec3::ZERO)
            .into_iter()
            .map(|(o, d)| {
                let wo = apply64(&r0, o);
                let wd = apply64(&r0, o + d) - wo;
                (wo.as_vec3(), wd.as_vec3(), f32::INFINITY)
            })
            .collect();
        let hits = g.closest(&rays);
        let leaks = hits.iter().filter(|h| h.prim == INVALID).count();
        let any_leaks = g.any(&rays).iter().filter(|&&a| !a).count();
        assert!(
            leaks == 0 && any_leaks == 0,
            "offset {offset}: {leaks} closest and {any_leaks} any-hit queries of {} leak",
            rays.len()
        );
    }
    g.assert_no_validation_errors();
}

#[test]
fn gpu_builds_both_levels_as_the_cpu_executor_does() {
    let Some(gpu) = integration_tests::gpu("gpu_builds_both_levels_as_the_cpu_executor_does") else {
        return;
    };
    let kernels = std::sync::Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
    for (run, offset) in [Vec3::ZERO, Vec3::new(1e5, -1e5, 1e5)].into_iter().enumerate() {
        let (meshes, placements, _) = instanced(offset, 40, 21 + run as u32);
        let cpu = levels(&meshes, &placements);
        let mut g = raytrace::gpu::GpuLevels::new(&gpu, &kernels, &meshes, &placements, opts()).expect("GPU levels");
        assert_eq!(
            g.boxes().expect("boxes"),
            cpu.boxes,
            "offset {offset}: the instances' world boxes"
        );
        assert_eq!(
            g.nodes().expect("nodes"),
            cpu.nodes,
            "offset {offset}: both levels' nodes"
        );
        // The instances move: the top level built again equals the CPU's of the moved scene.
        let moved: Vec<Placement> = placements
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let turn = rows(Vec3::Y, 0.1 * k as f32, Vec3::ONE, Vec3::new(0.5, 0.0, -0.25));
                let m = |a: &[[f32; 4]; 3]| {
                    shared::glam::Affine3A::from_cols_array_2d(&std::array::from_fn(|c| {
                        std::array::from_fn(|r| a[r][c])
                    }))
                };
                let c = m(&turn) * m(&p.rows);
                let cols = c.to_cols_array_2d();
                Placement {
                    rows: std::array::from_fn(|r| [cols[0][r], cols[1][r], cols[2][r], cols[3][r]]),
                    ..*p
                }
            })
            .collect();
        // The frame after a build refits the top level: the CPU's refit of its top level
        // over the moved instances' boxes.
        let rows_of = |ps: &[Placement]| ps.iter().map(|p| p.rows).collect::<Vec<_>>();
        let top_opts = raytrace::bvh::top_build(opts());
        let top = raytrace::cpu::build(&cpu.boxes, &[], top_opts).0;
        assert_eq!(&cpu.nodes[cpu.top as usize..], &top.nodes[..]);
        g.set_transforms(&rows_of(&moved)).expect("new transforms");
        g.rebuild_top().expect("top level");
        assert_eq!(g.top_refits(), Some(1));
        let fresh = levels(&meshes, &moved);
        // (restructuring it again, as the first `TOP_ROUNDS - 1` refits after a build do)
        let refit = if raytrace::bvh::TOP_ROUNDS > 1 {
            raytrace::cpu::refit_round
        } else {
            raytrace::cpu::refit
        };
        let refit = refit(&top, &fresh.boxes, &[], top_opts).expect("refit");
        let mut refitted = fresh.clone();
        refitted.nodes.truncate(fresh.top as usize);
        refitted.nodes.extend_from_slice(&refit.nodes);
        refitted.top_parents = refit.parents;
        raytrace::bvh::validate_levels(&refitted, &meshes, &moved).expect("valid refit levels");
        assert_eq!(
            g.nodes().expect("nodes"),
            refitted.nodes,
            "offset {offset}: the moved scene's levels, refit"
        );
        // Built again: the CPU's levels of the moved scene, its instances coded in the
        // bounds of the first build's (which the GPU kept through the refit).
        g.set_top_refits(0);
        assert_eq!(
            g.top_code_bounds().expect("bounds"),
            Some(top.bounds),
            "offset {offset}: the last build's bounds"
        );
        g.rebuild_top().expect("top level");
        assert_eq!(g.top_refits(), Some(0));
        let cpu = build_levels_coded(&meshes, &moved, opts(), Some(&top.bounds)).expect("levels");
        validate_levels(&cpu, &meshes, &moved).expect("valid levels");
        assert_eq!(
            g.nodes().expect("nodes"),
            cpu.nodes,
            "offset {offset}: the moved scene's levels"
        );
        // Built again over the same boxes: coded in their own bounds, the CPU's levels
        // without a hint.
        g.rebuild_top().expect("top level");
        assert_eq!(
            g.nodes().expect("nodes"),
            fresh.nodes,
            "offset {offset}: the moved scene built again"
        );
        let cpu = fresh;
        // A singular transform is refused by its instance's number, and nothing changes.
        let mut bad = rows_of(&moved);
        bad[3][1] = [0.0; 4];
        let e = g.set_transforms(&bad).expect_err("a singular transform").to_string();
        assert!(e.contains("instance 3") && e.contains("singular"), "{e}");
        g.rebuild_top().expect("top level");
        assert_eq!(
            g.nodes().expect("nodes"),
            cpu.nodes,
            "offset {offset}: a refused move changed the levels"
        );
    }
    integration_tests::assert_no_validation_errors(&gpu);
}

/// A plain top level (the radix tree and its fit, as `bench levels` times it) equals the CPU
/// executor's build over the same boxes, at sizes of one merge-sort run, of a run's edge and
/// of several runs and fit blocks, three times in a row: each build after the first codes
/// the instances in the bounds of the build before (`GpuLbvh::record_instanced`), the third
/// with one instance moved far outside them (its code clamped: the tree is still sound).
/// After `build_top_next` a build codes them in their own bounds, as the CPU's levels do.
#[test]
fn a_plain_top_level_is_built_as_the_cpu_builds_it() {
    let Some(gpu) = integration_tests::gpu("a_plain_top_level_is_built_as_the_cpu_builds_it") else {
        return;
    };
    let kernels = std::sync::Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
    for bits in [MortonBits::B30, MortonBits::B63] {
        let opts = BuildOptions::lbvh(bits);
        for count in [1, 2, 255, 256, 257, 1000, 4099] {
            let (meshes, placements, _) = instanced(Vec3::new(0.0, 1e3, 0.0), count, 7 + count as u32);
            let mut g = raytrace::gpu::GpuLevels::new(&gpu, &kernels, &meshes, &placements, opts).expect("GPU levels");
            let mut last = raytrace::cpu::build(&g.boxes().expect("boxes"), &[], opts).0.bounds;
            g.set_top_plain(true);
            g.set_top_refits(0);
            for turn in 0..4 {
                let moved: Vec<[[f32; 4]; 3]> = placements
                    .iter()
                    .enumerate()
                    .map(|(k, p)| {
                        let mut r = p.rows;
                        r[1][3] += (turn * (k % 7)) as f32;
                        if turn == 2 && k == count / 2 {
                            r[0][3] -= 1e4;
                        }
                        r
                    })
                    .collect();
                g.set_transforms(&moved).expect("new transforms");
                if turn == 3 {
                    g.build_top_next();
                }
                let coded = g.top_code_bounds().expect("bounds");
                assert_eq!(
                    coded,
                    (turn < 3).then_some(last),
                    "{count} instances, build {turn}: the bounds kept"
                );
                g.rebuild_top().expect("top level");
                let boxes = g.boxes().expect("boxes");
                let top = raytrace::cpu::build_coded(&boxes, &[], opts, coded.as_ref()).0;
                raytrace::bvh::validate(&top.nodes, &top.parents, &boxes, &[]).expect("a valid top level");
                let nodes = g.nodes().expect("nodes");
                let first = g.layout().top as usize;
                assert_eq!(
                    &nodes[first..],
                    &top.nodes[..],
                    "{count} instances, {bits:?}, build {turn}: the plain top level"
                );
                last = top.bounds;
            }
        }
    }
    integration_tests::assert_no_validation_errors(&gpu);
}

#[test]
fn bench_levels_measures_the_top_level_and_checks_it_against_the_cpu() {
    let Some(gpu) = integration_tests::gpu("bench_levels_measures_the_top_level_and_checks_it_against_the_cpu") else {
        return;
    };
    let o = raytrace::bench::levels::Options { instances: 60, runs: 3 };
    let r = raytrace::bench::levels::run(&gpu, &o).expect("bench levels");
    assert!(r.matches_cpu);
    assert!(
        r.top_p10_us > 0.0 && r.top_p10_us <= r.top_us && r.top_us <= r.top_p90_us,
        "{}",
        raytrace::bench::levels::markdown(&r)
    );
    assert!(
        r.top_refit_p10_us > 0.0 && r.top_refit_p10_us <= r.top_refit_us && r.top_refit_us <= r.top_refit_p90_us,
        "{}",
        raytrace::bench::levels::markdown(&r)
    );
    // 60 instances, each mesh in turn: 20 of each.
    assert_eq!(r.instanced_primitives, 20 * r.distinct_primitives as u64);
    assert!(r.bytes_per_instance > 96.0 && r.bytes_per_distinct_primitive > 48.0);
    assert!(raytrace::bench::levels::markdown(&r).contains("| yes |"));
}
