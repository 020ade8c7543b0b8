//! The path tracer through two levels (`--instancing on`): an instanced scene renders as the
//! same scene flattened, on the CPU executor and the GPU; both levels come out of the GPU as
//! the CPU builds them; picking names the instance's object; moving objects moves their
//! instances; a scene of both kinds (a world-space group transformed every frame, deforming,
//! beside instances) renders as flattened and follows its wave on both backends; `--explain`
//! says what was chosen; scenes that cannot be instanced are named.
use integration_tests::{assert_no_validation_errors, gpu};
use raytrace::bvh::{MeshPrims, Placement, TOP_ROUNDS};
use raytrace::cli::{compare, Prepared, SceneArgs};
use raytrace::cpu::render_cpu;
use raytrace::gpu::{Denoise, GpuRenderer, Kernels, GROUP_REFITS, TOP_REFITS};
use raytrace::picture::diff_stats;
use raytrace::scene::{auto_instances, InstancingMode, Scene, Shape};
use shared::instance::instance_box;
use shared::types::{Ray, Triangle, FEATURE_INSTANCES, FEATURE_NEE, INVALID};
use std::sync::Arc;

fn prepared(scene: &str, size: u32, spp: u32, instancing: &str) -> Prepared {
    prepared_at(scene, size, spp, instancing, 0.0)
}

fn prepared_at(scene: &str, size: u32, spp: u32, instancing: &str, time: f32) -> Prepared {
    let size = format!("{size}x{size}");
    let (spp, time) = (spp.to_string(), time.to_string());
    let args = [
        "raytrace",
        scene,
        "--size",
        &size,
        "--spp",
        &spp,
        "--instancing",
        instancing,
        "--time",
        &time,
    ];
    <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene")
}

/// A ray straight down from 20 units above `(x, z)`: what picking casts onto the ground.
fn down(x: f32, z: f32) -> Ray {
    Ray {
        origin: [x, 20.0, z, 0.0],
        dir: [0.0, -1.0, 0.0, f32::INFINITY],
    }
}

/// The shipped scene of both kinds: a waving pond and a ground quad in the world-space group
/// (`instance = false`), twelve bunnies and a light instanced (`instance = true`).
const POND: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/pond.toml");

/// Scenes of every kind of instance: the Cornell box (six instances of one quad, scaled
/// unevenly and turned, one of them the light: an instanced emitter for next-event
/// estimation), spheres (one-sphere meshes under uniform scales; metal and glass), Suzanne
/// (vertex normals).
const SCENES: [&str; 3] = ["cornell", "spheres", "suzanne"];

#[test]
fn an_instanced_scene_renders_as_its_flattened_form_on_the_cpu() {
    for scene in SCENES {
        let (on, off) = (prepared(scene, 40, 16, "on"), prepared(scene, 40, 16, "off"));
        assert!(on.data.instancing.is_some() && off.data.instancing.is_none(), "{scene}");
        assert_ne!(on.frame.features & FEATURE_INSTANCES, 0, "{scene}");
        assert_eq!(on.frame.n_instances as usize, on.scene.objects.len(), "{scene}");
        let cpu = |p: &Prepared| render_cpu(&p.data, &p.frame, p.spp, p.build(p.spp), &|_| {});
        let (a, b) = (cpu(&on), cpu(&off));
        // The same random streams: only the hits' last bits differ (the instance's triangle
        // is hit in model space), and they flip few paths.
        let d = diff_stats(&a.picture, &b.picture).expect("same size");
        eprintln!("{scene}: relative RMSE {}", d.relative_rmse);
        assert!(
            d.relative_rmse < 0.02,
            "{scene}: instanced and flattened differ: relative RMSE {} (means {:?} {:?})",
            d.relative_rmse,
            d.mean_a,
            d.mean_b
        );
        assert!(b.picture.mean_luminance() > 0.0, "{scene} is black");
    }
}

