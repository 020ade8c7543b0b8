//! The CPU executor: the very kernels of `shared` that the GPU runs, run on the CPU. Per-item
//! steps run for every index in turn; workgroup kernels run each phase for every lane before
//! the next (a barrier). `lbvh` builds the BVH, `render` renders a frame (pixels in parallel).
mod lbvh;
mod render;

pub use lbvh::build;
pub use render::{render_cpu, CpuRender};
