//! Texture sampling from a storage buffer of texels: wrap modes, bilinear filtering within a
//! mip level, trilinear filtering between levels (pbrt-v4 `util/mipmap.cpp`: `MIPMap::Bilerp`,
//! `MIPMap::Filter` with `FilterFunction::Trilinear`), and the level of detail of a ray cone
//! (Akenine-Möller et al., "Texture Level of Detail Strategies for Real-Time Ray Tracing",
//! Ray Tracing Gems ch. 20, 2019, eq. 34 and the triangle constant of its section 20.3.4;
//! Akenine-Möller et al., "Improved Shader and Texture Level of Detail Using Ray Cones",
//! JCGT 10(1), 2021).
//!
//! Textures are not Vulkan images: every texture of a scene lives in one buffer of RGBA8
//! texels, so the CPU executor reads the very same texels with the very same code as the GPU.
//!
//! ```text
//! texel word (u32):  bits 31..24 | 23..16 | 15..8 | 7..0
//!                         a     |   b    |   g   |  r
//!
//! texel buffer:  .. | texture k: level 0 (w x h, row-major, top row first) | level 1 | .. | level L-1 | ..
//!                     ^ TextureInfo::offset
//! level l: max(w >> l, 1) x max(h >> l, 1) texels; L = floor(log2(max(w, h))) + 1 levels,
//! so the last level is 1 x 1.
//! ```
//!
//! Texture coordinates follow glTF: `(0, 0)` is the top-left corner of the image (the first
//! texel of the buffer) and `(1, 1)` its bottom-right corner; texel `(x, y)` covers
//! `[x / w, (x + 1) / w) x [y / h, (y + 1) / h)`, its centre at `(x + 0.5) / w`. (OBJ's `v`
//! points up: its loader passes `1 - v`.)
use crate::sync::at;
use bytemuck::{Pod, Zeroable};
use core::mem::size_of;
use spirv_std::glam::{Vec2, Vec3, Vec4};

/// One texture of the texel buffer (32 bytes).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TextureInfo {
    /// Index of the first texel of level 0 in the texel buffer.
    pub offset: u32,
    /// Size of level 0 in texels (at least 1 each).
    pub width: u32,
    pub height: u32,
    /// Mip levels stored, at least 1 ([`mip_levels`] for a full chain).
    pub levels: u32,
    /// [`TEX_SRGB`], [`TEX_NEAREST`] and the wrap mode of each axis (see [`tex_flags`]).
    pub flags: u32,
    pub _pad: [u32; 3],
}
const _: () = assert!(size_of::<TextureInfo>() == 32);

/// The texels' RGB are sRGB-encoded (colours: glTF base colour and emissive): decoded to
/// linear on every read, before filtering. Alpha is always linear.
pub const TEX_SRGB: u32 = 1;
/// Nearest-texel lookups within a level instead of bilinear ones (glTF sampler filters
/// `NEAREST`, `NEAREST_MIPMAP_*`: pixel art).
pub const TEX_NEAREST: u32 = 1 << 1;
/// Bits 2..3: wrap mode of `u` (`WRAP_*`).
pub const TEX_WRAP_U_SHIFT: u32 = 2;
/// Bits 4..5: wrap mode of `v` (`WRAP_*`).
pub const TEX_WRAP_V_SHIFT: u32 = 4;
/// Mask of a wrap mode once shifted down.
pub const TEX_WRAP_MASK: u32 = 3;

/// Tiles the texture (glTF `REPEAT`, 10497; the default).
pub const WRAP_REPEAT: u32 = 0;
/// Repeats the edge texels (glTF `CLAMP_TO_EDGE`, 33071).
pub const WRAP_CLAMP: u32 = 1;
/// Tiles the texture mirrored every other time (glTF `MIRRORED_REPEAT`, 33648).
pub const WRAP_MIRROR: u32 = 2;

/// A material's texture index that means "no texture".
pub const NO_TEXTURE: u32 = u32::MAX;