#[test]
fn the_gpu_renders_instanced_scenes_as_the_cpu_and_as_flattened() {
    let Some(gpu) = gpu("the_gpu_renders_instanced_scenes_as_the_cpu_and_as_flattened") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    for scene in SCENES {
        let on = prepared(scene, 32, 8, "on");
        let c = compare(&on, &gpu, &kernels, true).expect("compare");
        // Both levels' nodes read back from the GPU equal the CPU executor's bit for bit.
        assert!(c.bvh_identical, "{scene}: the GPU's levels differ from the CPU's");
        assert!(
            c.stats.relative_rmse < 0.02,
            "{scene}: CPU and GPU differ: relative RMSE {}",
            c.stats.relative_rmse
        );
        let off = prepared(scene, 32, 8, "off");
        let flat = compare(&off, &gpu, &kernels, true).expect("compare");
        let d = diff_stats(&c.gpu.picture, &flat.gpu.picture).expect("same size");
        assert!(
            d.relative_rmse < 0.02,
            "{scene}: on the GPU instanced and flattened differ: relative RMSE {}",
            d.relative_rmse
        );
    }
    assert_no_validation_errors(&gpu);
}

#[test]
fn moving_objects_moves_their_instances_and_picking_names_the_object() {
    let Some(gpu) = gpu("moving_objects_moves_their_instances_and_picking_names_the_object") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let p = prepared("instances", 16, 1, "on");
    assert!(p.data.instancing.is_some());
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    r.load(&p.data, &p.frame).expect("load");
    r.render(1, true).expect("render");
    // A ray straight down onto bunny 5 (object 5): the instance's object, not the first
    // object showing the bunny's triangles.
    let at = |o: &shared::types::Object| (o.rows[0][3], o.rows[2][3]);
    let (x, z) = at(&p.data.objects[5]);
    let hit = r.cast_objects(&[down(x, z)]).expect("cast")[0];
    assert_eq!(hit.prim, 5, "picked {hit:?}");
    // Moved far away: the ray now finds the ground, and the bunny is found where it went.
    let mut moved = p.data.objects.clone();
    moved[5].rows[0][3] += 100.0;
    r.set_objects(&moved).expect("move");
    r.render(1, true).expect("render");
    let ground = p.scene.objects.iter().position(|o| o.name == "ground");
    let hits = r.cast_objects(&[down(x, z), down(x + 100.0, z)]).expect("cast");
    assert_ne!(hits[0].prim, 5);
    assert_eq!(hits[0].prim, ground.map_or(INVALID, |g| g as u32), "{hits:?}");
    assert_eq!(hits[1].prim, 5, "{hits:?}");
    // A transform that cannot be inverted is refused by the object's number; nothing moves.
    let mut flat = moved.clone();
    flat[7].rows[1] = [0.0; 4];
    let e = r.set_objects(&flat).unwrap_err().to_string();
    assert!(e.contains("object 7") && e.contains("singular"), "{e}");
    r.render(1, true).expect("render");
    assert_eq!(r.cast_objects(&[down(x + 100.0, z)]).expect("cast")[0].prim, 5);
    assert_no_validation_errors(&gpu);
}

