//! The raytrace host: Vulkan core, GPU LBVH builder, CPU executor of the same kernels,
//! inputs, scenes (live and editable), the windowed viewer, BVH validator and benchmarks.
pub mod bench;
pub mod bvh;
pub mod cli;
pub mod cpu;
pub mod features;
pub mod gpu;
pub mod inputs;
pub mod picture;
pub mod render;
pub mod scene;
pub mod view;
