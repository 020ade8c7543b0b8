//! The driver's acceleration structures as a second tracer (`--accel driver`,
//! `raytrace::gpu::driver`). Where the device offers ray-tracing pipelines (the H100): the
//! same pictures as the project's tracer on the built-in scenes, and the stability suite's
//! ray sets answered alike (closed meshes at every offset, axis-aligned rays with either sign
//! of zero, non-finite rays and bad ranges, spheres far and near). Elsewhere (lavapipe) those
//! print SKIPPED with the reason, and the renderer's error names what the device lacks.
mod common;

/// Read by the suite's helpers (`common::World`): the project's binary BVH.
const WIDE: bool = false;

use common::rays::*;
use common::*;
use raytrace::cli::{compare, SceneArgs};
use raytrace::gpu::driver::DriverBuild;
use raytrace::gpu::{Gpu, GpuOptions, GpuRenderer, Kernels};
use raytrace::inputs::hard_cases::closed_meshes;
use raytrace::render::Accel;
use shared::glam::Vec3;
use shared::traverse;
use shared::types::{Hit, Sphere, INVALID};
use std::sync::Arc;

const INF: f32 = f32::INFINITY;

/// The renderer refuses the driver tracer on a device opened without ray tracing, and on a
/// device without it (lavapipe) names the missing extension; where the device has it, the
/// renderer takes it.
#[test]
fn the_driver_tracer_names_what_the_device_lacks() {
    let Some(gpu) = integration_tests::gpu("the_driver_tracer_names_what_the_device_lacks") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    let e = format!("{:#}", r.set_accel(Accel::Driver, DriverBuild::FastBuild).unwrap_err());
    assert!(
        e.contains("--accel driver needs") && e.contains("opened without"),
        "{e}"
    );
    assert_eq!(r.accel(), Accel::Lbvh, "a failed switch left the tracer changed");
    drop((r, kernels, gpu));
    let gpu = Gpu::new(&GpuOptions {
        validation: true,
        ray_tracing: true,
        ..Default::default()
    })
    .expect("the device again");
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    match &gpu.ray_tracing {
        Ok(()) => {
            r.set_accel(Accel::Driver, DriverBuild::FastBuild)
                .expect("the driver tracer");
            assert_eq!(r.accel(), Accel::Driver);
        }
        Err(why) => {
            assert!(why.contains("VK_KHR_ray_tracing_pipeline"), "{why}");
            let e = format!("{:#}", r.set_accel(Accel::Driver, DriverBuild::FastBuild).unwrap_err());
            assert!(e.contains(why.as_str()) && e.contains("--accel lbvh"), "{e}");
        }
    }
    integration_tests::assert_no_validation_errors(&gpu);
}

/// The scene files beside the built-ins: `scenes/NAME.toml` of the source tree.
fn scene_file(name: &str) -> String {
    format!("{}/../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"))
}

/// Every built-in scene (the forest's billion triangles in two levels, the herd's ten
/// million), the sixteen bunnies in two levels too, and the pond (a waving world-space group
/// beside instances), traced by the driver, against the CPU executor's picture with the same
/// random streams; a flattened and an instanced scene each way the driver builds.
#[test]
fn driver_pictures_agree_with_the_project_tracer() {
    let test = "driver_pictures_agree_with_the_project_tracer";
    let Some(gpu) = integration_tests::ray_tracing_gpu(test) else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let pond = scene_file("pond");
    let mut cases: Vec<(&str, Vec<&str>)> = raytrace::scene::Scene::BUILTINS
        .iter()
        .map(|s| (*s, vec!["--driver-build", "fast-build"]))
        .collect();
    cases.push((pond.as_str(), vec!["--time", "0.7"]));
    for build in ["fast-trace", "update"] {
        cases.push(("spheres", vec!["--driver-build", build]));
        cases.push(("instances", vec!["--instancing", "on", "--driver-build", build]));
    }
    let mut worst = Vec::new();
    for (scene, extra) in &cases {
        let mut args = vec![
            "raytrace", scene, "--size", "128x96", "--spp", "16", "--accel", "driver",
        ];
        args.extend(extra);
        let p = <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene");
        let c = compare(&p, &gpu, &kernels, true).expect("compare");
        let layout = if p.data.instancing.is_some() {
            "two levels"
        } else {
            "flattened"
        };
        eprintln!(
            "{scene} {extra:?} ({layout}): relative RMSE {:.4}",
            c.stats.relative_rmse
        );
        if c.stats.relative_rmse > 0.05 {
            worst.push(format!("{scene} {extra:?}: {:.4}", c.stats.relative_rmse));
        }
    }
    integration_tests::assert_no_validation_errors(&gpu);
    assert!(worst.is_empty(), "pictures differ: {}", worst.join(", "));
}

