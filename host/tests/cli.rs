//! The command line as a newcomer meets it: `raytrace render` says which backend it chose and
//! why (the CPU executor where the only Vulkan device runs on the CPU, as lavapipe in CI
//! does), `--backend gpu` overrides that, and `raytrace info` lists every device and backend.
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_raytrace");

fn run(args: &[&str]) -> (Output, String, String) {
    let o = Command::new(BIN).args(args).output().expect("running raytrace");
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    (o, out, err)
}

fn picture(test: &str) -> String {
    let d = std::env::temp_dir().join(format!("raytrace-cli-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&d).expect("creating a temporary folder");
    d.join("picture.png").display().to_string()
}

/// Whether a Vulkan device that is not a CPU implementation exists.
fn has_real_gpu() -> bool {
    raytrace::gpu::Gpu::list().is_ok_and(|d| d.iter().any(|d| !d.is_cpu()))
}

#[test]
fn render_says_which_backend_it_chose_and_why() {
    let out = picture("auto");
    let (o, stdout, stderr) = run(&["render", "cornell", "--size", "32x32", "--spp", "1", "--out", &out]);
    assert!(o.status.success(), "render failed:\n{stderr}");
    assert!(std::path::Path::new(&out).exists(), "no picture written");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("backend: "))
        .unwrap_or_else(|| panic!("no backend line in:\n{stderr}"));
    if has_real_gpu() {
        assert_eq!(line, "backend: GPU");
    } else {
        assert!(line.contains("CPU executor"), "{line}");
        assert!(
            stdout.contains("on CPU executor"),
            "the summary names another device:\n{stdout}"
        );
    }
}

#[test]
fn backend_gpu_uses_a_cpu_vulkan_device_when_asked() {
    let Ok(devices) = raytrace::gpu::Gpu::list() else {
        eprintln!("SKIPPED backend_gpu_uses_a_cpu_vulkan_device_when_asked: no Vulkan");
        return;
    };
    let Some(d) = devices.first() else {
        eprintln!("SKIPPED backend_gpu_uses_a_cpu_vulkan_device_when_asked: no Vulkan device");
        return;
    };
    let out = picture("gpu");
    let args = [
        "render",
        "cornell",
        "--size",
        "32x32",
        "--spp",
        "1",
        "--backend",
        "gpu",
        "--out",
        &out,
    ];
    let (o, stdout, stderr) = run(&args);
    assert!(o.status.success(), "render failed:\n{stderr}");
    assert!(
        !stderr.contains("backend: "),
        "--backend gpu was second-guessed:\n{stderr}"
    );
    if devices.iter().all(|d| d.is_cpu()) {
        assert!(
            stdout.contains(&d.name),
            "the summary does not name {}:\n{stdout}",
            d.name
        );
    }
}

#[test]
fn info_lists_every_device_and_the_cpu_executor_with_a_speed() {
    let (o, stdout, stderr) = run(&["info"]);
    let devices = raytrace::gpu::Gpu::list().unwrap_or_default();
    assert_eq!(
        o.status.success(),
        !devices.is_empty(),
        "exit status:\n{stdout}\n{stderr}"
    );
    for d in &devices {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("Vulkan device {}: {}", d.index, d.name)))
            .unwrap_or_else(|| panic!("device {} missing from:\n{stdout}", d.name));
        assert!(line.ends_with("Mrays/s"), "{line}");
    }
    let cpu = stdout
        .lines()
        .find(|l| l.starts_with("CPU executor ("))
        .unwrap_or_else(|| panic!("no CPU executor line in:\n{stdout}"));
    assert!(cpu.ends_with("Mrays/s"), "{cpu}");
    assert!(stdout.contains("`raytrace render` picks: "), "{stdout}");
}

