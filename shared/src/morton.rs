//! Morton codes of quantised primitive centroids (Karras 2012, sec. 4; pbrt-v4 `LeftShift3`).
//!
//! Quantisation multiplies by a power of two chosen from the exponent of each axis's extent,
//! so it is exact on every backend: the CPU and the GPU produce the same codes bit for bit.
//! Each axis gets between half and all of its `2^bits` cells.
//!
//! The codes are extended by one bit of primitive size (Vinkler, Bittner & Havran 2017,
//! "Extended Morton codes for high performance bounding volume hierarchy construction"):
//! below the first three bits (the first octree split) comes a bit saying whether the
//! primitive is large (see [`large`]), then the Morton code's next bits, its last one
//! dropped. Large primitives (a room's walls) then gather in subtrees of their own instead of
//! widening the box of every subtree of small ones they fall among: on the CPU executor's
//! count, rays in the bunny scene (the bunny in the Cornell box) visit 18.6 -> 12.5 inner
//! nodes, in the Cornell box 11.0 -> 10.4, in Suzanne's 12.7 -> 9.6.
use crate::sync::{at, at_mut};
use crate::types::{BuildParams, OrderedBounds};
use spirv_std::glam::Vec3;

/// Spreads the low 10 bits of `v` so that bit `k` moves to bit `3k`:
///
/// ```text
/// v = ---- ---- ---- ---- ---- --98 7654 3210
///   = ---- 9--8 --7- -6-- 5--4 --3- -2-- 1--0
/// ```
pub fn expand_bits_10(v: u32) -> u32 {
    let mut v = v & 0x3FF;
    v = (v | (v << 16)) & 0x0300_00FF;
    v = (v | (v << 8)) & 0x0300_F00F;
    v = (v | (v << 4)) & 0x030C_30C3;
    v = (v | (v << 2)) & 0x0924_9249;
    v
}

/// Spreads the low 21 bits of `v` so that bit `k` moves to bit `3k` (63 bits used).
pub fn expand_bits_21(v: u64) -> u64 {
    let mut v = v & 0x1F_FFFF;
    v = (v | (v << 32)) & 0x001F_0000_0000_FFFF;
    v = (v | (v << 16)) & 0x001F_0000_FF00_00FF;
    v = (v | (v << 8)) & 0x100F_00F0_0F00_F00F;
    v = (v | (v << 4)) & 0x10C3_0C30_C30C_30C3;
    v = (v | (v << 2)) & 0x1249_2492_4924_9249;
    v
}

/// The power of two `s` for which `extent * s` lies in `[cells/2, cells)`; `cells = 2^bits`.
/// Built from the exponent bits of `extent`, so it is exact.
pub fn cell_scale(extent: f32, bits: u32) -> f32 {
    let e = ((extent.to_bits() >> 23) & 0xFF) as i32 - 127;
    let k = bits as i32 - 1 - e;
    let biased = (k + 127).clamp(1, 254);
    f32::from_bits((biased as u32) << 23)
}

/// Cell of `x` on an axis starting at `lo` with scale `s`, clamped to `[0, 2^bits)`; NaN -> 0.
pub fn quantise(x: f32, lo: f32, s: f32, bits: u32) -> u32 {
    let q = (x - lo) * s;
    let top = ((1u32 << bits) - 1) as f32;
    if q >= 0.0 {
        if q < top {
            q as u32
        } else {
            top as u32
        }
    } else {
        0
    }
}

/// Quantised cell of a primitive on each axis, from its summary.
fn cells(s: [f32; 4], b: &OrderedBounds, bits: u32) -> [u32; 3] {
    let lo = b.min();
    let ext: Vec3 = b.max() - lo;
    [
        quantise(s[0], lo.x, cell_scale(ext.x, bits), bits),
        quantise(s[1], lo.y, cell_scale(ext.y, bits), bits),
        quantise(s[2], lo.z, cell_scale(ext.z, bits), bits),
    ]
}

/// Spatial bits of a code above its size bit: one octree level.
pub const OCTREE_BITS: u32 = 3;

/// Whether a primitive is large: its box's largest side (`s[3]` of its summary) exceeds half
/// the largest side of the centroids' bounds (`b` holds doubled centroids, hence the 4).
/// Exact on every backend (subtractions, a comparison and a multiplication by a power of two).
pub fn large(s: [f32; 4], b: &OrderedBounds) -> bool {
    let e = b.max() - b.min();
    4.0 * s[3] > e.x.max(e.y).max(e.z)
}