/// A bottom level updated in place (`--driver-build update`: built at the first frame, refit
/// after the objects move) finds the same hits as one built afresh for the new positions:
/// the sixteen spinning bunnies flattened, and the pond's waving group beside its instances,
/// half a second on.
#[test]
fn updated_structures_trace_as_rebuilt_ones() {
    let test = "updated_structures_trace_as_rebuilt_ones";
    let Some(gpu) = integration_tests::ray_tracing_gpu(test) else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    for scene in ["instances".to_string(), scene_file("pond")] {
        let args = ["raytrace", &scene, "--size", "128x96", "--accel", "driver"];
        let p = <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene");
        let later = p.scene.objects_in(&p.data, 0.5);
        let mut pictures = Vec::new();
        for build in [DriverBuild::Update, DriverBuild::FastBuild] {
            let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
            r.set_accel(Accel::Driver, build).expect("the driver tracer");
            r.load(&p.data, &p.frame).expect("load");
            if build == DriverBuild::Update {
                // The first frame builds; the objects move; the next frame updates.
                r.render(1, true).expect("first frame");
            }
            r.set_objects(&later).expect("move");
            r.render(4, true).expect("frame");
            pictures.push(r.picture().expect("picture"));
        }
        let d = raytrace::picture::diff_stats(&pictures[0], &pictures[1]).expect("diff");
        assert!(
            d.relative_rmse < 1e-3,
            "{scene}: updated against rebuilt: relative RMSE {}",
            d.relative_rmse
        );
    }
    integration_tests::assert_no_validation_errors(&gpu);
}

/// The watertightness rays (aimed exactly at every vertex and edge midpoint of closed meshes
/// from inside, at offsets 0 to 1e5): every closest and any-hit query through the driver's
/// structures hits.
#[test]
fn closed_meshes_do_not_leak_through_the_driver() {
    let Some(mut g) = GpuWorld::open_driver("closed_meshes_do_not_leak_through_the_driver") else {
        return;
    };
    let mut leaks = Vec::new();
    let mut rays_shot = 0;
    for (name, mesh) in closed_meshes() {
        for s in OFFSETS {
            let offset = Vec3::new(s, -s, s);
            g.load(&World::new(mesh.triangles(offset), vec![]));
            let rays: Vec<_> = rays_at_vertices_and_edges(&mesh, offset)
                .into_iter()
                .map(|(o, d)| (o, d, INF))
                .collect();
            let (closest, any) = (g.closest(&rays), g.any(&rays));
            rays_shot += rays.len();
            for (i, &(o, d, _)) in rays.iter().enumerate() {
                if closest[i].prim == INVALID || !any[i] {
                    leaks.push(format!(
                        "{name} at offset {s}, from {o} along {d}: closest {:?}, any {}",
                        closest[i], any[i]
                    ));
                }
            }
        }
    }
    g.assert_no_validation_errors();
    eprintln!("{rays_shot} rays, {} leaks", leaks.len());
    assert!(
        leaks.is_empty(),
        "{} of {rays_shot} rays leaked, e.g.:\n{}",
        leaks.len(),
        leaks[..leaks.len().min(8)].join("\n")
    );
}

