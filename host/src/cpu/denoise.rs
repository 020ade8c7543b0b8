//! The denoiser's passes (`shared::denoise`) run by the CPU executor: each pass for every
//! pixel before the next, as the GPU's dispatches and barriers order them.
use shared::denoise::{self, DenoisePush, Guide, DENOISE_NO_HISTORY, DENOISE_PARITY, DENOISE_STILL, LEVELS};
use shared::types::Frame;

/// The denoiser's state between frames (the CPU twin of the GPU renderer's).
#[derive(Default)]
pub struct CpuDenoiser {
    history: Vec<[u32; 4]>,
    filter: Vec<[u32; 4]>,
    parity: bool,
    has_history: bool,
}

/// A denoised frame: linear radiance (`w` 1) and its display codes.
pub struct Denoised {
    pub output: Vec<[f32; 4]>,
    pub display: Vec<u32>,
}

impl CpuDenoiser {
    /// Denoises `guides` of `samples` samples per pixel of `frame`; with `history` the
    /// previous call's frame is reprojected (`still`: nothing moved since).
    pub fn run(&mut self, frame: &Frame, guides: &[Guide], samples: u32, history: bool, still: bool) -> Denoised {
        let n = (frame.width * frame.height) as usize;
        let entries = denoise::history_entries(n as u32) as usize;
        if self.history.len() != entries {
            self.history = vec![[0; 4]; entries];
            self.filter = vec![[0; 4]; denoise::filter_entries(n as u32) as usize];
            self.has_history = false;
        }
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let has = history && self.has_history;
        let mut p = DenoisePush {
            samples,
            level: 0,
            flags: flag(self.parity, DENOISE_PARITY)
                | flag(!has, DENOISE_NO_HISTORY)
                | flag(still && has, DENOISE_STILL),
            _pad: 0,
        };
        let guides = &planes(guides);
        for i in 0..n as u32 {
            denoise::temporal(i, &p, frame, guides, &mut self.history, &mut self.filter);
        }
        for i in 0..n as u32 {
            denoise::variance(i, &p, frame, &self.history, &mut self.filter);
        }
        let mut out = Denoised {
            output: vec![[0.0; 4]; n],
            display: vec![0; n],
        };
        for level in 0..LEVELS {
            p.level = level;
            for i in 0..n as u32 {
                denoise::atrous(
                    i,
                    &p,
                    frame,
                    guides,
                    &mut self.history,
                    &mut self.filter,
                    &mut out.output,
                    &mut out.display,
                );
            }
        }
        self.parity = !self.parity;
        self.has_history = true;
        out
    }
}

/// `guides` stored as the GPU's path tracer leaves them ([`Guide::store`]).
pub fn planes(guides: &[Guide]) -> Vec<[u32; 4]> {
    let n = guides.len() as u32;
    let mut out = vec![[0; 4]; (denoise::GUIDE_PLANES * n) as usize];
    for (i, g) in guides.iter().enumerate() {
        g.store(&mut out, n, i as u32);
    }
    out
}

/// The guides of `planes` ([`Guide::load`]).
pub fn unplane(planes: &[[u32; 4]]) -> Vec<Guide> {
    let n = planes.len() as u32 / denoise::GUIDE_PLANES;
    (0..n).map(|i| Guide::load(planes, n, i)).collect()
}
