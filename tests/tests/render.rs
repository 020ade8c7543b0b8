//! The path tracer on both backends: closest hits through the BVH equal brute force, CPU
//! and GPU images agree, a furnace converges to its analytic radiance, and the error falls
//! like 1/sqrt(spp).
use glam::Vec3;
use integration_tests::{assert_no_validation_errors, dump_mismatch, gpu, renderer};
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cli::{compare, Prepared, SceneArgs};
use raytrace::cpu::{render_cpu, CpuRender};
use raytrace::gpu::{GpuRenderer, Kernels};
use raytrace::picture::{diff_stats, Picture};
use raytrace::render::with_bvh;
use raytrace::scene::{CameraSpec, Mesh, Scene, SceneObject, Settings, Shape, Transform};
use shared::path::World;
use shared::rng::Rng;
use shared::traverse::Scene as Prims;
use shared::types::{Frame, Hit, Material, MaterialKind, Ray, Triangle};
use std::sync::Arc;

fn prepared(scene: &str, size: u32, spp: u32, extra: &[&str]) -> Prepared {
    let size = format!("{size}x{size}");
    let spp = spp.to_string();
    let mut args = vec!["raytrace", scene, "--size", &size, "--spp", &spp];
    args.extend_from_slice(extra);
    <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene")
}

/// Random rays from random points inside the bunny's box, and rays aimed at the bunny.
fn rays(n: usize) -> Vec<Ray> {
    let mut rng = Rng::new(1, 2, 3);
    let mut r = || rng.next_f32();
    (0..n)
        .map(|i| {
            let o = Vec3::new(20.0 + 515.0 * r(), 20.0 + 515.0 * r(), 20.0 + 515.0 * r());
            let d = if i % 2 == 0 {
                Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5)
            } else {
                Vec3::new(278.0 + 150.0 * (r() - 0.5), 150.0 * r(), 278.0 + 150.0 * (r() - 0.5)) - o
            };
            Ray {
                origin: [o.x, o.y, o.z, 0.0],
                dir: [d.x, d.y, d.z, f32::INFINITY],
            }
        })
        .collect()
}

#[test]
fn closest_hit_through_the_bvh_equals_brute_force() {
    // Through the restructured tree (the plain one is checked on the hard inputs).
    let p = prepared("bunny", 4, 1, &["--treelets", "on"]);
    let cpu = render_cpu(&p.data, &p.frame, 1, p.build(1), &|_| {});
    let rays = rays(4000);
    let (bvh_frame, brute_frame) = (with_bvh(p.frame, true), with_bvh(p.frame, false));
    let (bvh, brute) = (
        cpu_hits(&p, &cpu, &bvh_frame, &rays),
        cpu_hits(&p, &cpu, &brute_frame, &rays),
    );
    let bunny_hits = brute.iter().filter(|h| h.prim < p.frame.n_tris - 12).count();
    assert!(bunny_hits > 500, "only {bunny_hits} rays hit the bunny");
    assert_eq!(bvh, brute, "CPU: BVH and brute force disagree");

    let Some((gpu, mut r)) = renderer("closest_hit_through_the_bvh_equals_brute_force") else {
        return;
    };
    r.set_build(p.build(1));
    r.load(&p.data, &bvh_frame).expect("load");
    r.render(0, true).expect("build");
    check_gpu_hits("bunny, GPU BVH", &r.cast(&rays).expect("cast"), &brute);
    // Built without the pairs (`--pairs off`, or a binding too small for them), the walk
    // reads the tree alone: the same hits on both backends.
    let np = prepared("bunny", 4, 1, &["--treelets", "on", "--pairs", "off"]);
    assert!(p.build(1).pairs && !np.build(1).pairs, "--pairs auto/off");
    let cpu = render_cpu(&np.data, &np.frame, 1, np.build(1), &|_| {});
    assert!(cpu.bvh.pairs.is_empty(), "a build without pairs wrote them");
    assert_eq!(
        cpu_hits(&np, &cpu, &bvh_frame, &rays),
        brute,
        "CPU: the tree alone and brute force disagree"
    );
    r.set_build(np.build(1));
    r.load(&np.data, &bvh_frame).expect("load");
    r.render(0, true).expect("build");
    check_gpu_hits("bunny, GPU BVH without pairs", &r.cast(&rays).expect("cast"), &brute);
    // Brute force on the GPU over a smaller mesh: llvmpipe ends loops after 65535 iterations.
    let q = prepared("suzanne", 4, 1, &["--no-bvh"]);
    let cpu = render_cpu(&q.data, &q.frame, 1, q.build(1), &|_| {});
    let brute = cpu_hits(&q, &cpu, &q.frame, &rays);
    r.load(&q.data, &q.frame).expect("load");
    r.render(0, true).expect("build");
    check_gpu_hits("suzanne, GPU brute force", &r.cast(&rays).expect("cast"), &brute);
    assert_no_validation_errors(&gpu);
}

