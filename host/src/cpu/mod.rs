//! The CPU executor: the very kernels of `shared` that the GPU runs, run on the CPU, where
//! the tests check them against the GPU and where `--backend auto` renders without a GPU.
//! `lbvh` builds the BVH ([`build`]), `render` renders a frame ([`render_cpu`]).
mod denoise;
mod lbvh;
mod render;

pub use denoise::{unplane as guides_from_planes, CpuDenoiser, Denoised};
pub use lbvh::{build, build_coded, refit, refit_round};
pub use render::{
    display_image, levels_inputs, render_cpu, render_cpu_moving, render_cpu_samples, transformed, world_primitives,
    CpuRender,
};