/// The benches that take `--accel driver` open the device with the driver's ray tracing and
/// trace through it; where the device has none, they fail naming what it lacks.
#[test]
fn benches_trace_through_the_driver_or_say_what_the_device_lacks() {
    let Ok(devices) = raytrace::gpu::Gpu::list() else {
        eprintln!("SKIPPED benches_trace_through_the_driver_or_say_what_the_device_lacks: no Vulkan");
        return;
    };
    if devices.is_empty() {
        eprintln!("SKIPPED benches_trace_through_the_driver_or_say_what_the_device_lacks: no Vulkan device");
        return;
    }
    let dir = std::path::PathBuf::from(picture("bench-driver")).with_file_name("results");
    let out = dir.display().to_string();
    let cache = dir.join("cache").display().to_string();
    // The pond's objects are marked `instance = true`: the driver traces it in two levels,
    // and `bench trace` makes its batches from the flattened scene.
    let trace_scenes = concat!("cornell,", env!("CARGO_MANIFEST_DIR"), "/../scenes/pond.toml");
    let benches: [&[&str]; 5] = [
        &[
            "bench",
            "trace",
            "--accel",
            "driver",
            "--scenes",
            trace_scenes,
            "--size",
            "16x16",
            "--spp",
            "1",
            "--runs",
            "1",
        ],
        &[
            "bench",
            "devices",
            "--accel",
            "driver",
            "--devices",
            "0",
            "--size",
            "16x16",
            "--spp",
            "1",
            "--runs",
            "1",
        ],
        &[
            "bench",
            "accuracy",
            "--accel",
            "driver",
            "--size",
            "16x16",
            "--max-spp",
            "2",
            "--reference-spp",
            "8",
            "--depth-spp",
            "1",
            "--speed-spp",
            "1",
            "--speed-size",
            "16x16",
            "--runs",
            "1",
            "--cache",
            &cache,
        ],
        &[
            "bench", "features", "--accel", "driver", "--scenes", "cornell", "--size", "16x16", "--spp", "1", "--runs",
            "1",
        ],
        &[
            "bench",
            "table2",
            "--accel",
            "driver",
            "--runs",
            "1",
            "--brute-spp",
            "1",
            "--cpu-spp",
            "1",
        ],
    ];
    for args in benches {
        let mut args = args.to_vec();
        args.extend(["--out", &out]);
        let (o, _, stderr) = run(&args);
        let ray_tracing = raytrace::gpu::Gpu::new(&raytrace::gpu::GpuOptions {
            ray_tracing: true,
            ..Default::default()
        })
        .map(|g| g.ray_tracing.is_ok());
        if ray_tracing.unwrap_or(false) {
            assert!(o.status.success(), "{args:?} failed:\n{stderr}");
            // Table 2 adds the driver's columns to its own report.
            let kind = match args[1] {
                "table2" => "table2-".to_string(),
                "accuracy" => "accuracy-".to_string(),
                bench => format!("{bench}-driver-"),
            };
            let written = std::fs::read_dir(&dir)
                .expect("results folder")
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(&kind));
            assert!(written, "{args:?} wrote no {kind}* file");
        } else {
            assert!(!o.status.success(), "{args:?} succeeded without ray tracing");
            assert!(
                stderr.contains("VK_KHR_ray_tracing_pipeline") && stderr.contains("--accel lbvh"),
                "{args:?}:\n{stderr}"
            );
        }
    }
}

/// `--accel auto` (the default) traces a scene in two levels through the driver's
/// structures where the device has ray-tracing pipelines, and through the project's BVH
/// elsewhere; `--explain` says how it decides and the summary which it took.
#[test]
fn accel_auto_takes_the_drivers_structures_only_for_two_levels_on_a_device_with_them() {
    let Ok(devices) = raytrace::gpu::Gpu::list() else {
        eprintln!("SKIPPED accel_auto_...: no Vulkan");
        return;
    };
    if devices.is_empty() {
        eprintln!("SKIPPED accel_auto_...: no Vulkan device");
        return;
    }
    let ray_tracing = raytrace::gpu::Gpu::new(&raytrace::gpu::GpuOptions {
        ray_tracing: true,
        ..Default::default()
    })
    .is_ok_and(|g| g.ray_tracing.is_ok());
    let out = picture("accel-auto");
    for (instancing, two_levels) in [("on", true), ("off", false)] {
        let (o, stdout, stderr) = run(&[
            "render",
            "instances",
            "--instancing",
            instancing,
            "--backend",
            "gpu",
            "--size",
            "16x16",
            "--spp",
            "1",
            "--explain",
            "--out",
            &out,
        ]);
        assert!(o.status.success(), "--instancing {instancing}:\n{stderr}");
        assert!(stdout.contains("--accel auto"), "--instancing {instancing}:\n{stdout}");
        let summary = stdout
            .lines()
            .find(|l| l.starts_with("instances 16x16"))
            .unwrap_or_else(|| panic!("no summary in:\n{stdout}"));
        assert_eq!(
            summary.contains("driver's acceleration structures"),
            two_levels && ray_tracing,
            "--instancing {instancing}, ray tracing {ray_tracing}: {summary}"
        );
    }
}

/// `--explain` says which tree `--tree auto` builds for the frame and why: the radix tree
/// below 100 million path segments a frame, H-PLOC from there (the spheres with NEE at
/// 1024x1024 and depth 64: 134 million) and for scenes of at most 64 primitives (the Cornell
/// box's 36).
#[test]
fn explain_says_which_tree_auto_builds() {
    let out = picture("explain-tree");
    for (scene, prims, w, depth, ploc) in [
        ("spheres", 485u64, 16u64, 16u64, false),
        ("spheres", 485, 1024, 64, true),
        ("cornell", 36, 16, 16, true),
    ] {
        let (size, depth_arg) = (format!("{w}x{w}"), depth.to_string());
        let (o, stdout, stderr) = run(&[
            "render",
            scene,
            "--backend",
            "cpu",
            "--size",
            &size,
            "--spp",
            "1",
            "--depth",
            &depth_arg,
            "--explain",
            "--out",
            &out,
        ]);
        assert!(o.status.success(), "{scene} {size}:\n{stderr}");
        let line = stdout
            .lines()
            .find(|l| l.starts_with("BVH traced"))
            .unwrap_or_else(|| panic!("no BVH line in:\n{stdout}"));
        assert_eq!(line.contains("built by H-PLOC"), ploc, "{scene} {size}: {line}");
        // Pixels x samples x depth, twice with next-event estimation (on by default).
        let segments = w * w * depth * 2;
        let why = format!("--tree auto: {segments} path segments a frame, {prims} primitives; H-PLOC from 100000000 segments or up to 64 primitives");
        assert!(line.contains(&why), "{line}");
    }
}

