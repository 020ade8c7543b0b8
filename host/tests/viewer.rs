//! The viewer in a real window: `raytrace view` under the session's display, or under a fresh
//! Xvfb server (`xvfb-run`) where there is none, on whatever Vulkan device exists (lavapipe in
//! CI). Each run has the validation layer on; a validation error (objects leaked at exit
//! included) fails the test.
use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_raytrace");

fn required() -> bool {
    std::env::var("REQUIRE_VULKAN").is_ok_and(|v| v == "1")
}

fn skip_or_fail(test: &str, why: &str) -> Option<Output> {
    if required() {
        panic!("{test}: REQUIRE_VULKAN=1 but {why}");
    }
    eprintln!("SKIPPED {test}: {why}");
    None
}

/// Runs `raytrace ARGS` where a window can open; `None` (after a skip line) where no Vulkan
/// device or no display exists.
fn run_windowed(test: &str, args: &[&str]) -> Option<Output> {
    let info = Command::new(BIN).arg("info").output().expect("running raytrace info");
    if !info.status.success() {
        return skip_or_fail(
            test,
            &format!("no Vulkan device: {}", String::from_utf8_lossy(&info.stderr)),
        );
    }
    let out = if std::env::var_os("DISPLAY").is_some() {
        Command::new(BIN).args(args).output()
    } else {
        Command::new("xvfb-run")
            .args(["-a", "-s", "-screen 0 1024x768x24", BIN])
            .args(args)
            .output()
    };
    match out {
        Ok(o) => Some(o),
        Err(e) => skip_or_fail(
            test,
            &format!("no display and no xvfb-run ({e}): install xvfb and xauth"),
        ),
    }
}

fn temp(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("raytrace-viewer-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&d).expect("creating a temporary folder");
    d
}

/// Asserts that the run succeeded without validation errors; returns its stdout.
fn check(test: &str, o: &Output) -> String {
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        o.status.success(),
        "{test}: viewer failed ({})\nstdout:\n{stdout}\nstderr:\n{stderr}",
        o.status
    );
    assert!(
        !stderr.contains("validation error"),
        "{test}: Vulkan validation errors:\n{stderr}"
    );
    stdout
}

fn png(path: &Path) -> RgbImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
        .to_rgb8()
}

#[test]
fn presented_frames_equal_a_headless_render_of_the_same_samples() {
    // 8 frames of 2 samples each: 16 samples per pixel, accumulated while nothing moves, shown
    // without the denoiser.
    assert_viewer_shows_render(
        "presented_frames_equal_a_headless_render_of_the_same_samples",
        &["--spf", "2", "--frames", "8", "--no-denoise"],
        16,
    );
}

/// Runs the viewer on the Cornell box at 64x48 with `view_args`, and asserts that its last
/// presented frame equals `raytrace render cornell` of `spp` samples per pixel.
fn assert_viewer_shows_render(test: &str, view_args: &[&str], spp: u32) {
    let dir = temp(test);
    let shot = dir.join("shot.png");
    let mut args = vec!["--validation", "view", "cornell", "--size", "64x48"];
    args.extend_from_slice(view_args);
    args.extend(["--screenshot", shot.to_str().unwrap()]);
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    check(test, &o);
    assert_equals_render(&shot, &dir, spp);
}

/// Asserts that the screenshot `shot` equals `raytrace render cornell` at 64x48 and `spp`
/// samples per pixel (rendered into `dir`) up to one code value of rounding, and is not black.
fn assert_equals_render(shot: &Path, dir: &Path, spp: u32) {
    let reference = dir.join("reference.png");
    let r = Command::new(BIN)
        .args([
            "render",
            "cornell",
            "--size",
            "64x48",
            "--spp",
            &spp.to_string(),
            "--out",
        ])
        .arg(&reference)
        .output()
        .expect("running raytrace render");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (a, b) = (png(shot), png(&reference));
    assert_eq!(a.dimensions(), b.dimensions(), "screenshot size");
    // Same kernels, same sample indices, same accumulation order: the presented bytes equal
    // the headless render's up to one code value of rounding.
    let worst = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as i32 - y as i32).abs())
        .max()
        .unwrap_or(0);
    assert!(
        worst <= 1,
        "presented frame differs from the headless render by up to {worst} code values ({} vs {})",
        shot.display(),
        reference.display()
    );
    let mean = a.as_raw().iter().map(|&v| v as f64).sum::<f64>() / a.as_raw().len() as f64;
    assert!(mean > 5.0, "the presented frame is black (mean {mean})");
}

#[test]
fn resizing_and_minimising_neither_crash_nor_leak() {
    let test = "resizing_and_minimising_neither_crash_nor_leak";
    let dir = temp(test);
    let shot = dir.join("shot.png");
    let args = [
        "--validation",
        "view",
        "spheres",
        "--size",
        "64x48",
        "--frames",
        "16",
        "--script",
        "2:resize=96x40,5:minimize,7:restore,9:resize=40x96",
        "--screenshot",
        shot.to_str().unwrap(),
    ];
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    check(test, &o);
    assert_eq!(
        png(&shot).dimensions(),
        (40, 96),
        "the last resize reached the swapchain"
    );
}

