//! Kernels and GPU data shared by the SPIR-V entry points (`shader-crate`) and the host's CPU
//! executor. Every function here runs unchanged on both: the GPU calls it from a
//! `#[spirv(compute)]` entry point, the CPU executor calls it for every invocation in turn.
//!
//! Two kernel shapes (see ARCHITECTURE.md): per-item steps `fn step(i, ..)`, and
//! workgroup-cooperative kernels written as phases `fn phase(lane, group, &mut State, ..)`
//! separated by workgroup barriers.
#![cfg_attr(not(test), no_std)]
#![cfg_attr(not(target_arch = "spirv"), feature(core_float_math))]
#![cfg_attr(target_arch = "spirv", feature(asm_experimental_arch))]

pub mod alpha;
pub mod bounds;
#[cfg(test)]
mod chi2;
pub mod denoise;
pub mod display;
pub mod driver;
pub mod envmap;
pub mod instance;
pub mod intersect;
pub mod karras;
pub mod material;
pub mod math;
pub mod merge_sort;
pub mod morton;
pub mod node_words;
pub mod path;
pub mod pbr;
pub mod ploc;
pub mod radix_sort;
pub mod refit;
pub mod rng;
pub mod sampling;
pub mod scan;
pub mod shading;
pub mod sync;
pub mod texture;
pub mod transform;
pub mod traverse;
pub mod treelet;
pub mod types;
pub mod wide;

pub use spirv_std::glam;