#[test]
fn the_choice_is_explained_and_scenes_that_cannot_be_instanced_are_named() {
    // Auto: the sixteen bunnies share one mesh (instanced); the bunny in the box does not.
    let shared = prepared("instances", 8, 1, "auto");
    assert!(shared.data.instancing.is_some());
    let explain = shared.features.explain();
    assert!(
        explain.contains("instances") && explain.contains("objects are instances"),
        "{explain}"
    );
    // The measured break-even (H200, bench/NOTES.md session 49): real-time frames (one
    // sample a pixel) of the herd instanced at any size (its two levels also trace faster),
    // of the sixteen bunnies instanced at 1280x720 but flattened at 1920x1080 (2.89 against
    // 2.99 ms), as is a still of 32 samples; a scene that shares little never instanced.
    let (frame, small_frame) = (1920 * 1080, 1280 * 720);
    let still = 800 * 800 * 32;
    assert!(auto_instances(10_031_907, 69_669, frame));
    assert!(!auto_instances(1_114_659, 69_669, frame));
    assert!(auto_instances(1_114_659, 69_669, small_frame));
    assert!(!auto_instances(1_114_659, 69_669, still));
    assert!(auto_instances(10_031_907, 69_669, still));
    assert!(!auto_instances(36, 14, 1));
    let herd = prepared("herd", 1920, 1, "auto");
    assert!(herd.data.instancing.is_some(), "{}", herd.features.explain());
    let bunnies = prepared("instances", 800, 32, "auto");
    assert!(bunnies.data.instancing.is_none(), "{}", bunnies.features.explain());
    let single = prepared("bunny", 8, 1, "auto");
    assert!(single.data.instancing.is_none());
    assert!(
        single.features.explain().contains("flattened"),
        "{}",
        single.features.explain()
    );
    // A sphere scaled unevenly would be an ellipsoid through its instance.
    let mut scene = Scene::builtin("spheres").unwrap();
    let k = scene
        .objects
        .iter()
        .position(|o| matches!(o.shape, Shape::Sphere { .. }))
        .unwrap();
    scene.objects[k].transform.scale.x *= 2.0;
    let e = scene.gpu_data_as(0.0, InstancingMode::On).unwrap_err();
    assert!(e.contains(&format!("object {k}")) && e.contains("unevenly"), "{e}");
    // Auto, for frames that would be instanced, flattens it instead and says why; off never
    // instances.
    let many = Scene::builtin("instances").unwrap();
    let mut uneven = many.clone();
    let light = uneven
        .objects
        .iter()
        .position(|o| matches!(o.shape, Shape::Sphere { .. }))
        .unwrap();
    uneven.objects[light].transform.scale.y = 3.0;
    assert!(many
        .gpu_data_for(0.0, InstancingMode::Auto, 1)
        .unwrap()
        .instancing
        .is_some());
    let d = uneven.gpu_data_for(0.0, InstancingMode::Auto, 1).unwrap();
    assert!(
        d.instancing.is_none() && d.instancing_why.contains("unevenly"),
        "{}",
        d.instancing_why
    );
    assert!(many.gpu_data_as(0.0, InstancingMode::Off).unwrap().instancing.is_none());
}

#[test]
fn a_mixed_scene_renders_as_its_flattened_form_on_the_cpu() {
    for time in [0.0, 0.7] {
        let (on, off) = (
            prepared_at(POND, 40, 16, "auto", time),
            prepared_at(POND, 40, 16, "off", time),
        );
        let i = on.data.instancing.as_ref().expect("the scene asks for instances");
        // The pond's 64 x 64 grid and the ground's quad in the group; twelve bunnies and the
        // lamp instanced, and the group's instance.
        assert_eq!(i.world_tris, 2 * 64 * 64 + 2);
        assert_eq!(on.frame.n_instances, 14);
        assert!(off.data.instancing.is_none());
        let explain = on.features.explain();
        assert!(
            explain.contains("12 instance = true") && explain.contains("2 in the world-space group"),
            "{explain}"
        );
        let cpu = |p: &Prepared| render_cpu(&p.data, &p.frame, p.spp, p.build(p.spp), &|_| {});
        let (a, b) = (cpu(&on), cpu(&off));
        let d = diff_stats(&a.picture, &b.picture).expect("same size");
        assert!(
            d.relative_rmse < 0.02,
            "time {time}: mixed and flattened differ: relative RMSE {}",
            d.relative_rmse
        );
        assert!(b.picture.mean_luminance() > 0.0);
    }
    // The wave moves the pond: frames at two moments differ there.
    let frame = |t: f32| {
        let p = prepared_at(POND, 40, 16, "auto", t);
        render_cpu(&p.data, &p.frame, p.spp, p.build(p.spp), &|_| {}).picture
    };
    let d = diff_stats(&frame(0.0), &frame(0.7)).expect("same size");
    assert!(d.relative_rmse > 0.01, "the wave did not move: {}", d.relative_rmse);
}

