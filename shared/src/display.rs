//! The display pass: average the accumulated samples, apply exposure, clamp to `[0, 1]` and
//! encode as 8-bit sRGB (or the thesis's gamma 1/2), packed RGBA8 (`r | g << 8 | b << 16 |
//! a << 24`), or BGRA8 for swapchain images that want it.
use crate::math::{powf, sqrt};
use crate::types::{Frame, RenderPush, DISPLAY_BGRA, FLAG_GAMMA2};
use spirv_std::glam::Vec3;

/// The sRGB transfer function (IEC 61966-2-1) of a linear value in `[0, 1]`.
pub fn srgb_encode(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * powf(x, 1.0 / 2.4) - 0.055
    }
}

/// Linear radiance to an 8-bit code value: exposure, clamp, transfer curve, rounding.
pub fn encode(x: f32, exposure: f32, gamma2: bool) -> u32 {
    let v = (x * exposure).clamp(0.0, 1.0);
    // NaN fails the comparison in `clamp`'s `max`/`min`; map it to black.
    let v = if v.is_nan() { 0.0 } else { v };
    let e = if gamma2 { sqrt(v) } else { srgb_encode(v) };
    (e * 255.0 + 0.5) as u32
}

/// Pixel `i` of the display image from the accumulation image after `p.samples` samples.
pub fn display(i: u32, p: &RenderPush, f: &Frame, accum: &[[f32; 4]], image: &mut [u32]) {
    if i >= f.width * f.height {
        return;
    }
    image[i as usize] = pixel(accum[i as usize], p, f);
}

/// The display code of one accumulation pixel after `p.samples` samples.
pub fn pixel(a: [f32; 4], p: &RenderPush, f: &Frame) -> u32 {
    let scale = 1.0 / p.samples.max(1) as f32;
    pack(Vec3::new(a[0], a[1], a[2]) * scale, f, p.flags & DISPLAY_BGRA != 0)
}

/// The display code of linear radiance `c`: RGBA8, or BGRA8 with `bgra`.
pub fn pack(c: Vec3, f: &Frame, bgra: bool) -> u32 {
    let gamma2 = f.flags & FLAG_GAMMA2 != 0;
    let r = encode(c.x, f.exposure, gamma2);
    let g = encode(c.y, f.exposure, gamma2);
    let b = encode(c.z, f.exposure, gamma2);
    let (lo, hi) = if bgra { (b, r) } else { (r, b) };
    lo | (g << 8) | (hi << 16) | (255 << 24)
}
