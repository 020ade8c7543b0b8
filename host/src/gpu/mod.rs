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
pub use levels::{GpuLevels, TOP_REFITS};
pub use render::{frame_timings, stage_ms, Denoise, GpuRenderer, GROUP_REFITS, SAMPLES_PER_DISPATCH};
pub use swapchain::Swapchain;

include!(concat!(env!("OUT_DIR"), "/shader_modules.rs"));

/// The SPIR-V module of `shader-crate`'s entry point `symbol` (`compute::path_trace`).
pub fn shader_module(symbol: &str) -> Option<&'static [u8]> {
    SHADER_MODULES.iter().find(|m| m.0 == symbol).map(|m| m.1)
}
/// The SPIR-V module of the driver tracer's ray-tracing pipeline (`shader-crate` with its
/// `driver` feature), loaded only on devices with ray-tracing pipelines.
pub const DRIVER_SPV: &[u8] = include_bytes!(env!("DRIVER_SPV_PATH"));

include!(concat!(env!("OUT_DIR"), "/entry_points.rs"));

#[cfg(test)]
mod tests {
    /// The module's instructions as (opcode, operand words).
    fn instructions(bytes: &[u8]) -> Vec<(u32, Vec<u32>)> {
        let words = ash::util::read_spv(&mut std::io::Cursor::new(bytes)).expect("SPIR-V");
        let mut out = Vec::new();
        let mut i = 5;
        while i < words.len() {
            let (count, op) = ((words[i] >> 16) as usize, words[i] & 0xffff);
            assert!(count > 0 && i + count <= words.len(), "malformed at word {i}");
            out.push((op, words[i + 1..i + count].to_vec()));
            i += count;
        }
        out
    }

    #[test]
    fn every_kernel_has_a_module_of_its_own_entry_point_without_source_or_lines() {
        for k in super::Kernel::ALL {
            let symbol = k.symbol();
            let module = super::shader_module(&symbol).unwrap_or_else(|| panic!("no module for {symbol}"));
            let inst = instructions(module);
            // OpEntryPoint: execution model, function, then the name as a string.
            let entries: Vec<String> = inst
                .iter()
                .filter(|(op, _)| *op == 15)
                .map(|(_, w)| {
                    let bytes: Vec<u8> = w[2..].iter().flat_map(|x| x.to_le_bytes()).collect();
                    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
                    String::from_utf8_lossy(&bytes[..end]).into_owned()
                })
                .collect();
            assert_eq!(entries, vec![symbol.clone()], "entry points of {symbol}'s module");
            // OpSourceContinued, OpSource, OpLine, OpNoLine: stripped by build.rs.
            for (op, _) in &inst {
                assert!(![2, 3, 8, 317].contains(op), "{symbol}'s module keeps opcode {op}");
            }
        }
    }

    /// The tracers read the BVH's nodes and the triangles as whole 16-byte words
    /// (`shared::sync::word_at`: an `OpLoad` of a `uvec4`, which NVIDIA's compiler makes one
    /// 16-byte load), not a load per component (the tracers' frames 15-25% slower on the
    /// H200, bench/NOTES.md session 53).
    #[test]
    fn the_tracers_read_nodes_and_triangles_as_whole_words() {
        for k in super::Kernel::ALL.into_iter().filter(|k| k.is_tracer()) {
            let symbol = k.symbol();
            let inst = instructions(super::shader_module(&symbol).expect("module"));
            // OpTypeInt (21): id, width, signedness; OpTypeVector (23): id, component, count.
            let uint: Vec<u32> = inst
                .iter()
                .filter(|(op, w)| *op == 21 && w[1] == 32 && w[2] == 0)
                .map(|(_, w)| w[0])
                .collect();
            let uvec4: Vec<u32> = inst
                .iter()
                .filter(|(op, w)| *op == 23 && uint.contains(&w[1]) && w[2] == 4)
                .map(|(_, w)| w[0])
                .collect();
            // OpLoad (61): result type, result, pointer.
            let loads = inst.iter().filter(|(op, w)| *op == 61 && uvec4.contains(&w[0])).count();
            // A node pair is four words, a triangle three.
            assert!(loads >= 7, "{symbol} loads {loads} whole uvec4 words");
        }
    }

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