#[test]
fn the_gpu_builds_and_refits_a_mixed_scenes_group_as_the_cpu() {
    let Some(gpu) = gpu("the_gpu_builds_and_refits_a_mixed_scenes_group_as_the_cpu") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    // At a moment of the wave: the GPU's transform waves the pond as the CPU's does, bit for
    // bit (both levels' nodes equal), and the images agree.
    let p = prepared_at(POND, 32, 8, "auto", 0.7);
    let c = compare(&p, &gpu, &kernels, true).expect("compare");
    assert!(c.bvh_identical, "the GPU's levels differ from the CPU's");
    assert!(c.stats.relative_rmse < 0.02, "relative RMSE {}", c.stats.relative_rmse);
    // Frames go on: objects moved to later moments (the wave's phase, the spinning bunnies),
    // the group transformed, its tree built by the first frame, refit by the next
    // `GROUP_REFITS` over its triangles as they are then, built again by the one after; the
    // top level, built (restructured) when the scene loads, refit by the next `TOP_REFITS`
    // frames over the instances' boxes as they are then (the first `TOP_ROUNDS - 1`
    // restructuring it again), built again by the one after (coding the instances in the
    // bounds of the build before: `cpu::build_coded`). The CPU's levels with both trees made
    // the same way (`cpu::refit`) are sound and equal, bit for bit.
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    r.set_build(p.build(1));
    r.load(&p.data, &p.frame).expect("load");
    let i = p.data.instancing.as_ref().unwrap();
    let opts = raytrace::bvh::BuildOptions {
        wide: false,
        ..p.build(1)
    };
    let top_opts = raytrace::bvh::top_build(opts);
    // The top level's inputs, by the kernel both backends run.
    let boxes = |meshes: &[MeshPrims], placements: &[Placement]| {
        let l = raytrace::bvh::layout(meshes, placements).expect("layout");
        let n = l.instances.len() as u32;
        let mut b = vec![Triangle::default(); n as usize];
        (0..n).for_each(|k| instance_box(k, n, &l.instances, &l.objects, &mut b));
        b
    };
    let (meshes, placements) = raytrace::cpu::levels_inputs(&p.data, i, &p.data.objects);
    let mut top = (raytrace::cpu::build(&boxes(&meshes, &placements), &[], top_opts).0, 0);
    // The bounds of the top level's last build, in which the next codes its instances.
    let mut last = top.0.bounds;
    let mut group_built = None;
    for f in 0..TOP_REFITS + 2 {
        let t = 1.1 + f as f32 * 0.05;
        let objects = p.scene.objects_in(&p.data, t);
        r.set_objects(&objects).expect("move");
        r.render(1, true).expect("render");
        let (meshes, placements) = raytrace::cpu::levels_inputs(&p.data, i, &objects);
        let group_opts = raytrace::bvh::mesh_build(&placements, 0, opts);
        let group = match &group_built {
            Some(b) if f % (GROUP_REFITS + 1) != 0 => {
                raytrace::cpu::refit(b, &meshes[0].tris, &[], group_opts).expect("refit")
            }
            _ => group_built
                .insert(raytrace::cpu::build(&meshes[0].tris, &[], group_opts).0)
                .clone(),
        };
        let b = boxes(&meshes, &placements);
        top = if top.1 < TOP_REFITS {
            // The first `TOP_ROUNDS - 1` refits after a build restructure it again.
            let refit = if top.1 + 1 < TOP_ROUNDS {
                raytrace::cpu::refit_round
            } else {
                raytrace::cpu::refit
            };
            (refit(&top.0, &b, &[], top_opts).expect("refit"), top.1 + 1)
        } else {
            let built = raytrace::cpu::build_coded(&b, &[], top_opts, Some(&last)).0;
            last = built.bounds;
            (built, 0)
        };
        let checked = [
            0,
            1,
            2,
            GROUP_REFITS,
            GROUP_REFITS + 1,
            TOP_REFITS - 1,
            TOP_REFITS,
            TOP_REFITS + 1,
        ];
        if !checked.contains(&f) {
            continue;
        }
        let mut cpu = raytrace::bvh::build_levels(&meshes, &placements, opts).expect("levels");
        assert_eq!(cpu.boxes, b);
        let first = cpu.mesh_nodes[0] as usize;
        cpu.nodes[first..first + group.nodes.len()].copy_from_slice(&group.nodes);
        cpu.mesh_parents[0] = group.parents;
        let at = cpu.top as usize;
        cpu.nodes[at..].copy_from_slice(&top.0.nodes);
        cpu.top_parents = top.0.parents.clone();
        raytrace::bvh::validate_levels(&cpu, &meshes, &placements).expect("valid levels");
        assert_eq!(r.bvh().expect("nodes").nodes, cpu.nodes, "frame {f}: the levels differ");
        assert_eq!(
            r.world().expect("primitives").0,
            cpu.tris,
            "frame {f}: the primitives differ"
        );
    }
    // Picking names the object in the group (the pond) and an instance's (a bunny).
    let pond = p.scene.objects.iter().position(|o| o.name == "pond").unwrap() as u32;
    let bunny = p.scene.objects.iter().position(|o| o.name == "bunny 3").unwrap();
    let b = p.data.objects[bunny].rows;
    let hits = r.cast_objects(&[down(0.3, 0.2), down(b[0][3], b[2][3])]).expect("cast");
    assert_eq!((hits[0].prim, hits[1].prim), (pond, bunny as u32), "{hits:?}");
    assert_no_validation_errors(&gpu);
}

