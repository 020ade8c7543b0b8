//! The GPU side. The Vulkan core: context (instance, device, allocator, validation), buffers,
//! compute pipelines from the embedded SPIR-V, command recording with timestamps, and the
//! window swapchain of the viewer; every Vulkan object is owned by a type that frees it on
//! `Drop`. On it, the LBVH build (`lbvh`: [`GpuLbvh`]) and the renderer (`render`:
//! [`GpuRenderer`]).
mod buffer;
mod commands;
mod context;
mod denoise;
pub mod driver;
mod kernels;
mod lbvh;
mod levels;
mod render;
mod swapchain;

pub use buffer::Buffer;
pub use commands::{Commands, MAX_TIMESTAMPS};
pub use context::{DeviceInfo, Gpu, GpuOptions, Instance};
pub use denoise::{denoise_ms, is_denoise, PASSES as DENOISE_PASSES};
pub use kernels::{BindingSets, Kernel, Kernels, BINDINGS};
pub use lbvh::GpuLbvh;
pub use levels::GpuLevels;
pub use render::{frame_timings, stage_ms, Denoise, GpuRenderer};
pub use swapchain::Swapchain;

/// The SPIR-V module of `shader-crate`, compiled by `host/build.rs`.
pub const SHADER_SPV: &[u8] = include_bytes!(env!("SHADER_SPV_PATH"));
/// The SPIR-V module of the driver tracer's ray-tracing pipeline (`shader-crate` with its
/// `driver` feature), loaded only on devices with ray-tracing pipelines.
pub const DRIVER_SPV: &[u8] = include_bytes!(env!("DRIVER_SPV_PATH"));

include!(concat!(env!("OUT_DIR"), "/entry_points.rs"));

#[cfg(test)]
mod tests {
    #[test]
    fn every_kernel_is_an_entry_point_of_the_module() {
        for k in super::Kernel::ALL {
            assert!(
                super::ENTRY_POINTS.contains(&k.symbol().as_str()),
                "{} missing from {:?}",
                k.symbol(),
                super::ENTRY_POINTS
            );
        }
    }
}
