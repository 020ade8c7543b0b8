//! The raytrace host: Vulkan core, GPU LBVH builder, CPU executor of the same kernels,
//! inputs, scenes, BVH validator and benchmarks.
pub mod bench;
pub mod bvh;
pub mod cli;
pub mod cpu;
pub mod inputs;
pub mod lbvh;
pub mod picture;
pub mod render;
pub mod scene;
pub mod table2;
pub mod validate;
pub mod vk;