/// Flags of a texture: sRGB or linear, bilinear or nearest, and a `WRAP_*` mode per axis.
pub const fn tex_flags(srgb: bool, nearest: bool, wrap_u: u32, wrap_v: u32) -> u32 {
    let colour = if srgb { TEX_SRGB } else { 0 };
    let filter = if nearest { TEX_NEAREST } else { 0 };
    colour | filter | (wrap_u & TEX_WRAP_MASK) << TEX_WRAP_U_SHIFT | (wrap_v & TEX_WRAP_MASK) << TEX_WRAP_V_SHIFT
}

/// Levels of a full mip chain of a `width` x `height` texture (both at least 1): halving
/// (rounding down) until the largest side is 1, `floor(log2(max(width, height))) + 1`.
pub const fn mip_levels(width: u32, height: u32) -> u32 {
    let side = if width > height { width } else { height };
    if side == 0 {
        1
    } else {
        32 - side.leading_zeros()
    }
}

/// Size of mip level `level` (below 32) of a `width` x `height` texture:
/// `(max(width >> level, 1), max(height >> level, 1))`.
pub const fn level_size(width: u32, height: u32, level: u32) -> (u32, u32) {
    let w = width >> level;
    let h = height >> level;
    (if w > 1 { w } else { 1 }, if h > 1 { h } else { 1 })
}

/// Texels of levels `0..levels` of a `width` x `height` texture: where level `levels` would
/// start, counted from level 0.
pub const fn chain_texels(width: u32, height: u32, levels: u32) -> u32 {
    let mut sum = 0;
    let mut l = 0;
    while l < levels {
        let (w, h) = level_size(width, height, l);
        sum += w * h;
        l += 1;
    }
    sum
}

/// Where level `level` of `info` starts in the texel buffer, and its width and height.
pub fn level_base(info: &TextureInfo, level: u32) -> (u32, u32, u32) {
    let (w, h) = level_size(info.width, info.height, level);
    (info.offset + chain_texels(info.width, info.height, level), w, h)
}

/// The exact piecewise sRGB decoding function of IEC 61966-2-1 (what GPUs apply to `*_SRGB`
/// texture formats): an encoded value in `[0, 1]` to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c * (1.0 / 12.92)
    } else {
        crate::math::powf((c + 0.055) * (1.0 / 1.055), 2.4)
    }
}

/// The exact sRGB encoding function, inverse of [`srgb_to_linear`], of a linear value in
/// `[0, 1]`.
pub fn linear_to_srgb(l: f32) -> f32 {
    if l <= 0.0031308 {
        l * 12.92
    } else {
        1.055 * crate::math::powf(l, 1.0 / 2.4) - 0.055
    }
}

/// A texel word decoded to `[0, 1]`: RGB through [`srgb_to_linear`] when `srgb`, alpha as is.
pub fn decode(word: u32, srgb: bool) -> Vec4 {
    let s = 1.0 / 255.0;
    let r = (word & 0xff) as f32 * s;
    let g = ((word >> 8) & 0xff) as f32 * s;
    let b = ((word >> 16) & 0xff) as f32 * s;
    let a = (word >> 24) as f32 * s;
    if srgb {
        Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
    } else {
        Vec4::new(r, g, b, a)
    }
}

/// Integer coordinate `i` mapped into `0..n` (`n` at least 1) by a `WRAP_*` mode.
pub fn wrap(i: i32, n: u32, mode: u32) -> u32 {
    if mode == WRAP_CLAMP {
        if i <= 0 {
            0
        } else if i as u32 >= n {
            n - 1
        } else {
            i as u32
        }
    } else if mode == WRAP_MIRROR {
        // Period 2n: 0 1 .. n-1 n-1 .. 1 0 | 0 1 ..
        let m = rem_euclid(i, 2 * n);
        if m >= n {
            2 * n - 1 - m
        } else {
            m
        }
    } else {
        rem_euclid(i, n)
    }
}

