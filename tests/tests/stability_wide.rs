//! The stability suite (`stability.rs`) again, every query through the wide BVH
//! (`shared::wide`): the CPU executor's and the GPU's wide BVHs (equal bit for bit), the wide
//! traversal on both backends.

/// Read by the suite's helpers (`common::World`).
const WIDE: bool = true;

#[path = "stability.rs"]
mod suite;