/// 30-bit code of primitive `i` (`zyx` bit triples, the size bit below the first; see the
/// module); 0 when `i >= n`.
pub fn code30(i: u32, p: &BuildParams, b: &OrderedBounds, summaries: &[[f32; 4]]) -> u32 {
    if i >= p.n {
        return 0;
    }
    code30_of(*at(summaries, i), b)
}

/// The 30-bit code of a primitive of summary `s` ([`crate::types::prim_summary`]) in the
/// bounds `b`; a primitive outside them takes the nearest cell.
pub fn code30_of(s: [f32; 4], b: &OrderedBounds) -> u32 {
    let q = cells(s, b, 10);
    let m = (expand_bits_10(q[2]) << 2) | (expand_bits_10(q[1]) << 1) | expand_bits_10(q[0]);
    let low = (1u32 << (30 - OCTREE_BITS)) - 1;
    (m & !low) | (large(s, b) as u32) << (29 - OCTREE_BITS) | (m & low) >> 1
}

/// [`code30`] of primitive `i` into `keys[i]`, which it returns; also resets the sort value
/// to `i`.
pub fn morton30(
    i: u32,
    p: &BuildParams,
    b: &OrderedBounds,
    summaries: &[[f32; 4]],
    keys: &mut [u32],
    vals: &mut [u32],
) -> u32 {
    if i >= p.n {
        return 0;
    }
    let key = code30(i, p, b, summaries);
    *at_mut(keys, i) = key;
    *at_mut(vals, i) = i;
    key
}

/// 63-bit code of primitive `i`, laid out as [`code30`]'s; 0 when `i >= n`.
pub fn code63(i: u32, p: &BuildParams, b: &OrderedBounds, summaries: &[[f32; 4]]) -> u64 {
    if i >= p.n {
        return 0;
    }
    code63_of(*at(summaries, i), b)
}

/// [`code30_of`]'s 63-bit code.
pub fn code63_of(s: [f32; 4], b: &OrderedBounds) -> u64 {
    let q = cells(s, b, 21);
    let m = (expand_bits_21(q[2] as u64) << 2) | (expand_bits_21(q[1] as u64) << 1) | expand_bits_21(q[0] as u64);
    let low = (1u64 << (63 - OCTREE_BITS)) - 1;
    (m & !low) | (large(s, b) as u64) << (62 - OCTREE_BITS) | (m & low) >> 1
}

