//! What the two renderers share: the GPU's (`crate::gpu::GpuRenderer`) records transform,
//! BVH build, path tracing and display into one command buffer; the CPU's
//! (`crate::cpu::render_cpu`) runs the very same kernels of `shared` through the CPU
//! executor. Both produce a [`Picture`] and per-stage times.
use crate::bvh::BuildOptions;
use crate::picture::Picture;
use shared::types::{Frame, FLAG_BVH, VARIANT_WIDE_BVH};

/// Where kernels run.
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum Backend {
    /// The GPU, unless every Vulkan device is a CPU implementation (lavapipe, SwiftShader)
    /// or there is none: then the CPU executor, which runs the same kernels much faster
    /// there (`choose_backend` in `cli/render.rs`).
    Auto,
    Gpu,
    Cpu,
}

/// What finds the rays' hits on the GPU (`--accel`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum Accel {
    /// The project's own BVH, built by its kernels every frame and walked by `shared`'s
    /// traversal (on either backend).
    #[default]
    Lbvh,
    /// The Vulkan driver's acceleration structures, built by the driver every frame and
    /// traversed by its ray-tracing pipeline (`crate::gpu::driver`): GPU only, on devices
    /// with VK_KHR_ray_tracing_pipeline.
    Driver,
}

/// Stage times (seconds) summed by stage: labels like `sort.scatter` count under `sort`.
pub fn stage_totals(timings: &[(&'static str, f64)]) -> Vec<(&'static str, f64)> {
    let mut out: Vec<(&'static str, f64)> = Vec::new();
    for &(label, t) in timings {
        let stage = label.split('.').next().unwrap_or(label);
        match out.iter_mut().find(|(s, _)| *s == stage) {
            Some(e) => e.1 += t,
            None => out.push((stage, t)),
        }
    }
    out
}

/// Rays traced for a picture (each pixel's accumulated count).
pub fn rays_traced(p: &Picture) -> u64 {
    p.accum.iter().map(|a| a[3] as u64).sum()
}

/// `frame` with tracing through the BVH switched on or off.
pub fn with_bvh(mut frame: Frame, bvh: bool) -> Frame {
    if bvh {
        frame.flags |= FLAG_BVH;
    } else {
        frame.flags &= !FLAG_BVH;
    }
    frame
}

/// A frame's `features` with [`VARIANT_WIDE_BVH`] set where `build` collapses the tree into
/// the wide BVH (the tracer then walks it).
pub fn tracer_features(features: u32, build: BuildOptions) -> u32 {
    if build.wide {
        features | VARIANT_WIDE_BVH
    } else {
        features & !VARIANT_WIDE_BVH
    }
}
