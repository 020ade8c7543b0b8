//! Helpers of the integration tests: opening the GPU (skip or fail without one), comparing a
//! CPU and a GPU picture, checking the validation layer, and writing both sides of a mismatch
//! to a file.
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cpu::render_cpu;
use raytrace::gpu::{Gpu, GpuOptions, GpuRenderer, Kernels};
use raytrace::picture::diff_stats;
use raytrace::scene::SceneGpu;
use shared::types::Frame;
use std::fmt::Debug;
use std::path::PathBuf;
use std::sync::Arc;

/// The Vulkan device with validation on, or `None` (after printing a skip line) where there
/// is none. With `REQUIRE_VULKAN=1` a missing device fails the test instead.
pub fn gpu(test: &str) -> Option<Arc<Gpu>> {
    match Gpu::new(&GpuOptions {
        validation: true,
        ..Default::default()
    }) {
        Ok(g) => Some(g),
        Err(e) => {
            if std::env::var("REQUIRE_VULKAN").is_ok_and(|v| v == "1") {
                panic!("{test}: REQUIRE_VULKAN=1 but no Vulkan device: {e:#}");
            }
            eprintln!("SKIPPED {test}: no Vulkan device ({e:#})");
            None
        }
    }
}

/// [`gpu`] opened with the driver's ray tracing (`--accel driver`), or `None` after a skip
/// line where there is no device or the device has no ray-tracing pipelines (lavapipe): a
/// missing extension is no failure even with `REQUIRE_VULKAN=1`; a present one that breaks
/// fails the tests that use it.
pub fn ray_tracing_gpu(test: &str) -> Option<Arc<Gpu>> {
    let opts = GpuOptions {
        validation: true,
        ray_tracing: true,
        ..Default::default()
    };
    let gpu = match Gpu::new(&opts) {
        Ok(g) => g,
        Err(e) => {
            if std::env::var("REQUIRE_VULKAN").is_ok_and(|v| v == "1") {
                panic!("{test}: REQUIRE_VULKAN=1 but no Vulkan device: {e:#}");
            }
            eprintln!("SKIPPED {test}: no Vulkan device ({e:#})");
            return None;
        }
    };
    if let Err(why) = &gpu.ray_tracing {
        eprintln!("SKIPPED {test}: no ray tracing on this device ({why})");
        return None;
    }
    Some(gpu)
}

/// [`gpu`] with a path tracer on it (all kernels built), or `None` where [`gpu`] skips.
pub fn renderer(test: &str) -> Option<(Arc<Gpu>, GpuRenderer)> {
    let gpu = self::gpu(test)?;
    let kernels = Arc::new(Kernels::new(&gpu).expect("kernels"));
    let r = GpuRenderer::new(&gpu, &kernels).expect("renderer");
    Some((gpu, r))
}

/// Renders `spp` samples of `frame` on the CPU executor and on `r` (both with 30-bit LBVH
/// builds) and asserts the pictures agree within `tolerance` relative RMSE.
pub fn assert_cpu_and_gpu_agree(r: &mut GpuRenderer, data: &SceneGpu, frame: &Frame, spp: u32, tolerance: f64) {
    let build = BuildOptions::lbvh(MortonBits::B30);
    let cpu = render_cpu(data, frame, spp, build, &|_| {}).picture;
    r.set_build(build);
    r.load(data, frame).expect("load");
    r.render(spp, true).expect("render");
    let g = r.picture().expect("picture");
    let d = diff_stats(&cpu, &g).unwrap();
    assert!(
        d.relative_rmse < tolerance,
        "relative RMSE {} (tolerance {tolerance})",
        d.relative_rmse
    );
}

/// Fails if the validation layer reported any error.
pub fn assert_no_validation_errors(gpu: &Gpu) {
    let errors = gpu.validation_errors();
    assert!(
        errors.is_empty(),
        "{} Vulkan validation errors, first: {}",
        errors.len(),
        errors[0]
    );
}

/// Writes `left` and `right` to a file under the test's temporary folder and returns its path.
pub fn dump_mismatch(
    name: &str,
    left_label: &str,
    left: &impl Debug,
    right_label: &str,
    right: &impl Debug,
) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/tmp/mismatches");
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!(
        "{}.txt",
        name.replace(|c: char| !c.is_ascii_alphanumeric(), "_")
    ));
    let text = format!("== {left_label}\n{left:#?}\n== {right_label}\n{right:#?}\n");
    if let Err(e) = std::fs::write(&path, text) {
        eprintln!("could not write {}: {e}", path.display());
    }
    path
}