/// [`code63`] of primitive `i` into `keys[i]`, which it returns; also resets the sort value
/// to `i`.
pub fn morton63(
    i: u32,
    p: &BuildParams,
    b: &OrderedBounds,
    summaries: &[[f32; 4]],
    keys: &mut [u64],
    vals: &mut [u32],
) -> u64 {
    if i >= p.n {
        return 0;
    }
    let key = code63(i, p, b, summaries);
    *at_mut(keys, i) = key;
    *at_mut(vals, i) = i;
    key
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slow_expand(v: u64, bits: u32) -> u64 {
        (0..bits).map(|k| ((v >> k) & 1) << (3 * k)).sum()
    }

    #[test]
    fn expand_bits_moves_bit_k_to_3k() {
        for v in [0u32, 1, 2, 3, 0x155, 0x2AA, 0x3FF, 0x200, 0x1234] {
            assert_eq!(expand_bits_10(v) as u64, slow_expand((v & 0x3FF) as u64, 10), "{v:#x}");
        }
        for v in [0u64, 1, 0x1F_FFFF, 0x15_5555, 0x10_0000, 0x12_3456, 0xFFFF_FFFF] {
            assert_eq!(expand_bits_21(v), slow_expand(v & 0x1F_FFFF, 21), "{v:#x}");
        }
    }

    #[test]
    fn cell_scale_fits_extent_into_cells() {
        for ext in [1e-30f32, 1e-6, 0.3, 1.0, 1.5, 2.0, 1023.0, 1024.0, 3e5, 1e30, f32::MAX] {
            for bits in [10u32, 21] {
                let s = cell_scale(ext, bits);
                let cells = (1u64 << bits) as f64;
                let scaled = ext as f64 * s as f64;
                assert!(
                    scaled < cells && scaled >= cells / 2.0,
                    "ext {ext} bits {bits}: {scaled}"
                );
            }
        }
        // Zero extent (all centroids equal) quantises everything to cell 0.
        assert_eq!(quantise(5.0, 5.0, cell_scale(0.0, 10), 10), 0);
    }

    #[test]
    fn quantise_clamps_and_rejects_nan() {
        assert_eq!(quantise(f32::NAN, 0.0, 1.0, 10), 0);
        assert_eq!(quantise(-1.0, 0.0, 1.0, 10), 0);
        assert_eq!(quantise(1e9, 0.0, 1.0, 10), 1023);
        assert_eq!(quantise(1e9, 0.0, 1.0, 21), (1 << 21) - 1);
        assert_eq!(quantise(7.9, 0.0, 1.0, 10), 7);
    }

    /// The size bit: set for a primitive whose box spans more than half of the centroids'
    /// extent, clear for small ones, and below the first octree level: codes still order
    /// by octant first, then small before large within one, then by position.
    #[test]
    fn large_primitives_get_the_size_bit_below_the_first_octant_bits() {
        use crate::types::{f32_to_ordered, prim_summary, Triangle};
        let tri = |c: [f32; 3], r: f32| Triangle {
            v0: [c[0] - r, c[1] - r, c[2], 0.0],
            v1: [c[0] + r, c[1] - r, c[2], 0.0],
            v2: [c[0], c[1] + r, c[2], 0.0],
        };
        // Small triangles in the low octant and the high one, and a wall-sized one.
        let tris = [
            tri([0.1, 0.1, 0.1], 0.01),
            tri([0.9, 0.9, 0.9], 0.01),
            tri([0.2, 0.2, 0.2], 0.6),
        ];
        let mut b = OrderedBounds::EMPTY;
        let summaries: [[f32; 4]; 3] = core::array::from_fn(|i| prim_summary(i as u32, 3, &tris, &[]));
        for s in summaries {
            for (k, v) in s[..3].iter().copied().enumerate() {
                b.min[k] = b.min[k].min(f32_to_ordered(v));
                b.max[k] = b.max[k].max(f32_to_ordered(v));
            }
        }
        let p = BuildParams {
            n_tris: 3,
            n: 3,
            shift: 0,
            passes: 0,
        };
        let (mut k30, mut k63, mut vals) = ([0u32; 3], [0u64; 3], [0u32; 3]);
        for i in 0..3 {
            morton30(i, &p, &b, &summaries, &mut k30, &mut vals);
            morton63(i, &p, &b, &summaries, &mut k63, &mut vals);
        }
        let bit30 = |k: u32| k >> (29 - OCTREE_BITS) & 1;
        let bit63 = |k: u64| k >> (62 - OCTREE_BITS) & 1;
        assert_eq!([bit30(k30[0]), bit30(k30[1]), bit30(k30[2])], [0, 0, 1], "{k30:x?}");
        assert_eq!([bit63(k63[0]), bit63(k63[1]), bit63(k63[2])], [0, 0, 1], "{k63:x?}");
        // Same octant as the first (low), so after it; before the high octant's.
        assert!(k30[0] < k30[2] && k30[2] < k30[1], "{k30:x?}");
        assert!(k63[0] < k63[2] && k63[2] < k63[1], "{k63:x?}");
        assert!(k30.iter().all(|&k| k < 1 << 30) && k63.iter().all(|&k| k < 1 << 63));
    }

    /// A summary holds what the Morton stage used to gather itself: twice the centroid
    /// (`min + max` of a triangle's box, `c + c` of a sphere's centre) and the box's largest
    /// side, exactly.
    #[test]
    fn summaries_hold_the_doubled_centroid_and_the_largest_side() {
        use crate::types::{prim_summary, Sphere, Triangle};
        let tris = [Triangle {
            v0: [0.0, 0.0, 0.0, 0.0],
            v1: [2.0, 1.0, 0.5, 0.0],
            v2: [-1.0, 3.0, 0.25, 0.0],
        }];
        // A negative radius counts as its absolute value.
        let spheres = [Sphere {
            center_radius: [1.0, -2.0, 0.1, -0.75],
        }];
        let want = [[1.0, 3.0, 0.5, 3.0], [2.0, -4.0, 0.2, 1.5]];
        for (i, want) in want.into_iter().enumerate() {
            let s = prim_summary(i as u32, 1, &tris, &spheres);
            assert_eq!(s.map(f32::to_bits), want.map(f32::to_bits), "primitive {i}");
        }
    }
}
