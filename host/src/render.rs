//! What the two renderers share: the GPU's (`crate::gpu::GpuRenderer`) records transform,
//! BVH build, path tracing and display into one command buffer; the CPU's
//! (`crate::cpu::render_cpu`) runs the very same kernels of `shared` through the CPU
//! executor. Both produce a [`Picture`] and per-stage times.
use crate::bvh::BuildOptions;
use crate::picture::Picture;
use shared::types::{
    Frame, FEATURE_INSTANCES, FEATURE_NEE, FLAG_BVH, VARIANT_NO_PAIRS, VARIANT_STEPPED, VARIANT_WIDE_BVH,
};

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

/// What `--accel` asks for on `render`, `view` and `compare`: a tracer, or the faster one for
/// the scene and device ([`AccelChoice::resolve`]).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum AccelChoice {
    /// The driver's acceleration structures for a scene laid out in two levels on a device
    /// with ray-tracing pipelines, the project's BVH otherwise.
    #[default]
    Auto,
    /// The project's own BVH, built every frame and walked by `shared`'s traversal.
    Lbvh,
    /// The Vulkan driver's acceleration structures (devices with VK_KHR_ray_tracing_pipeline;
    /// elsewhere an error names what the device lacks).
    Driver,
}

impl From<Accel> for AccelChoice {
    fn from(a: Accel) -> AccelChoice {
        match a {
            Accel::Lbvh => AccelChoice::Lbvh,
            Accel::Driver => AccelChoice::Driver,
        }
    }
}

impl AccelChoice {
    /// The tracer, and why: as asked, or for `auto` the driver's structures where the scene
    /// is laid out in two levels (`two_levels`) and the device has ray-tracing pipelines
    /// (`ray_tracing`), unless the frame asks for something of the project's BVH alone
    /// (`project_only`: brute force, the wide BVH). Measured on the H100 (`bench peer`,
    /// bench/NOTES.md sessions 26-27): the driver's hardware traversal takes a two-level
    /// scene's frame 1.5x (without next-event estimation) to 3-4x (with it) faster than our
    /// walk of two levels, while our build and walk win every flattened scene's frame.
    pub fn resolve(self, ray_tracing: bool, two_levels: bool, project_only: bool) -> (Accel, &'static str) {
        match self {
            AccelChoice::Lbvh => (Accel::Lbvh, "--accel lbvh"),
            AccelChoice::Driver => (Accel::Driver, "--accel driver"),
            AccelChoice::Auto if project_only => (
                Accel::Lbvh,
                "--accel auto: the frame asks for the project's BVH (--no-bvh or --bvh wide)",
            ),
            AccelChoice::Auto if !two_levels => (
                Accel::Lbvh,
                "--accel auto: a flattened scene, which the project's BVH builds and traces faster",
            ),
            AccelChoice::Auto if !ray_tracing => (
                Accel::Lbvh,
                "--accel auto: a scene in two levels, on a device without ray-tracing pipelines",
            ),
            AccelChoice::Auto => (
                Accel::Driver,
                "--accel auto: a scene in two levels, on a device with ray-tracing pipelines, which traverse instances faster",
            ),
        }
    }
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

/// A frame's `features` for its tracers: with [`VARIANT_WIDE_BVH`] where `build` collapses
/// the tree into the wide BVH (the tracer then walks it), [`VARIANT_NO_PAIRS`] where it writes
/// a binary tree without its pairs (`BuildOptions::pairs`: the binary walk then reads the tree
/// alone), and [`VARIANT_STEPPED`] where the path loop steps the walks itself
/// (`path::stepped_pixels`): paths of more than one segment, without next-event estimation,
/// in a flattened scene through the binary BVH. (Primary rays alone trace faster a segment at
/// a time: bench/NOTES.md, session 51.)
pub fn tracer_features(frame: &Frame, build: BuildOptions) -> u32 {
    let features = frame.features & !(VARIANT_WIDE_BVH | VARIANT_NO_PAIRS | VARIANT_STEPPED);
    let features = if build.wide {
        features | VARIANT_WIDE_BVH
    } else if !build.pairs {
        features | VARIANT_NO_PAIRS
    } else {
        features
    };
    let stepped = frame.max_depth > 1 && features & (FEATURE_NEE | FEATURE_INSTANCES | VARIANT_WIDE_BVH) == 0;
    features | if stepped { VARIANT_STEPPED } else { 0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_takes_the_drivers_structures_for_two_levels_on_a_device_with_them() {
        // (ray tracing, two levels, the project's BVH asked for) -> the tracer auto takes.
        let cases = [
            ((true, true, false), Accel::Driver),
            ((true, false, false), Accel::Lbvh),
            ((false, true, false), Accel::Lbvh),
            ((false, false, false), Accel::Lbvh),
            ((true, true, true), Accel::Lbvh),
        ];
        for ((rt, two, project), want) in cases {
            let (got, why) = AccelChoice::Auto.resolve(rt, two, project);
            assert_eq!(
                got, want,
                "ray tracing {rt}, two levels {two}, project only {project}: {why}"
            );
            assert!(why.starts_with("--accel auto: "), "{why}");
        }
        // Asked for by name, a tracer is taken whatever the scene and device (the driver's
        // then fails by name where the device lacks it).
        for (rt, two, project) in [(false, false, true), (true, true, false)] {
            assert_eq!(AccelChoice::Lbvh.resolve(rt, two, project).0, Accel::Lbvh);
            assert_eq!(AccelChoice::Driver.resolve(rt, two, project).0, Accel::Driver);
        }
    }
}
