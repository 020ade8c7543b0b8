//! The raytrace host, a module per role: `gpu` (the Vulkan core, the GPU LBVH builder, the
//! GPU renderer), `cpu` (the CPU executor of the same kernels: the build and the renderer),
//! `bvh` (what a build produces on either backend, and its validator), `render` (what the two
//! renderers share), `scene` (scene files, built-in scenes, model files), `features` (the
//! kernel features a scene needs), `picture` (rendered images), `inputs` (generated and loaded
//! primitives, the hard cases), `view` (the windowed viewer and its live scene), `shard`
//! (shards of a frame's samples for render farms, and their merge), `cli` (the command line)
//! and `bench` (the benchmarks).
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
pub mod shard;
pub mod view;