#[test]
fn adding_and_removing_objects_keeps_the_meshes_bvhs() {
    let Some(gpu) = gpu("adding_and_removing_objects_keeps_the_meshes_bvhs") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let p = prepared("instances", 16, 1, "on");
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    r.load(&p.data, &p.frame).expect("load");
    let (built, kept) = r.meshes_built().expect("two levels");
    // The bunny, the ground's quad and the lamp's sphere.
    assert_eq!((built, kept), (3, 0));
    // An edit: a bunny added (a copy of bunny 5, 40 units on), bunny 7 removed.
    let mut scene = p.scene.clone();
    let mut copy = scene.objects[5].clone();
    copy.transform.translation.x += 40.0;
    scene.objects.push(copy);
    scene.objects.remove(7);
    let data = scene.gpu_data_as(0.0, InstancingMode::On).expect("data");
    let mut frame = scene.frame(&data);
    frame.features = p.frame.features;
    r.load(&data, &frame).expect("load the edited scene");
    // No mesh built again: only the top level over the objects as they are now.
    assert_eq!(r.meshes_built(), Some((0, 3)));
    r.render(1, true).expect("render");
    // The same levels and the same picture as the edited scene loaded afresh.
    let mut fresh = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    fresh.load(&data, &frame).expect("load");
    fresh.render(1, true).expect("render");
    assert_eq!(r.bvh().expect("nodes").nodes, fresh.bvh().expect("nodes").nodes);
    assert_eq!(r.world().expect("primitives"), fresh.world().expect("primitives"));
    assert_eq!(r.sums().expect("image"), fresh.sums().expect("image"));
    // The added bunny is picked where it went, by its object's number.
    let added = (scene.objects.len() - 1) as u32;
    let o = data.objects[added as usize].rows;
    assert_eq!(r.cast_objects(&[down(o[0][3], o[2][3])]).expect("cast")[0].prim, added);
    assert_no_validation_errors(&gpu);
}

