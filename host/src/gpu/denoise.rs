//! The GPU denoiser's buffers and passes (`shared::denoise`: SVGF). Its kernels take their
//! own buffers as a set of the build's layout (set 0: guides, history, filter, output) and
//! the frame and display image from the renderer's set 1; `GpuRenderer` records them after
//! the path tracer in place of the display pass.
use crate::gpu::{BindingSets, Buffer, Commands, Gpu, Kernel, Kernels, BINDINGS};
use anyhow::Result;
use ash::vk;
use gpu_allocator::MemoryLocation;
use shared::denoise::{
    filter_entries, history_entries, DenoisePush, DENOISE_BGRA, DENOISE_NO_HISTORY, DENOISE_PARITY, DENOISE_STILL,
    GUIDE_PLANES, LEVELS,
};
use shared::types::TILE_SIDE;
use std::sync::Arc;

/// Timestamp labels of the denoiser's passes (the a-trous levels share one; the last level
/// also remodulates and writes the image), each after its pass: a frame's denoiser time is
/// their sum ([`denoise_ms`]).
pub const PASSES: [&str; 3] = ["denoise temporal", "denoise variance", "denoise a-trous"];

/// Whether `label` is one of [`PASSES`].
pub fn is_denoise(label: &str) -> bool {
    PASSES.contains(&label)
}

/// Milliseconds of the denoiser's passes in timings of `frame_timings` (0 where it did not
/// run).
pub fn denoise_ms(timings: &[(&'static str, f64)]) -> f64 {
    timings
        .iter()
        .filter(|(l, _)| is_denoise(l))
        .map(|(_, s)| s * 1e3)
        .sum()
}

/// The denoiser's state for one image size.
pub struct GpuDenoiser {
    /// This frame's and the previous frame's [`History`] (halves swapped every frame); only
    /// `set` names it.
    _history: Buffer,
    /// The a-trous filter's two halves and the pixels' surfaces, `[f32; 4]` a pixel; only
    /// `set` names it.
    _filter: Buffer,
    /// Denoised linear radiance, `[f32; 4]` a pixel.
    pub output: Buffer,
    set: BindingSets,
    width: u32,
    height: u32,
    /// Which half of `history` the next frame writes.
    parity: bool,
    /// Whether the other half holds a previous frame.
    has_history: bool,
}

impl GpuDenoiser {
    /// Buffers for `width x height` pixels reading the path tracer's `guides`.
    pub fn new(gpu: &Arc<Gpu>, kernels: &Kernels, guides: &Buffer, width: u32, height: u32) -> Result<GpuDenoiser> {
        let pixels = (width * height) as u64;
        let dev = |name: &str, bytes: u64| Buffer::new(gpu, name, bytes.max(16), MemoryLocation::GpuOnly);
        let history = dev("denoiser history", history_entries(pixels as u32) as u64 * 16)?;
        let filter = dev("denoiser filter", filter_entries(pixels as u32) as u64 * 16)?;
        let output = dev("denoised image", pixels * 16)?;
        let mut buffers = [&output; BINDINGS];
        buffers[0] = guides;
        buffers[1] = &history;
        buffers[2] = &filter;
        let set = BindingSets::new(gpu, kernels, 0, &[&buffers])?;
        Ok(GpuDenoiser {
            _history: history,
            _filter: filter,
            output,
            set,
            width,
            height,
            parity: false,
            has_history: false,
        })
    }

    /// Whether this state fits a `width x height` image.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        (self.width, self.height) == (width, height)
    }

    /// Records the passes over guides of `samples` samples per pixel into `cmds`;
    /// `render_set` is the renderer's set 1 (frame, display image). With `history` the
    /// previous frame's is reprojected; `still`: nothing moved since then. Writes the
    /// display image (BGRA with `bgra`) and [`Self::output`].
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        cmds: &mut Commands,
        kernels: &Kernels,
        render_set: vk::DescriptorSet,
        samples: u32,
        history: bool,
        still: bool,
        bgra: bool,
    ) -> Result<()> {
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let flags = flag(self.parity, DENOISE_PARITY)
            | flag(!(history && self.has_history), DENOISE_NO_HISTORY)
            | flag(still && self.has_history, DENOISE_STILL)
            | flag(bgra, DENOISE_BGRA);
        let sets = [self.set.sets[0], render_set];
        let (gx, gy) = (self.width.div_ceil(TILE_SIDE), self.height.div_ceil(TILE_SIDE));
        let mut pass = |kernel: Kernel, level: u32, label: &'static str| -> Result<()> {
            let push = DenoisePush {
                samples,
                level,
                flags,
                _pad: 0,
            };
            cmds.dispatch_sets(kernels, &sets, kernel, bytemuck::bytes_of(&push), gx, gy)?;
            cmds.barrier();
            cmds.timestamp(label);
            Ok(())
        };
        pass(Kernel::DenoiseTemporal, 0, PASSES[0])?;
        pass(Kernel::DenoiseVariance, 0, PASSES[1])?;
        for level in 0..LEVELS {
            pass(Kernel::DenoiseAtrous, level, PASSES[2])?;
        }
        self.parity = !self.parity;
        self.has_history = true;
        Ok(())
    }
}

/// Bytes of the guides buffer for `pixels` pixels (one guide, the least a binding holds,
/// where the path tracer leaves none), and one entry more: the persistent path tracer's
/// pixel counter (`path::render_tiles`), the buffer's last.
pub fn guide_bytes(pixels: u64) -> u64 {
    pixels.max(1) * GUIDE_PLANES as u64 * 16 + 16
}