#[test]
fn an_image_past_the_devices_binding_limit_is_refused_by_name() {
    let Some((gpu, mut r)) = renderer("an_image_past_the_devices_binding_limit_is_refused_by_name") else {
        return;
    };
    let limit = gpu.max_binding;
    if limit > 1 << 30 {
        eprintln!(
            "SKIPPED the binding-limit refusal: {} binds up to {} MB, and an image past that would take as much memory",
            gpu.name,
            limit >> 20
        );
        return;
    }
    // One row past the limit: the accumulation image holds 16 bytes a pixel.
    let p = prepared("cornell", 8, 1, &[]);
    let (width, height) = (4096, (limit / (16 * 4096) + 1) as u32);
    let big = Frame {
        width,
        height,
        ..p.frame
    };
    let e = r
        .load(&p.data, &big)
        .expect_err("an image past the binding limit was taken");
    let message = format!("{e:#}");
    assert!(
        message.contains("accumulation image") && message.contains("maxStorageBufferRange"),
        "{message}"
    );
    // The renderer goes on at a size that fits.
    r.load(&p.data, &p.frame).expect("a load after the refusal");
    r.render(1, true).expect("a render after the refusal");
    assert_eq!(r.samples(), 1);
    assert_no_validation_errors(&gpu);
}

/// Closest hits of `rays` on the CPU, through the BVH or by brute force as `frame` says.
fn cpu_hits(p: &Prepared, cpu: &CpuRender, frame: &Frame, rays: &[Ray]) -> Vec<Hit> {
    let nodes = cpu.bvh.traced_nodes();
    let w = World {
        scene: Prims {
            tris: bytemuck::cast_slice(&cpu.tris),
            spheres: &cpu.spheres,
            nodes: bytemuck::cast_slice(&nodes),
            wide: bytemuck::cast_slice(&cpu.bvh.wide),
            order: &cpu.bvh.sorted_prims,
            n_tris: p.frame.n_tris,
            n_prims: p.frame.n_prims,
            top: 0,
            instances: &[],
            n_instances: 0,
            coverage: p.data.coverage(),
            features: raytrace::render::tracer_features(frame, p.build(1)),
        },
        objects: &p.data.objects,
        prim_object: &p.data.prim_object,
        materials: &p.data.materials,
        lights: &p.data.lights,
        frame,
        attrs: &p.data.attrs,
        punctual: &p.data.punctual,
        env: &[],
        textures: &[],
        texels: &[],
    };
    rays.iter()
        .map(|r| {
            w.closest(
                Vec3::from_slice(&r.origin[..3]),
                Vec3::from_slice(&r.dir[..3]),
                r.dir[3],
            )
        })
        .collect()
}

/// GPU hits equal the CPU's: same primitive, distance within 1e-4 relative (the GPU may
/// divide and fuse less exactly).
fn check_gpu_hits(what: &str, hits: &[Hit], cpu: &[Hit]) {
    let bad: Vec<usize> = (0..hits.len())
        .filter(|&i| hits[i].prim != cpu[i].prim || (hits[i].t - cpu[i].t).abs() > 1e-4 * cpu[i].t)
        .collect();
    if !bad.is_empty() {
        let path = dump_mismatch(what, "GPU", &hits, "CPU", &cpu);
        panic!(
            "{what}: {} of {} hits differ, first ray {}: {}",
            bad.len(),
            hits.len(),
            bad[0],
            path.display()
        );
    }
}