/// Axis-aligned rays with either sign of zero at meshes whose boxes are flat: the driver
/// finds what the CPU's brute force finds (to a few ulps; rays along an open mesh's boundary
/// edge may go either way), and its any-hit query agrees with its closest. Non-finite rays,
/// zero directions and bad ranges miss; rays at the edge of the float range return.
#[test]
fn axis_aligned_and_non_finite_rays_through_the_driver() {
    let Some(mut g) = GpuWorld::open_driver("axis_aligned_and_non_finite_rays_through_the_driver") else {
        return;
    };
    let mut wrong = Vec::new();
    let dirs = signed_zero_directions();
    for (name, tris) in axis_ray_meshes() {
        let world = World::new(tris, vec![]);
        let scene = world.scene();
        g.load(&world);
        let mut rays = Vec::new();
        for x in AXIS_RAY_COORDS {
            for y in AXIS_RAY_COORDS {
                for z in AXIS_RAY_COORDS {
                    rays.extend(dirs.iter().map(|&d| (Vec3::new(x, y, z), d, INF)));
                }
            }
        }
        let (hits, any) = (g.closest(&rays), g.any(&rays));
        for (i, &(o, d, _)) in rays.iter().enumerate() {
            let cpu = traverse::closest_brute(&scene, o, d, INF);
            let on_edge = |h: &Hit| h.prim != INVALID && h.u.min(h.v).min(1.0 - h.u - h.v) < 1e-5;
            let same = (cpu.prim == INVALID) == (hits[i].prim == INVALID)
                && (cpu.prim == INVALID || ulps(hits[i].t, cpu.t as f64) <= 4.0);
            if !(same || on_edge(&cpu) || on_edge(&hits[i])) || any[i] != (hits[i].prim != INVALID) {
                wrong.push(format!(
                    "{name} from {o} along {d:?}: driver {:?} (any {}), CPU {:?}",
                    hits[i], any[i], cpu
                ));
            }
        }
    }
    let world = mixed_world();
    g.load(&world);
    let mut bad: Vec<_> = non_finite_rays().into_iter().map(|(o, d)| (o, d, INF)).collect();
    bad.extend(BAD_T_MAX.map(|t| (GOOD_RAY.0, GOOD_RAY.1, t)));
    let (hits, any) = (g.closest(&bad), g.any(&bad));
    for (i, r) in bad.iter().enumerate() {
        if hits[i] != Hit::MISS || any[i] {
            wrong.push(format!("{r:?}: {:?}, any {}", hits[i], any[i]));
        }
    }
    let extreme: Vec<_> = EXTREME_RAYS.iter().map(|&(o, d)| (o, d, INF)).collect();
    let n = world.scene().n_prims;
    for (r, h) in extreme.iter().zip(g.closest(&extreme)) {
        if !sane(&h, n, INF) {
            wrong.push(format!("extreme ray {r:?}: {h:?}"));
        }
    }
    g.assert_no_validation_errors();
    assert!(
        wrong.is_empty(),
        "{} wrong answers through the driver, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}

/// Spheres through the intersection shader: small spheres far from the origin and large
/// ones near it, hit from outside and from inside, give the distances the CPU's sphere test
/// gives, to a few ulps (the same `shared` code, compiled by the driver; the structures only
/// narrow the candidates).
#[test]
fn spheres_through_the_driver_match_the_cpu() {
    let Some(mut g) = GpuWorld::open_driver("spheres_through_the_driver_match_the_cpu") else {
        return;
    };
    let mut rnd = Random::new(7);
    let mut wrong = Vec::new();
    for (r, at) in [(1e-2f32, 1e5f32), (0.5, 1e3), (1e3, 0.0), (1e4, 10.0)] {
        let center = Vec3::new(at, -0.5 * at, 0.25 * at);
        let world = World::new(
            vec![],
            vec![Sphere {
                center_radius: [center.x, center.y, center.z, r],
            }],
        );
        let scene = world.scene();
        g.load(&world);
        let mut rays = Vec::new();
        for k in 0..512 {
            // Outside, aimed at a point of the sphere; or inside, any direction.
            let (o, d) = if k % 2 == 0 {
                let o = center + rnd.unit() * (4.0 * r);
                (o, center + rnd.unit() * (0.9 * r) - o)
            } else {
                (center + rnd.unit() * (0.5 * r), rnd.unit())
            };
            rays.push((o, d, INF));
        }
        let hits = g.closest(&rays);
        for (i, &(o, d, _)) in rays.iter().enumerate() {
            let cpu = traverse::closest_brute(&scene, o, d, INF);
            if cpu.prim != hits[i].prim || (cpu.prim != INVALID && ulps(hits[i].t, cpu.t as f64) > 8.0) {
                wrong.push(format!(
                    "sphere r {r} at {center}: from {o} along {d}: driver {:?}, CPU {:?}",
                    hits[i], cpu
                ));
            }
        }
    }
    g.assert_no_validation_errors();
    assert!(
        wrong.is_empty(),
        "{} sphere hits differ, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
}