/// `i` modulo `n` (at least 1) in `0..n`, without signed overflow: `-1 -> n - 1`.
fn rem_euclid(i: i32, n: u32) -> u32 {
    if i >= 0 {
        i as u32 % n
    } else {
        // -(i + 1) is in 0..=i32::MAX.
        n - 1 - (-(i + 1)) as u32 % n
    }
}

/// Texel `(x, y)` of level `level` (clamped to the last) with the texture's wrap modes
/// applied, decoded to linear RGBA (see [`decode`]).
pub fn texel(info: &TextureInfo, texels: &[u32], level: u32, x: i32, y: i32) -> Vec4 {
    let level = last_level_at_most(info, level);
    let (base, w, h) = level_base(info, level);
    fetch(info, texels, base, w, h, x, y, info.flags & TEX_SRGB != 0)
}

/// `level`, or the last level of `info` if that is smaller.
fn last_level_at_most(info: &TextureInfo, level: u32) -> u32 {
    let last = info.levels - 1;
    if level < last {
        level
    } else {
        last
    }
}

/// [`texel`] in a level already located by [`level_base`], RGB decoded from sRGB if `srgb`.
#[allow(clippy::too_many_arguments)]
fn fetch(info: &TextureInfo, texels: &[u32], base: u32, w: u32, h: u32, x: i32, y: i32, srgb: bool) -> Vec4 {
    let xi = wrap(x, w, (info.flags >> TEX_WRAP_U_SHIFT) & TEX_WRAP_MASK);
    let yi = wrap(y, h, (info.flags >> TEX_WRAP_V_SHIFT) & TEX_WRAP_MASK);
    decode(*at(texels, base + yi * w + xi), srgb)
}

fn floor(x: f32) -> f32 {
    spirv_std::num_traits::Float::floor(x)
}

fn log2(x: f32) -> f32 {
    spirv_std::num_traits::Float::log2(x)
}

/// Texture coordinate `u` of an axis with `mode`, reduced to one period where the mode
/// repeats (so that texel coordinates stay small and precise far from the unit square);
/// NaN becomes 0 and the result lies within `[-2^20, 2^20]`.
fn reduce(u: f32, mode: u32) -> f32 {
    let r = if mode == WRAP_REPEAT {
        u - floor(u)
    } else if mode == WRAP_MIRROR {
        u - 2.0 * floor(u * 0.5)
    } else {
        u
    };
    const LIMIT: f32 = (1 << 20) as f32;
    if r > LIMIT {
        LIMIT
    } else if r < -LIMIT {
        -LIMIT
    } else if r.is_nan() {
        0.0
    } else {
        r
    }
}

/// Bilinear interpolation of the four texels around `uv` in level `level` (clamped to the
/// last), wrap modes applied (pbrt-v4 `MIPMap::Bilerp`): at a texel's centre that texel,
/// halfway between two centres their average. With [`TEX_NEAREST`], the texel under `uv`.
pub fn bilinear(info: &TextureInfo, texels: &[u32], level: u32, uv: Vec2) -> Vec4 {
    filtered(info, texels, level, uv, info.flags & TEX_SRGB != 0)
}

/// The alpha of the texture at `uv` in level 0, filtered as [`bilinear`] filters (the
/// coverage of alpha-tested surfaces, `crate::alpha`). Reads no colour: where it is inlined,
/// no sRGB decoding is.
pub fn alpha(info: &TextureInfo, texels: &[u32], uv: Vec2) -> f32 {
    filtered(info, texels, 0, uv, false).w
}