#[test]
fn cpu_and_gpu_images_of_the_cornell_box_agree() {
    let Some(gpu) = gpu("cpu_and_gpu_images_of_the_cornell_box_agree") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    // 8 spp: H-PLOC's tree (`--tree auto`), and the radix tree.
    for extra in [
        &[][..],
        &["--no-nee"][..],
        &["--bits", "b63"][..],
        &["--tree", "karras"][..],
    ] {
        let p = prepared("cornell", 48, 8, extra);
        let c = compare(&p, &gpu, &kernels, true).expect("compare");
        eprintln!(
            "{extra:?}: world max error {}, topology identical {}, boxes identical {}, relative RMSE {}",
            c.world_max_error,
            c.topology_identical == Some(true),
            c.bvh_identical,
            c.stats.relative_rmse
        );
        // The GPU may evaluate `fma` unfused (Vulkan allows it), so world coordinates can
        // differ in the last bits; the GPU's tree is the CPU's build over its own
        // coordinates, and the radix tree's shape (Morton codes) does not move with them.
        assert!(
            c.world_max_error <= 1e-6,
            "{extra:?}: world-space primitives differ by {}",
            c.world_max_error
        );
        assert_eq!(
            c.same_build,
            Some(true),
            "{extra:?}: the GPU's BVH is not the CPU's build"
        );
        assert_eq!(p.build(8).builds_ploc(), extra.is_empty() || extra[0] != "--tree");
        if !p.build(8).builds_ploc() {
            assert_eq!(c.topology_identical, Some(true), "{extra:?}: BVH topologies differ");
        }
        // Same random streams: only floating-point differences in sin/cos/pow/division
        // separate the backends, and they flip few paths.
        assert!(
            c.stats.relative_rmse < 0.02,
            "{extra:?}: relative RMSE {} (means CPU {:?} GPU {:?})",
            c.stats.relative_rmse,
            c.stats.mean_a,
            c.stats.mean_b
        );
    }
    assert_no_validation_errors(&gpu);
}

/// A closed cube seen from inside: every wall diffuse with albedo `a` and emitting `e`.
fn furnace(a: f32, e: f32, depth: u32, extra: &[(&str, bool)]) -> Scene {
    let v = |x: f32, y: f32, z: f32| [x, y, z, 0.0];
    let corners: Vec<[f32; 4]> = (0..8)
        .map(|i| {
            v(
                (i & 1) as f32 * 2.0 - 1.0,
                (i >> 1 & 1) as f32 * 2.0 - 1.0,
                (i >> 2 & 1) as f32 * 2.0 - 1.0,
            )
        })
        .collect();
    // Faces wound so that their normals point into the cube.
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut tris = Vec::new();
    for q in quads {
        let c = |k: usize| corners[q[k]];
        tris.push(Triangle {
            v0: c(0),
            v1: c(2),
            v2: c(1),
        });
        tris.push(Triangle {
            v0: c(0),
            v1: c(3),
            v2: c(2),
        });
    }
    let mut settings = Settings {
        width: 24,
        height: 24,
        max_depth: depth,
        ..Default::default()
    };
    for &(k, on) in extra {
        match k {
            "nee" => settings.nee = on,
            "mis" => settings.mis = on,
            _ => settings.russian_roulette = on,
        }
    }
    Scene {
        name: "furnace".into(),
        punctual: Vec::new(),
        environment: None,
        textures: Default::default(),
        camera: CameraSpec {
            position: Vec3::new(0.1, -0.2, 0.3),
            look_at: Vec3::new(1.0, 0.5, -0.2),
            up: Vec3::Y,
            vfov_deg: 90.0,
            aperture: 0.0,
            focus_distance: None,
        },
        settings,
        materials: vec![(
            "wall".into(),
            Material {
                albedo: [a, a, a, 0.0],
                emission: [e, e, e, 0.0],
                kind: MaterialKind::Diffuse as u32,
                ..Default::default()
            },
        )],
        meshes: vec![Mesh::flat("inward cube", tris)],
        objects: vec![SceneObject {
            name: "box".into(),
            shape: Shape::Mesh(0),
            transform: Transform::IDENTITY,
            material: 0,
            animation: Default::default(),
            instance: None,
        }],
    }
}

fn mean_radiance(p: &Picture) -> f64 {
    let lin = p.linear();
    lin.iter().map(|c| c[0] as f64).sum::<f64>() / lin.len() as f64
}