/// The persistent path tracer (`path::render_tiles`, what every frame runs on GPUs other than
/// lavapipe) renders every pixel as the 8x8 tiles do, bit
/// for bit: the Cornell box in two levels (an instanced light, next-event estimation), the pond
/// (its world-space group) and Suzanne flattened, with and without the denoiser's guides
/// (whose buffer's last entry holds the counter), at 64x64 (an invocation takes at most one
/// pixel) and 720x720 (an H100 invocation takes about four). Skipped on lavapipe, which
/// renders with the tiles: llvmpipe runs a workgroup's subgroups one after another, so its
/// first ones take most of the pixels, and its loop limiter (65,535 iterations of a loop an
/// invocation, the count kept across the loop's entries) then ends their paths early (pixels
/// lost or darker there, and not the same from run to run).
#[test]
fn the_persistent_path_tracer_renders_every_pixel_as_the_tiles_do() {
    let Some(gpu) = gpu("the_persistent_path_tracer_renders_every_pixel_as_the_tiles_do") else {
        return;
    };
    if gpu.is_lavapipe() {
        eprintln!("SKIPPED: lavapipe renders with the tiles (its loop limiter cuts persistent invocations short)");
        return;
    }
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    for size in [64, 720] {
        for (scene, instancing) in [("cornell", "on"), (POND, "on"), ("suzanne", "off")] {
            let p = prepared(scene, size, 4, instancing);
            assert_eq!(p.frame.features & FEATURE_INSTANCES != 0, instancing == "on", "{scene}");
            let render = |persistent: bool, denoise: Denoise| {
                let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
                r.set_persistent(Some(persistent));
                r.load(&p.data, &p.frame).expect("load");
                r.set_denoise(denoise).expect("denoiser");
                r.render(4, true).expect("render");
                let guides = match denoise {
                    Denoise::Off => Vec::new(),
                    _ => r.guides().expect("guides"),
                };
                (r.sums().expect("sums"), guides)
            };
            for denoise in [Denoise::Off, Denoise::EveryFrame] {
                let (tiles, tiles_guides) = render(false, denoise);
                let (persistent, persistent_guides) = render(true, denoise);
                assert!(tiles.iter().all(|s| s[3] > 0.0), "{scene}: a pixel without rays");
                let apart = tiles.iter().zip(&persistent).filter(|(a, b)| a != b).count();
                assert_eq!(apart, 0, "{scene} at {size} ({denoise:?}): {apart} pixels differ");
                assert!(
                    tiles_guides == persistent_guides,
                    "{scene} at {size} ({denoise:?}): the guides differ"
                );
            }
        }
    }
    assert_no_validation_errors(&gpu);
}

/// Scenes in two levels with next-event estimation queue their shadow rays
/// (`path_queue`, `path_queue_persistent`: the path tracer writes each light sample to a
/// queue, one sample a dispatch; `shadow_resolve` casts them and adds the lit ones): the sums are the bits of the
/// shadow rays cast in place, in one band of rows and in several (bands of 8 and of 20 rows
/// of a 36-row frame, the last band shorter), in tiles and persistent (not on lavapipe, see above), and so are the
/// denoiser's guides of a frame of one sample. The Cornell box (an instanced light) and the
/// pond (a world-space group, sphere light).
#[test]
fn queued_shadow_rays_render_as_cast_in_place() {
    let Some(gpu) = gpu("queued_shadow_rays_render_as_cast_in_place") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let persistent: &[bool] = if gpu.is_lavapipe() { &[false] } else { &[false, true] };
    for scene in ["cornell", POND] {
        let p = prepared(scene, 36, 4, "on");
        assert_ne!(p.frame.features & FEATURE_NEE, 0, "{scene}: no next-event estimation");
        let render = |queue: bool, rows: Option<u32>, persistent: bool, spp: u32, denoise: Denoise| {
            let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
            r.set_shadow_queue(Some(queue));
            r.set_queue_rows(rows);
            r.set_persistent(Some(persistent));
            r.load(&p.data, &p.frame).expect("load");
            r.set_denoise(denoise).expect("denoiser");
            r.render(spp, true).expect("render");
            let guides = match denoise {
                Denoise::Off => Vec::new(),
                _ => r.guides().expect("guides"),
            };
            (r.sums().expect("sums"), guides)
        };
        let (in_place, _) = render(false, None, false, 4, Denoise::Off);
        let (in_place_1, in_place_guides) = render(false, None, false, 1, Denoise::EveryFrame);
        assert!(in_place.iter().all(|s| s[3] > 0.0), "{scene}: a pixel without rays");
        for &persistent in persistent {
            for rows in [None, Some(8), Some(20)] {
                let (queued, _) = render(true, rows, persistent, 4, Denoise::Off);
                let apart = in_place.iter().zip(&queued).filter(|(a, b)| a != b).count();
                assert_eq!(
                    apart, 0,
                    "{scene}, bands {rows:?}, persistent {persistent}: {apart} pixels differ"
                );
                let (queued_1, queued_guides) = render(true, rows, persistent, 1, Denoise::EveryFrame);
                assert!(queued_1 == in_place_1, "{scene}, bands {rows:?}: one sample differs");
                assert!(
                    queued_guides == in_place_guides,
                    "{scene}, bands {rows:?}, persistent {persistent}: the guides differ"
                );
            }
        }
    }
    assert_no_validation_errors(&gpu);
}