/// [`bilinear`], RGB decoded from sRGB if `srgb`.
fn filtered(info: &TextureInfo, texels: &[u32], level: u32, uv: Vec2, srgb: bool) -> Vec4 {
    let level = last_level_at_most(info, level);
    let (base, w, h) = level_base(info, level);
    let u = reduce(uv.x, (info.flags >> TEX_WRAP_U_SHIFT) & TEX_WRAP_MASK) * w as f32;
    let v = reduce(uv.y, (info.flags >> TEX_WRAP_V_SHIFT) & TEX_WRAP_MASK) * h as f32;
    if info.flags & TEX_NEAREST != 0 {
        return fetch(info, texels, base, w, h, floor(u) as i32, floor(v) as i32, srgb);
    }
    let x = u - 0.5;
    let y = v - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let (dx, dy) = (x - x0, y - y0);
    let (xi, yi) = (x0 as i32, y0 as i32);
    let t00 = fetch(info, texels, base, w, h, xi, yi, srgb);
    let t10 = fetch(info, texels, base, w, h, xi + 1, yi, srgb);
    let t01 = fetch(info, texels, base, w, h, xi, yi + 1, srgb);
    let t11 = fetch(info, texels, base, w, h, xi + 1, yi + 1, srgb);
    (t00 * (1.0 - dx) + t10 * dx) * (1.0 - dy) + (t01 * (1.0 - dx) + t11 * dx) * dy
}

/// The texture at `uv` filtered for level of detail `lod` (0: level 0; each 1 more halves
/// the resolution): trilinear, a blend of [`bilinear`] lookups in levels `floor(lod)` and
/// `floor(lod) + 1` (pbrt-v4 `MIPMap::Filter`, trilinear). `lod` is clamped to
/// `[0, levels - 1]`; NaN counts as 0.
pub fn sample(info: &TextureInfo, texels: &[u32], uv: Vec2, lod: f32) -> Vec4 {
    let top = (info.levels - 1) as f32;
    let lod = if lod > top {
        top
    } else if lod > 0.0 {
        lod
    } else {
        0.0
    };
    let l0 = floor(lod);
    let t = lod - l0;
    let level = l0 as u32;
    let a = bilinear(info, texels, level, uv);
    if t > 0.0 {
        let b = bilinear(info, texels, level + 1, uv);
        a * (1.0 - t) + b * t
    } else {
        a
    }
}

/// The texture LOD constant of a triangle (Ray Tracing Gems ch. 20, eq. 34's `Delta`):
/// `0.5 * log2(t_a / p_a)`, with `t_a = width * height * |(uv1 - uv0) x (uv2 - uv0)|` twice
/// its area in texels and `p_a = |(p1 - p0) x (p2 - p0)|` twice its area in world units.
/// `width = height = 1` gives the constant in texture-coordinate units, to which
/// [`resolution_lod`] adds a texture's size. A triangle without area gives 0; one whose
/// texture coordinates have no area gives the value of a texel area of `f32::MIN_POSITIVE`.
#[allow(clippy::too_many_arguments)]
pub fn triangle_lod_constant(
    uv0: Vec2,
    uv1: Vec2,
    uv2: Vec2,
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    width: u32,
    height: u32,
) -> f32 {
    let (e1, e2) = (uv1 - uv0, uv2 - uv0);
    let t_a = (width as f32 * height as f32) * (e1.x * e2.y - e2.x * e1.y).abs();
    let p_a = (p1 - p0).cross(p2 - p0).length();
    if !(p_a.is_finite() && t_a.is_finite()) || p_a <= 0.0 {
        return 0.0;
    }
    let t_a = if t_a > f32::MIN_POSITIVE {
        t_a
    } else {
        f32::MIN_POSITIVE
    };
    0.5 * log2(t_a / p_a)
}

/// What a texture's size adds to a LOD constant computed in texture-coordinate units:
/// `0.5 * log2(width * height)`.
pub fn resolution_lod(info: &TextureInfo) -> f32 {
    0.5 * log2(info.width as f32 * info.height as f32)
}