#[test]
fn furnace_converges_to_its_analytic_radiance() {
    let (a, e, depth) = (0.5f32, 1.0f32, 6u32);
    // Paths of at most `depth` segments: L = e (1 - a^depth) / (1 - a).
    let expected = e as f64 * (1.0 - (a as f64).powi(depth as i32)) / (1.0 - a as f64);
    // (Next-event estimation without MIS is left out: in a cube its estimator has unbounded
    // variance along the edges, where light points come arbitrarily close.)
    let modes: [&[(&str, bool)]; 3] = [&[("nee", false), ("rr", false)], &[("nee", false)], &[]];
    let gpu = gpu("furnace_converges_to_its_analytic_radiance");
    let kernels = gpu.as_ref().map(|g| Arc::new(Kernels::new(g).expect("kernels")));
    for mode in modes {
        let scene = furnace(a, e, depth, mode);
        let data = scene.gpu_data(0.0);
        let frame = scene.frame(&data);
        let cpu = render_cpu(&data, &frame, 64, BuildOptions::lbvh(MortonBits::B30), &|_| {});
        let got = mean_radiance(&cpu.picture);
        assert!(
            (got - expected).abs() < 0.01 * expected,
            "CPU {mode:?}: {got} != {expected}"
        );
        if let (Some(g), Some(k)) = (&gpu, &kernels) {
            let mut r = GpuRenderer::new(g, k).expect("renderer");
            r.load(&data, &frame).expect("load");
            r.render(64, true).expect("render");
            let got = mean_radiance(&r.picture().expect("picture"));
            assert!(
                (got - expected).abs() < 0.01 * expected,
                "GPU {mode:?}: {got} != {expected}"
            );
        }
    }
    if let Some(g) = &gpu {
        assert_no_validation_errors(g);
    }
}

#[test]
fn error_falls_like_one_over_the_square_root_of_samples() {
    let Some((gpu, mut r)) = renderer("error_falls_like_one_over_the_square_root_of_samples") else {
        return;
    };
    let render = |r: &mut GpuRenderer, spp: u32, seed: &str| {
        let p = prepared("cornell", 24, spp, &["--seed", seed]);
        r.load(&p.data, &p.frame).expect("load");
        r.render(spp, true).expect("render");
        r.picture().expect("picture")
    };
    let reference = render(&mut r, 2048, "7");
    let errors: Vec<(f64, f64)> = [4u32, 16, 64, 256]
        .iter()
        .map(|&spp| {
            (
                spp as f64,
                diff_stats(&reference, &render(&mut r, spp, "1")).expect("stats").rmse,
            )
        })
        .collect();
    // Least-squares slope of log(error) against log(spp): -1/2 for an unbiased estimator.
    let n = errors.len() as f64;
    let (xs, ys): (Vec<f64>, Vec<f64>) = errors.iter().map(|&(s, e)| (s.ln(), e.ln())).unzip();
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let slope = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum::<f64>()
        / xs.iter().map(|x| (x - mx) * (x - mx)).sum::<f64>();
    eprintln!("slope {slope}, errors {errors:?}");
    assert!((-0.62..=-0.38).contains(&slope), "slope {slope}, errors {errors:?}");
    assert_no_validation_errors(&gpu);
}

