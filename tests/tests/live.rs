//! A live scene edited between frames, as the viewer edits it: after every addition, move,
//! rotation and removal the BVH the GPU rebuilt passes the validator, and the picture equals
//! a headless render of the edited scene loaded from scratch.
use glam::Vec3;
use integration_tests::{assert_no_validation_errors, gpu};
use raytrace::bvh::validate;
use raytrace::gpu::{Gpu, GpuRenderer, Kernels};
use raytrace::picture::Picture;
use raytrace::scene::Scene;
use raytrace::view::LiveScene;
use std::sync::Arc;

const SPP: u32 = 4;

/// `SPP` samples of the live scene through the renderer that has followed every edit.
fn render_live(live: &mut LiveScene, r: &mut GpuRenderer) -> Picture {
    live.sync(r).expect("sync");
    r.render(SPP, true).expect("render");
    r.picture().expect("picture")
}

/// The same scene rendered by a fresh renderer that loads it once.
fn render_fresh(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, live: &LiveScene) -> Picture {
    let mut r = GpuRenderer::new(gpu, kernels).expect("renderer");
    let data = live.scene.gpu_data(live.time);
    let frame = live.frame();
    r.load(&data, &frame).expect("load");
    r.render(SPP, true).expect("render");
    r.picture().expect("picture")
}

fn check(step: &str, gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, live: &mut LiveScene, r: &mut GpuRenderer) {
    let picture = render_live(live, r);
    let bvh = r.bvh().expect("bvh");
    let (tris, spheres) = r.world().expect("world");
    let stats = validate(&bvh.nodes, &bvh.parents, &tris, &spheres)
        .unwrap_or_else(|e| panic!("after {step}: invalid BVH: {e}"));
    let (n_tris, n_spheres) = live.scene.counts();
    assert_eq!((tris.len(), spheres.len()), (n_tris, n_spheres), "after {step}");
    let fresh = render_fresh(gpu, kernels, live);
    assert_eq!(
        picture.accum, fresh.accum,
        "after {step}: the edited scene renders differently from the same scene loaded afresh"
    );
    assert_eq!(picture.display, fresh.display, "after {step}");
    eprintln!("{step}: {stats:?}");
}

#[test]
fn edits_between_frames_keep_the_bvh_valid_and_the_picture_that_of_the_edited_scene() {
    let Some(gpu) = gpu("edits_between_frames_keep_the_bvh_valid_and_the_picture_that_of_the_edited_scene") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    let mut scene = Scene::builtin("cornell").expect("cornell");
    (scene.settings.width, scene.settings.height) = (48, 40);
    let mut live = LiveScene::new(scene);
    check("loading", &gpu, &kernels, &mut live, &mut r);
    let before = render_live(&mut live, &mut r);

    let sphere = live.add_sphere(Vec3::new(278.0, 278.0, 200.0), 80.0);
    check("adding a sphere", &gpu, &kernels, &mut live, &mut r);
    // The sphere is in the middle of the view: picking there finds it.
    let f = *r.frame();
    let (picked, _) = live
        .pick(&mut r, f.width as f32 / 2.0, f.height as f32 / 2.0)
        .expect("pick")
        .expect("something under the centre");
    assert_eq!(picked, sphere, "picked {}", live.scene.objects[picked].name);

    let mesh = live
        .add_mesh(0, Vec3::new(150.0, 100.0, 150.0), 60.0)
        .expect("add mesh");
    check("adding a mesh", &gpu, &kernels, &mut live, &mut r);
    live.translate(sphere, Vec3::new(60.0, 40.0, 0.0)).expect("move");
    live.rotate(mesh, Vec3::new(0.0, 30.0, 10.0)).expect("rotate");
    check("moving and rotating", &gpu, &kernels, &mut live, &mut r);
    live.remove(mesh).expect("remove mesh");
    live.remove(sphere).expect("remove sphere");
    check("removing both", &gpu, &kernels, &mut live, &mut r);
    let after = render_live(&mut live, &mut r);
    assert_eq!(
        before.accum, after.accum,
        "adding and removing again gives back the first picture"
    );

    let tall = live
        .scene
        .objects
        .iter()
        .position(|o| o.name.contains("tall"))
        .expect("a tall block");
    live.remove(tall).expect("remove the tall block");
    check("removing a block of the scene", &gpu, &kernels, &mut live, &mut r);
    assert_no_validation_errors(&gpu);
}

#[test]
fn an_animated_scene_restarts_accumulation_only_when_something_moves() {
    let Some(gpu) = gpu("an_animated_scene_restarts_accumulation_only_when_something_moves") else {
        return;
    };
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let mut r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    let mut scene = Scene::builtin("cornell").expect("cornell");
    (scene.settings.width, scene.settings.height) = (16, 16);
    scene.objects[0].animation.spin_deg_per_s = Vec3::new(0.0, 45.0, 0.0);
    let mut live = LiveScene::new(scene);
    assert!(live.animated());
    assert!(live.sync(&mut r).expect("sync"), "the first sync loads");
    r.render(1, true).expect("render");
    assert!(!live.sync(&mut r).expect("sync"), "nothing moved");
    r.render(1, true).expect("render");
    assert_eq!(r.samples(), 2);
    live.time = 0.5;
    assert!(live.sync(&mut r).expect("sync"), "the spinning object moved");
    assert_eq!(r.samples(), 0);
    live.scene.settings.max_depth = 3;
    live.time = 0.5;
    r.render(1, true).expect("render");
    assert!(live.sync(&mut r).expect("sync"), "a new depth restarts");
    assert_no_validation_errors(&gpu);
}