/// `--explain` says which path loop the frame runs: the stepped loop for paths of more than
/// one segment without next-event estimation, else a segment at a time.
#[test]
fn explain_says_which_path_loop_runs() {
    let out = picture("explain-loop");
    for (extra, stepped) in [
        (&[][..], false),
        (&["--no-nee"][..], true),
        (&["--no-nee", "--depth", "1"][..], false),
    ] {
        let args = [
            &[
                "render",
                "cornell",
                "--backend",
                "cpu",
                "--size",
                "8x8",
                "--spp",
                "1",
                "--explain",
                "--out",
                &out,
            ][..],
            extra,
        ]
        .concat();
        let (o, stdout, stderr) = run(&args);
        assert!(o.status.success(), "{extra:?}:\n{stderr}");
        let line = stdout
            .lines()
            .find(|l| l.starts_with("path loop"))
            .unwrap_or_else(|| panic!("no path loop line in:\n{stdout}"));
        assert_eq!(
            line.contains("stepped in a loop of its own"),
            stepped,
            "{extra:?}: {line}"
        );
    }
}

/// `raytrace compare` checks the GPU's BVH against the CPU executor's build over the GPU's
/// own world-space primitives: at 8 spp `--tree auto` builds by H-PLOC, whose merges follow
/// the boxes' bits, which the backends' transforms may round differently.
#[test]
fn compare_passes_with_an_h_ploc_tree() {
    if raytrace::gpu::Gpu::list().map_or(true, |d| d.is_empty()) {
        eprintln!("SKIPPED compare_passes_with_an_h_ploc_tree: no Vulkan device");
        return;
    }
    let out = picture("compare-ploc");
    let (o, stdout, stderr) = run(&["compare", "cornell", "--size", "48x48", "--spp", "8", "--out", &out]);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("world-space primitives, bit for bit: true"), "{stdout}");
}

/// `bench accuracy --devices` names a device that is not there before rendering anything.
#[test]
fn a_benchmarks_reference_devices_are_checked() {
    if raytrace::gpu::Gpu::list().map_or(true, |d| d.is_empty()) {
        eprintln!("SKIPPED a_benchmarks_reference_devices_are_checked: no Vulkan device");
        return;
    }
    let dir = std::path::PathBuf::from(picture("bench-reference-devices")).with_file_name("cache");
    let cache = dir.display().to_string();
    let (o, _, stderr) = run(&[
        "bench",
        "accuracy",
        "--size",
        "8x8",
        "--max-spp",
        "1",
        "--reference-spp",
        "4",
        "--devices",
        "0,99",
        "--cache",
        &cache,
    ]);
    assert!(!o.status.success(), "a missing device was taken");
    assert!(stderr.contains("--devices") && stderr.contains("device 99"), "{stderr}");
    assert!(!dir.exists(), "a reference was written: {}", dir.display());
}

/// `bench denoise` end to end on a tiny path, its references split across two devices (the
/// first opened twice): a report with every method's row and a reference per frame (three
/// frames and the still view's) in the cache.
#[test]
fn the_denoise_bench_reports_every_method_with_references_split_across_devices() {
    if raytrace::gpu::Gpu::list().map_or(true, |d| d.is_empty()) {
        eprintln!(
            "SKIPPED the_denoise_bench_reports_every_method_with_references_split_across_devices: no Vulkan device"
        );
        return;
    }
    let out = std::path::PathBuf::from(picture("bench-denoise")).with_file_name("denoise");
    let cache = out.join("cache");
    let (o, stdout, stderr) = run(&[
        "bench",
        "denoise",
        "--scenes",
        "cornell",
        "--size",
        "32x24",
        "--frames",
        "3",
        "--max-spp",
        "8",
        "--reference-spp",
        "32",
        "--still-frames",
        "4",
        "--crossover-spp",
        "16",
        "--timing-size",
        "64x48",
        "--timing-frames",
        "3",
        "--timing-runs",
        "1",
        "--devices",
        "0,0",
        "--cache",
        &cache.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]);
    assert!(o.status.success(), "bench denoise failed:\n{stderr}");
    for row in [
        "| raw 1 spp |",
        "| denoised 1 spp |",
        "| raw 8 spp |",
        "Crossover on the still view",
    ] {
        assert!(stdout.contains(row), "no {row:?} in:\n{stdout}");
    }
    assert_eq!(stderr.matches("rendered in").count(), 4, "{stderr}");
    assert!(stderr.contains("on 2 devices"), "{stderr}");
    let references = std::fs::read_dir(&cache).expect("cache").count();
    assert_eq!(references, 4, "references cached");
}