/// The level of detail of a ray cone of width `cone_width` at the hit hitting a triangle of
/// LOD constant `lod_constant` at `cos_n_d` between its normal and the ray:
/// `Delta + log2(|W| / |n . d|)` (Ray Tracing Gems ch. 20, eq. 34). The width is the cone's
/// diameter where it meets the surface: `2 t tan(alpha / 2)`, about `alpha t`, for spread angle
/// `alpha` (the whole cone angle; JCGT 2021 erratum) after distance `t`, accumulated over
/// bounces as `W_i = W_(i-1) + alpha_(i-1) t_i`. Finite: the width is taken as at least
/// `f32::MIN_POSITIVE` and the cosine as at least `1e-6` in magnitude.
pub fn ray_cone_lod(lod_constant: f32, cone_width: f32, cos_n_d: f32) -> f32 {
    let w = cone_width.abs();
    let w = if w > f32::MIN_POSITIVE { w } else { f32::MIN_POSITIVE };
    let c = cos_n_d.abs();
    let c = if c > 1e-6 { c } else { 1e-6 };
    let w = if w < f32::MAX * 1e-6 { w } else { f32::MAX * 1e-6 };
    lod_constant + log2(w / c)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rgba(r: u32, g: u32, b: u32, a: u32) -> u32 {
        r | g << 8 | b << 16 | a << 24
    }

    /// A 3x2 linear texture, texel (x, y) = (40 x + 100 y, 10 + x, 20 + y, 255), and its full
    /// chain of levels (1x1: a grey texel).
    fn three_by_two(wrap_u: u32, wrap_v: u32) -> (TextureInfo, Vec<u32>) {
        let mut texels = Vec::new();
        for y in 0..2 {
            for x in 0..3 {
                texels.push(rgba(40 * x + 100 * y, 10 + x, 20 + y, 255));
            }
        }
        texels.push(rgba(77, 77, 77, 255));
        let info = TextureInfo {
            offset: 0,
            width: 3,
            height: 2,
            levels: mip_levels(3, 2),
            flags: tex_flags(false, false, wrap_u, wrap_v),
            _pad: [0; 3],
        };
        (info, texels)
    }

    /// Byte `b` as [`decode`] reads it (times the float nearest 1/255).
    fn unorm(b: u32) -> f32 {
        b as f32 * (1.0 / 255.0)
    }

    /// The byte pattern's red at integer coordinates `(x, y)` of the 3x2 texture.
    fn red(x: u32, y: u32) -> f32 {
        unorm(40 * x + 100 * y)
    }

    #[test]
    fn the_chain_of_three_by_two_is_two_levels() {
        assert_eq!(mip_levels(3, 2), 2);
        assert_eq!(level_size(3, 2, 1), (1, 1));
        assert_eq!(chain_texels(3, 2, 2), 7);
    }

    #[test]
    fn wrap_modes_on_a_three_by_two_texture() {
        // Integer wrap: repeat, clamp, mirror at negative and past-the-end coordinates.
        let repeat: Vec<u32> = (-4..7).map(|i| wrap(i, 3, WRAP_REPEAT)).collect();
        assert_eq!(repeat, [2, 0, 1, 2, 0, 1, 2, 0, 1, 2, 0]);
        let clamp: Vec<u32> = (-4..7).map(|i| wrap(i, 3, WRAP_CLAMP)).collect();
        assert_eq!(clamp, [0, 0, 0, 0, 0, 1, 2, 2, 2, 2, 2]);
        let mirror: Vec<u32> = (-4..7).map(|i| wrap(i, 3, WRAP_MIRROR)).collect();
        assert_eq!(mirror, [2, 2, 1, 0, 0, 1, 2, 2, 1, 0, 0]);
        assert_eq!(wrap(i32::MIN, 3, WRAP_REPEAT), (i32::MIN as i64).rem_euclid(3) as u32);
        assert_eq!(wrap(i32::MAX, 3, WRAP_CLAMP), 2);

        // Through texel() and through nearest lookups at uv outside [0, 1].
        for (wrap_u, wrap_v) in [
            (WRAP_REPEAT, WRAP_CLAMP),
            (WRAP_CLAMP, WRAP_MIRROR),
            (WRAP_MIRROR, WRAP_REPEAT),
        ] {
            let (mut info, texels) = three_by_two(wrap_u, wrap_v);
            for y in -3..5 {
                for x in -4..7 {
                    let (xi, yi) = (wrap(x, 3, wrap_u), wrap(y, 2, wrap_v));
                    let t = texel(&info, &texels, 0, x, y);
                    assert_eq!(t.x, red(xi, yi), "texel ({x}, {y}) wrap {wrap_u} {wrap_v}");
                    assert_eq!(t.y, unorm(10 + xi));
                    assert_eq!(t.z, unorm(20 + yi));
                    assert_eq!(t.w, 1.0);
                }
            }
            info.flags |= TEX_NEAREST;
            // uv at texel centres of the tiled plane: u = (x + 0.5) / 3, v = (y + 0.5) / 2.
            for y in -3..5 {
                for x in -4..7 {
                    let uv = Vec2::new((x as f32 + 0.5) / 3.0, (y as f32 + 0.5) / 2.0);
                    let (xi, yi) = (wrap(x, 3, wrap_u), wrap(y, 2, wrap_v));
                    let t = bilinear(&info, &texels, 0, uv);
                    assert_eq!(t.x, red(xi, yi), "nearest at {uv} wrap {wrap_u} {wrap_v}");
                }
            }
        }
        // Examples spelled out: u = -0.1 and 1.1, v = 0.25.
        let (mut info, texels) = three_by_two(WRAP_REPEAT, WRAP_REPEAT);
        info.flags |= TEX_NEAREST;
        let at = |info: &TextureInfo, u: f32| bilinear(info, &texels, 0, Vec2::new(u, 0.25)).x;
        assert_eq!(at(&info, -0.1), red(2, 0));
        assert_eq!(at(&info, 1.1), red(0, 0));
        info.flags = tex_flags(false, true, WRAP_CLAMP, WRAP_CLAMP);
        assert_eq!(at(&info, -0.1), red(0, 0));
        assert_eq!(at(&info, 1.1), red(2, 0));
        info.flags = tex_flags(false, true, WRAP_MIRROR, WRAP_MIRROR);
        assert_eq!(at(&info, -0.1), red(0, 0));
        assert_eq!(at(&info, -0.5), red(1, 0));
        assert_eq!(at(&info, 1.1), red(2, 0));
        assert_eq!(at(&info, 1.9), red(0, 0));
        assert_eq!(at(&info, 2.1), red(0, 0));
        // NaN and huge coordinates stay in the texture.
        assert!(at(&info, f32::NAN).is_finite());
        assert!(at(&info, 1e30).is_finite());
        info.flags = tex_flags(false, false, WRAP_CLAMP, WRAP_CLAMP);
        assert_eq!(at(&info, -1e30), red(0, 0));
        assert_eq!(at(&info, 1e30), red(2, 0));
    }

    #[test]
    fn bilinear_at_texel_centres_and_halfway() {
        for (wrap_u, wrap_v) in [
            (WRAP_REPEAT, WRAP_REPEAT),
            (WRAP_CLAMP, WRAP_CLAMP),
            (WRAP_MIRROR, WRAP_MIRROR),
        ] {
            let (info, texels) = three_by_two(wrap_u, wrap_v);
            for y in 0..2 {
                for x in 0..3 {
                    let uv = Vec2::new((x as f32 + 0.5) / 3.0, (y as f32 + 0.5) / 2.0);
                    let got = bilinear(&info, &texels, 0, uv);
                    assert_eq!(got, texel(&info, &texels, 0, x, y), "centre of ({x}, {y})");
                }
            }
            // Halfway between the centres of (0, 0) and (1, 0), of (1, 0) and (1, 1), and in
            // the middle of four.
            let half = |uv: Vec2| bilinear(&info, &texels, 0, uv).x;
            let close = |a: f32, b: f32| (a - b).abs() < 1e-6;
            assert!(close(half(Vec2::new(1.0 / 3.0, 0.25)), (red(0, 0) + red(1, 0)) / 2.0));
            assert!(close(half(Vec2::new(0.5, 0.5)), (red(1, 0) + red(1, 1)) / 2.0));
            let four = (red(1, 0) + red(2, 0) + red(1, 1) + red(2, 1)) / 4.0;
            assert!(close(half(Vec2::new(2.0 / 3.0, 0.5)), four));
        }
        // Across the edge: halfway between the last and (by its wrap) the next texel.
        let edge = Vec2::new(1.0, 0.25);
        let (info, texels) = three_by_two(WRAP_REPEAT, WRAP_REPEAT);
        let got = bilinear(&info, &texels, 0, edge).x;
        assert!((got - (red(2, 0) + red(0, 0)) / 2.0).abs() < 1e-6);
        let (info, texels) = three_by_two(WRAP_CLAMP, WRAP_CLAMP);
        assert!((bilinear(&info, &texels, 0, edge).x - red(2, 0)).abs() < 1e-6);
    }

    #[test]
    fn srgb_decoding_is_the_exact_curve() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-6);
        // Every byte against a table computed in f64 from the standard's formula, and the
        // round trip through the encoding.
        for b in 0..256u32 {
            let c = b as f64 / 255.0;
            let table = if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            };
            let got = decode(rgba(b, b, b, b), true);
            assert!((got.x as f64 - table).abs() < 1e-6, "byte {b}: {} vs {table}", got.x);
            assert_eq!(got.x, got.y);
            assert_eq!(got.x, got.z);
            assert_eq!(got.w, unorm(b), "alpha stays linear");
            assert_eq!(decode(rgba(b, 0, 0, 0), false).x, unorm(b));
            assert!((unorm(b) - b as f32 / 255.0).abs() <= f32::EPSILON * unorm(b));
            assert_eq!((linear_to_srgb(got.x) * 255.0).round() as u32, b);
        }
        // Through a texture flagged sRGB.
        let info = TextureInfo {
            width: 1,
            height: 1,
            levels: 1,
            flags: TEX_SRGB,
            ..Default::default()
        };
        let t = texel(&info, &[rgba(128, 0, 255, 128)], 0, 0, 0);
        assert!((t.x - 0.215_860_5).abs() < 1e-6 && t.y == 0.0 && (t.z - 1.0).abs() < 1e-6);
        assert_eq!(t.w, unorm(128));
    }

    /// A 4x4 linear texture of red 0 with a chain whose level 1 (2x2) is red 100 and
    /// level 2 (1x1) red 200.
    fn chain() -> (TextureInfo, Vec<u32>) {
        let mut texels = vec![rgba(0, 0, 0, 255); 16];
        texels.extend([rgba(100, 0, 0, 255); 4]);
        texels.push(rgba(200, 0, 0, 255));
        let info = TextureInfo {
            offset: 0,
            width: 4,
            height: 4,
            levels: 3,
            flags: 0,
            _pad: [0; 3],
        };
        assert_eq!(chain_texels(4, 4, 3), texels.len() as u32);
        (info, texels)
    }

    #[test]
    fn trilinear_blends_levels_and_clamps_lod() {
        let (info, texels) = chain();
        let uv = Vec2::new(0.3, 0.7);
        let red = |lod: f32| sample(&info, &texels, uv, lod).x * 255.0;
        let close = |a: f32, b: f32| (a - b).abs() < 1e-4;
        assert!(close(red(0.0), 0.0));
        assert!(close(red(0.5), 50.0), "{}", red(0.5));
        assert!(close(red(1.0), 100.0));
        assert!(close(red(1.25), 125.0));
        assert!(close(red(2.0), 200.0));
        for lod in [-1.0, -1e30, f32::NEG_INFINITY, f32::NAN] {
            assert!(close(red(lod), 0.0), "lod {lod}");
        }
        for lod in [2.5, 3.0, 1e30, f32::INFINITY] {
            assert!(close(red(lod), 200.0), "lod {lod}");
        }
        // Level indices past the last read the last; the texture's offset is honoured.
        assert!(close(bilinear(&info, &texels, 7, uv).x * 255.0, 200.0));
        assert!(close(texel(&info, &texels, u32::MAX, 0, 0).x * 255.0, 200.0));
        let mut shifted = vec![rgba(9, 9, 9, 9); 5];
        shifted.extend(&texels);
        let moved = TextureInfo { offset: 5, ..info };
        assert_eq!(sample(&moved, &shifted, uv, 0.75), sample(&info, &texels, uv, 0.75));
    }

    #[test]
    fn non_power_of_two_chain() {
        assert_eq!(mip_levels(5, 3), 3);
        let sizes: Vec<(u32, u32)> = (0..3).map(|l| level_size(5, 3, l)).collect();
        assert_eq!(sizes, [(5, 3), (2, 1), (1, 1)]);
        assert_eq!(chain_texels(5, 3, 3), 15 + 2 + 1);
        let info = TextureInfo {
            offset: 10,
            width: 5,
            height: 3,
            levels: 3,
            ..Default::default()
        };
        assert_eq!(level_base(&info, 1), (25, 2, 1));
        assert_eq!(level_base(&info, 2), (27, 1, 1));
        assert_eq!(mip_levels(1, 1), 1);
        assert_eq!(mip_levels(256, 256), 9);
        assert_eq!(mip_levels(1, 300), 9);
        assert_eq!(level_size(1, 300, 8), (1, 1));
    }

    #[test]
    fn lod_constant_of_a_unit_right_triangle() {
        // Texel area 256 * 256 * 1 (twice), world area 1 (twice): 0.5 log2(65536) = 8.
        let (p0, p1, p2) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let (uv0, uv1, uv2) = (Vec2::ZERO, Vec2::X, Vec2::Y);
        let delta = triangle_lod_constant(uv0, uv1, uv2, p0, p1, p2, 256, 256);
        assert_eq!(delta, 256f32.log2());
        // Order and winding do not matter; doubling the world size takes one level off.
        assert_eq!(triangle_lod_constant(uv0, uv2, uv1, p0, p2, p1, 256, 256), 8.0);
        let big = triangle_lod_constant(uv0, uv1, uv2, p0, p1 * 2.0, p2 * 2.0, 256, 256);
        assert_eq!(big, 7.0);
        // In uv units plus the resolution.
        let info = TextureInfo {
            width: 256,
            height: 256,
            ..Default::default()
        };
        let uv_only = triangle_lod_constant(uv0, uv1, uv2, p0, p1, p2, 1, 1);
        assert_eq!(uv_only + resolution_lod(&info), 8.0);
        // Degenerate triangles give finite constants.
        assert_eq!(triangle_lod_constant(uv0, uv1, uv2, p0, p0, p2, 256, 256), 0.0);
        let flat_uv = triangle_lod_constant(uv0, uv0, uv0, p0, p1, p2, 256, 256);
        assert!(flat_uv.is_finite() && flat_uv < -60.0);
        let nan = Vec3::splat(f32::NAN);
        assert_eq!(triangle_lod_constant(uv0, uv1, uv2, nan, p1, p2, 256, 256), 0.0);
    }

    #[test]
    fn ray_cone_lod_adds_width_and_slant() {
        assert_eq!(ray_cone_lod(8.0, 1.0, 1.0), 8.0);
        // A cone 1/256 wide on a 256-texel unit square seen head-on: one texel, level 0.
        assert_eq!(ray_cone_lod(8.0, 1.0 / 256.0, 1.0), 0.0);
        assert_eq!(ray_cone_lod(8.0, 1.0 / 256.0, -0.5), 1.0);
        assert_eq!(ray_cone_lod(8.0, -4.0, 1.0), 10.0);
        for (w, c) in [(0.0, 1.0), (1.0, 0.0), (f32::INFINITY, 0.0), (0.0, 0.0)] {
            assert!(ray_cone_lod(8.0, w, c).is_finite(), "{w} {c}");
        }
    }
}
