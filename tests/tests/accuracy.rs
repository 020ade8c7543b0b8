//! `raytrace bench accuracy` end to end on a tiny frame: the error falls with samples, the
//! robust intersection tests never leak where Moller-Trumbore does, and the report's plots
//! are real PNGs.
use integration_tests::gpu;
use raytrace::bench::accuracy::{cached_reference, markdown, plots, run, Options, References};
use raytrace::cli::SceneArgs;
use raytrace::gpu::Kernels;
use std::sync::Arc;

#[test]
fn accuracy_bench_measures_error_time_and_leaks() {
    let Some(gpu) = gpu("accuracy_bench_measures_error_time_and_leaks") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("raytrace-accuracy-{}", std::process::id()));
    let o = Options {
        scene: "cornell".into(),
        size: (16, 16),
        max_spp: 16,
        reference_spp: 256,
        depth_spp: 2,
        speed_spp: 1,
        speed_size: (16, 16),
        runs: 1,
        cache: dir.join("cache"),
        devices: None,
        accel: Default::default(),
        driver_build: Default::default(),
    };
    let r = run(&gpu, &o).expect("bench accuracy");
    // Plain, NEE, NEE + MIS, without roulette, and NEE + MIS denoised.
    assert_eq!(r.convergence.len(), 5);
    assert!(r.convergence[4].name.contains("denoised"), "{}", r.convergence[4].name);
    for c in &r.convergence {
        let spp: Vec<u32> = c.points.iter().map(|p| p.spp).collect();
        assert_eq!(spp, [1, 2, 4, 8, 16], "{}", c.name);
        assert!(
            c.points.iter().all(|p| p.ms > 0.0 && p.rel_mse.is_finite()),
            "{}: {:?}",
            c.name,
            c.points
        );
    }
    let nee_mis = &r.convergence[2].points;
    assert!(
        nee_mis[4].rel_mse < nee_mis[0].rel_mse,
        "NEE + MIS: the error did not fall from 1 to 16 spp: {nee_mis:?}"
    );
    assert!(r
        .bvh
        .iter()
        .take(2)
        .all(|b| b.sah >= 1.0 && b.build_ms > 0.0 && b.rays_per_s > 0.0));
    let robust = &r.precision[0];
    assert_eq!((robust.leaks_bvh, robust.leaks_brute), (0, 0), "{robust:?}");
    assert!(robust.rays > 10_000);
    let mt = &r.precision[1];
    assert!(mt.leaks_brute > 0, "Moller-Trumbore found every shared edge: {mt:?}");
    // The reference is cached for later runs: one EXR file.
    let cached = std::fs::read_dir(&o.cache).expect("cache").count();
    assert_eq!(cached, 1);
    let names = plots(&r, &dir, "t").expect("plots");
    for n in &names {
        let img = image::open(dir.join(n)).expect("plot decodes");
        assert_eq!((img.width(), img.height()), (900, 600));
    }
    assert!(markdown(&r, &names).contains("| NEE + MIS |"));
    integration_tests::assert_no_validation_errors(&gpu);
}

/// `--devices` on the benchmarks' references: a reference split across two devices (here the
/// first device opened twice, as CI has one) is one device's image within float rounding,
/// kept under the same cache name, and read back from the cache the next time.
#[test]
fn a_reference_split_across_devices_is_one_devices_image() {
    let Some(gpu) = gpu("a_reference_split_across_devices_is_one_devices_image") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("raytrace-references-{}", std::process::id()));
    let p = <SceneArgs as clap::Parser>::try_parse_from(["raytrace", "cornell", "--size", "24x16"])
        .expect("arguments")
        .prepare()
        .expect("scene");
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    // The objects moved, as the denoise benchmark's frames move them.
    let mut objects = p.data.objects.clone();
    objects[0].rows[1][3] += 0.25;
    let reference = |refs: &mut References, cache: &str| {
        let (data, f, name) = (&p.data, &p.frame, &p.scene.name);
        cached_reference(refs, data, &objects, f, name, 64, &dir.join(cache)).expect("reference")
    };
    let one = reference(&mut References::new(&gpu, &kernels, None).expect("renderer"), "one");
    let mut two = References::new(&gpu, &kernels, Some("0,0")).expect("two devices");
    let split = reference(&mut two, "two");
    assert!(split.made.contains("2 devices"), "{}", split.made);
    assert_eq!(one.path.file_name(), split.path.file_name());
    let peak = one.pixels.iter().flatten().fold(0f32, |m, &v| m.max(v));
    let diff = one
        .pixels
        .iter()
        .flatten()
        .zip(split.pixels.iter().flatten())
        .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        peak > 0.0 && diff <= 1e-5 * peak,
        "split reference differs by {diff} (peak {peak})"
    );
    // Moving the objects made another image than the scene's own placement would.
    let unmoved = cached_reference(
        &mut two,
        &p.data,
        &p.data.objects,
        &p.frame,
        "cornell",
        64,
        &dir.join("two"),
    )
    .expect("unmoved reference");
    assert_ne!(unmoved.path, split.path);
    assert_ne!(unmoved.pixels, split.pixels);
    assert_eq!(reference(&mut two, "two").made, "cached");
    drop(two);
    let _ = std::fs::remove_dir_all(&dir);
    integration_tests::assert_no_validation_errors(&gpu);
}
