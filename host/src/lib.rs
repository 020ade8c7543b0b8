//! The raytrace host: Vulkan core, GPU LBVH builder, CPU executor of the same kernels,
//! inputs, scenes (live and editable), the windowed viewer, BVH validator and benchmarks.
pub mod accuracy;
pub mod bench;
pub mod builtin_assets;
pub mod bvh;
pub mod cli;
pub mod cpu;
pub mod feature_bench;
pub mod features;
pub mod hard_cases;
pub mod inputs;
pub mod lbvh;
pub mod live;
pub mod picture;
pub mod plot;
pub mod readme_table;
pub mod realtime;
pub mod render;
pub mod scene;
pub mod table2;
pub mod trace_bench;
pub mod validate;
pub mod view;
pub mod vk;
