//! Kernels specialised to the scene render what the all-features kernel renders, on both
//! backends, and leaving a feature out really removes it.
use integration_tests::{assert_no_validation_errors, renderer};
use raytrace::cli::{Prepared, SceneArgs};
use raytrace::cpu::render_cpu;
use raytrace::picture::{diff_stats, max_display_diff, Picture};
use shared::types::FEATURES_ALL;

fn prepared(scene: &str, features: &str) -> Prepared {
    let mut args = vec!["raytrace", scene, "--size", "12x12", "--spp", "2"];
    if !features.is_empty() {
        args.extend(["--features", features]);
    }
    <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene")
}

fn cpu(p: &Prepared) -> Picture {
    render_cpu(&p.data, &p.frame, p.spp, p.build(p.spp), &|_| {}).picture
}

const SCENES: [&str; 3] = ["cornell", "suzanne", "spheres"];

#[test]
fn specialised_kernels_render_the_same_picture_on_the_cpu() {
    for scene in SCENES {
        let (all, spec) = (prepared(scene, "all"), prepared(scene, ""));
        assert_eq!(all.frame.features, FEATURES_ALL);
        assert_ne!(spec.frame.features, FEATURES_ALL, "{scene} needs every feature?");
        assert_eq!(cpu(&all), cpu(&spec), "{scene}: specialised CPU render differs");
    }
}

#[test]
fn specialised_kernels_render_the_same_picture_on_the_gpu() {
    let Some((gpu, mut r)) = renderer("specialised_kernels_render_the_same_picture_on_the_gpu") else {
        return;
    };
    let mut render = |p: &Prepared| {
        r.load(&p.data, &p.frame).expect("load");
        r.render(p.spp, true).expect("render");
        r.picture().expect("picture")
    };
    for scene in SCENES {
        let (a, b) = (render(&prepared(scene, "all")), render(&prepared(scene, "")));
        // Two programs compiled apart may round differently in the last bits; nothing more.
        let d = diff_stats(&a, &b).expect("diff");
        assert!(d.relative_rmse < 1e-3, "{scene}: relative RMSE {}", d.relative_rmse);
        assert!(
            max_display_diff(&a, &b) <= 1,
            "{scene}: display differs by {}",
            max_display_diff(&a, &b)
        );
    }
    // Leaving out a feature the scene uses changes the picture: the bits reach the kernel.
    let (a, b) = (render(&prepared("spheres", "")), render(&prepared("spheres", "-metal")));
    assert!(
        max_display_diff(&a, &b) > 10,
        "metal forced off left the spheres unchanged"
    );
    assert_no_validation_errors(&gpu);
}

#[test]
fn a_feature_forced_off_is_off_on_the_cpu_too() {
    let (a, b) = (cpu(&prepared("spheres", "")), cpu(&prepared("spheres", "-dielectric")));
    assert!(
        max_display_diff(&a, &b) > 10,
        "dielectric forced off left the spheres unchanged"
    );
}