#[test]
fn bad_scene_input_names_the_file_and_the_problem() {
    let dir = std::env::temp_dir().join(format!("raytrace-bad-scenes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let cases = [
        ("missing.toml", None, "missing.toml"),
        ("syntax.toml", Some("[camera\nposition = [0, 0, 0]"), "line"),
        ("field.toml", Some("[camera]\npositon = [0, 1, 0]\n"), "positon"),
        ("empty.toml", Some("[camera]\nposition = [0, 1, 5]\nlook_at = [0, 0, 0]\n"), "no objects"),
        (
            "material.toml",
            Some("[camera]\nposition = [0, 1, 5]\nlook_at = [0, 0, 0]\n[[objects]]\nsphere = 1.0\nmaterial = \"gold\"\n"),
            "gold",
        ),
        (
            "nan.toml",
            Some("[camera]\nposition = [0, 1, 5]\nlook_at = [0, 0, 0]\n[materials.w]\nkind = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n[[objects]]\nmesh = \"nan.obj\"\nmaterial = \"w\"\n"),
            "nan.obj",
        ),
    ];
    std::fs::write(dir.join("nan.obj"), "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n").expect("write");
    for (name, text, needle) in cases {
        let path = dir.join(name);
        if let Some(t) = text {
            std::fs::write(&path, t).expect("write");
        }
        let args = <SceneArgs as clap::Parser>::parse_from(["raytrace", path.to_str().expect("utf-8 path")]);
        let err = match args.prepare() {
            Ok(_) => panic!("{name}: accepted"),
            Err(e) => format!("{e:#}"),
        };
        assert!(err.contains(name), "{name}: error does not name the file: {err}");
        assert!(
            err.to_lowercase().contains(needle),
            "{name}: error does not say {needle:?}: {err}"
        );
    }
}

/// Path regeneration (`path::pixel_samples` starts a lane's next sample as soon as its path
/// ends) must give the image of tracing the samples one after another: eight samples in one
/// dispatch and eight dispatches of one sample accumulate the same bits.
#[test]
fn samples_in_one_dispatch_equal_samples_one_at_a_time() {
    let Some((gpu, mut r)) = renderer("samples_in_one_dispatch_equal_samples_one_at_a_time") else {
        return;
    };
    for scene in ["cornell", "spheres"] {
        let p = prepared(scene, 24, 8, &[]);
        r.load(&p.data, &p.frame).expect("load");
        r.render(8, true).expect("render");
        let together = r.picture().expect("picture");
        r.load(&p.data, &p.frame).expect("load");
        r.render(1, true).expect("render");
        for _ in 1..8 {
            r.render(1, false).expect("render");
        }
        let apart = r.picture().expect("picture");
        let bits = |p: &Picture| p.accum.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert!(together.accum.iter().any(|a| a[0] > 0.0), "{scene}: black image");
        assert_eq!(bits(&together), bits(&apart), "{scene}: accumulation images differ");
    }
    assert_no_validation_errors(&gpu);
}

/// The stepped path loop (`path::stepped_pixels`, which the renderer runs off lavapipe only)
/// renders the segment loop's bits on the GPU: frames of several segments without next-event
/// estimation, through the BVH and by brute force, through a kernel of its own.
#[test]
fn the_stepped_path_loop_renders_the_segment_loops_bits() {
    let Some((gpu, mut r)) = renderer("the_stepped_path_loop_renders_the_segment_loops_bits") else {
        return;
    };
    // One scene's kernels (their compiles are most of the time on lavapipe): the CPU
    // executor's unit test runs the loop on more scenes.
    let cases: [(&str, &[&str]); 2] = [("cornell", &["--no-nee"]), ("cornell", &["--no-nee", "--no-bvh"])];
    for (case, (scene, extra)) in cases.into_iter().enumerate() {
        let p = prepared(scene, 24, 4, extra);
        let mut images = Vec::new();
        for stepped in [false, true] {
            r.set_stepped(Some(stepped));
            r.load(&p.data, &p.frame).expect("load");
            assert_eq!(r.stepped(), stepped, "{scene} {extra:?}");
            r.render(4, true).expect("render");
            let picture = r.picture().expect("picture");
            assert!(
                picture.accum.iter().any(|a| a[0] > 0.0),
                "{scene} {extra:?}: black image"
            );
            images.push(picture.accum.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>());
            // The stepped loop's own kernel (the segment loop's kernels hold no other loop),
            // made by the first case's stepped render and kept.
            let made = r
                .kernels()
                .made_log()
                .iter()
                .any(|(k, _)| *k == raytrace::gpu::Kernel::PathStepped);
            assert_eq!(made, stepped || case > 0, "{scene} {extra:?}: path_stepped made");
        }
        assert!(images[0] == images[1], "{scene} {extra:?}: the loops' images differ");
    }
    r.set_stepped(None);
    assert_no_validation_errors(&gpu);
}

/// A pipeline asked for by several threads at once (the path tracer's is started on a thread
/// of its own while the build is recorded, `Kernels::make_soon`) is made once, and every
/// ask gets it.
#[test]
fn a_pipeline_asked_for_at_once_is_made_once() {
    let Some(gpu) = gpu("a_pipeline_asked_for_at_once_is_made_once") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let constant = shared::types::FEATURE_TRIANGLES;
    kernels.make_soon(raytrace::gpu::Kernel::PathTrace, constant);
    let asks: Vec<_> = std::thread::scope(|scope| {
        let threads: Vec<_> = (0..4)
            .map(|_| scope.spawn(|| kernels.specialised(raytrace::gpu::Kernel::PathTrace, constant)))
            .collect();
        threads
            .into_iter()
            .map(|t| t.join().expect("thread").expect("pipeline"))
            .collect()
    });
    assert!(asks.iter().all(|&p| p == asks[0]), "different pipelines: {asks:?}");
    // Every ask has returned, so the one that made it (any thread) has logged it.
    let made: Vec<_> = kernels
        .made_log()
        .into_iter()
        .filter(|(k, _)| *k == raytrace::gpu::Kernel::PathTrace)
        .collect();
    assert_eq!(made.len(), 1, "made {made:?}");
    assert_no_validation_errors(&gpu);
}

/// The sample groups of a persistent dispatch (`path::sample_groups`, `group_samples`):
/// enough for about `GROUP_ITEMS` items, at most `MAX_GROUPS`, each sample in one group, no
/// group empty, and from the frame's pixels alone.
#[test]
fn sample_groups_cover_each_sample_once() {
    use shared::path::{group_samples, sample_groups, GROUP_ITEMS, MAX_GROUPS};
    // 800x800 at 31 samples a dispatch: six groups (3.84M items), five of 6 samples and one of 1.
    assert_eq!(sample_groups(640_000, 31), 6);
    assert_eq!(group_samples(31, 6, 0), (0, 6));
    assert_eq!(group_samples(31, 6, 5), (30, 1));
    // 1920x1080 at one sample (real time), and 4K at 32: one group.
    assert_eq!(sample_groups(1920 * 1080, 1), 1);
    assert_eq!(sample_groups(3840 * 2160, 32), 1);
    for pixels in [1, 36, 576, 4096, 518_400, 640_000, 2_073_600, 1 << 24] {
        for samples in [1, 2, 3, 5, 7, 8, 16, 31, 32] {
            let groups = sample_groups(pixels, samples);
            assert!(
                (1..=MAX_GROUPS.min(samples)).contains(&groups),
                "{pixels} {samples}: {groups}"
            );
            assert!(groups == 1 || groups as u64 * pixels as u64 <= GROUP_ITEMS as u64);
            let mut next = 0;
            for g in 0..groups {
                let (first, count) = group_samples(samples, groups, g);
                assert!(first == next && count > 0, "{pixels} {samples}: group {g} of {groups}");
                next += count;
            }
            assert_eq!(next, samples, "{pixels} {samples}");
        }
    }
}

/// A persistent stepped dispatch of 32 samples at 720x720 splits each pixel's samples into
/// eight groups of four (`path::sample_groups`, `VARIANT_GROUPS`), writes each group's sums
/// past the image and adds them in group order (`path::add_groups`): the image is, bit for
/// bit, the eight groups traced apart by the tiles (each from an empty image) and added in
/// that order. Skipped on lavapipe, which renders with the tiles (see
/// `the_persistent_path_tracer_renders_every_pixel_as_the_tiles_do`).
#[test]
fn persistent_sample_groups_add_in_group_order() {
    let Some((gpu, mut r)) = renderer("persistent_sample_groups_add_in_group_order") else {
        return;
    };
    if gpu.is_lavapipe() {
        eprintln!("SKIPPED: lavapipe renders with the tiles");
        return;
    }
    let spp = 32;
    assert_eq!(shared::path::sample_groups(720 * 720, spp), 8);
    for extra in [&["--no-nee"][..]] {
        let p = prepared("bunny", 720, spp, extra);
        r.set_persistent(Some(true));
        r.set_first_sample(0);
        r.load(&p.data, &p.frame).expect("load");
        r.render(spp, true).expect("render");
        let grouped = r.sums().expect("sums");
        // Each group of four samples apart, through the tiles.
        r.set_persistent(Some(false));
        let mut expected: Vec<[f32; 4]> = Vec::new();
        for g in 0..8 {
            r.set_first_sample(4 * g);
            r.load(&p.data, &p.frame).expect("load");
            r.render(4, true).expect("render");
            let part = r.sums().expect("sums");
            if expected.is_empty() {
                expected = part;
            } else {
                for (e, s) in expected.iter_mut().zip(&part) {
                    *e = [e[0] + s[0], e[1] + s[1], e[2] + s[2], e[3] + s[3]];
                }
            }
        }
        r.set_persistent(None);
        r.set_first_sample(0);
        assert!(expected.iter().all(|s| s[3] > 0.0), "{extra:?}: a pixel without rays");
        let apart = grouped.iter().zip(&expected).filter(|(a, b)| a != b).count();
        assert_eq!(apart, 0, "{extra:?}: {apart} pixels differ");
    }
    assert_no_validation_errors(&gpu);
}