#[test]
fn objects_are_added_picked_moved_and_removed_in_the_window() {
    let test = "objects_are_added_picked_moved_and_removed_in_the_window";
    let dir = temp(test);
    let shot = dir.join("shot.png");
    // The added sphere sits in the middle of the view: pick it there, move it up, remove it
    // where it went; remove the short block below the centre; add a mesh.
    let args = [
        "--validation",
        "view",
        "cornell",
        "--size",
        "64x64",
        "--frames",
        "12",
        "--script",
        "2:add-sphere,4:pick=32;32,5:move=0;50;0,7:remove=32;27,9:remove=32;56,10:add-mesh",
        "--screenshot",
        shot.to_str().unwrap(),
    ];
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    let stdout = check(test, &o);
    for want in EDITED {
        assert!(stdout.contains(want), "{test}: expected {want:?} in\n{stdout}");
    }
    assert_eq!(png(&shot).dimensions(), (64, 64));
}

/// The T key's action switches to the driver's acceleration structures where the device has
/// ray-tracing pipelines (picking then casts through them), and elsewhere (lavapipe) says
/// what the device lacks and keeps tracing with the project's BVH; either way the viewer
/// goes on, edits and picks.
#[test]
fn the_tracer_switch_goes_to_the_driver_or_says_why_not() {
    let test = "the_tracer_switch_goes_to_the_driver_or_says_why_not";
    let args = [
        "--validation",
        "view",
        "cornell",
        "--size",
        "64x64",
        "--frames",
        "9",
        "--script",
        "1:tracer=driver,3:add-sphere,5:pick=32;32,7:tracer=lbvh",
    ];
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    let stdout = check(test, &o);
    assert!(
        stdout.contains("tracer: Driver") || stdout.contains("--accel driver needs"),
        "{test}: neither switched nor said why not:\n{stdout}"
    );
    for want in [
        "new object added sphere 1 (selected)",
        "selected added sphere 1",
        "tracer: Lbvh",
    ] {
        assert!(stdout.contains(want), "{test}: expected {want:?} in\n{stdout}");
    }
}

/// What the viewer prints for the edits both window tests script on the Cornell box.
const EDITED: [&str; 5] = [
    "new object added sphere 1 (selected)",
    "selected added sphere 1",
    "removed added sphere 1",
    "removed short block",
    "new object added builtin:cube 2 (selected)",
];

#[test]
fn instances_are_added_picked_moved_and_removed_in_the_window() {
    // The same edits with every object an instance of its mesh: picking names the instance's
    // object, a move rebuilds the top level, additions and removals load the scene again, and
    // the statistics check both levels against the CPU executor's.
    let test = "instances_are_added_picked_moved_and_removed_in_the_window";
    let args = [
        "--validation",
        "view",
        "cornell",
        "--instancing",
        "on",
        "--size",
        "64x64",
        "--frames",
        "12",
        "--script",
        "2:add-sphere,4:pick=32;32,5:move=0;50;0,6:stats,7:remove=32;27,9:remove=32;56,10:add-mesh,11:stats",
    ];
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    let stdout = check(test, &o);
    for want in EDITED
        .iter()
        .chain(&["two levels valid: 9 instances", "two levels valid: 8 instances"])
    {
        assert!(stdout.contains(want), "{test}: expected {want:?} in\n{stdout}");
    }
    assert!(
        !stdout.contains("DIFFER"),
        "{test}: GPU and CPU levels differ:\n{stdout}"
    );
}

#[test]
fn a_still_denoised_viewer_converges_to_the_headless_render() {
    // The denoiser is on by default. 7 frames of 16 samples: the first six (16 to 96
    // samples per pixel) are denoised, the seventh (112) shows the accumulation itself,
    // which the denoiser has left as the path tracer made it.
    assert_viewer_shows_render(
        "a_still_denoised_viewer_converges_to_the_headless_render",
        &["--spf", "16", "--frames", "7"],
        112,
    );
}

#[test]
fn a_denoised_viewer_past_its_spp_cap_shows_the_accumulation() {
    // --spp 16 in one frame of 16 samples: that frame is denoised; the two after trace
    // nothing and show the accumulation (the denoiser never filters a frame's guides twice).
    assert_viewer_shows_render(
        "a_denoised_viewer_past_its_spp_cap_shows_the_accumulation",
        &["--spf", "16", "--spp", "16", "--frames", "3"],
        16,
    );
}

#[test]
fn the_denoiser_follows_a_moving_camera_and_its_switch() {
    let test = "the_denoiser_follows_a_moving_camera_and_its_switch";
    let dir = temp(test);
    let shot = dir.join("shot.png");
    // Denoised while the camera flies (reprojecting the history), switched off and on again,
    // then denoised while an added object moves.
    let args = [
        "--validation",
        "view",
        "cornell",
        "--size",
        "64x48",
        "--frames",
        "12",
        "--script",
        "1:fly=0;0;0.3,2:fly=0.2;0;0,3:denoise=off,4:fly=0;0.1;0,5:denoise=on,6:add-sphere,8:move=0;0.2;0",
        "--screenshot",
        shot.to_str().unwrap(),
    ];
    let Some(o) = run_windowed(test, &args) else {
        return;
    };
    let stdout = check(test, &o);
    for want in ["denoiser off", "denoiser on", "new object added sphere 1 (selected)"] {
        assert!(stdout.contains(want), "{test}: expected {want:?} in\n{stdout}");
    }
    let p = png(&shot);
    assert_eq!(p.dimensions(), (64, 48));
    let mean = p.as_raw().iter().map(|&v| v as f64).sum::<f64>() / p.as_raw().len() as f64;
    assert!(mean > 5.0, "the denoised frame is black (mean {mean})");
}
