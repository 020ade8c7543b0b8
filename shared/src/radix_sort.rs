//! Stable least-significant-digit radix sort of (key, primitive) pairs over many workgroups
//! (reduce-then-scan; Merrill & Grimshaw 2011, without their subgroup tricks).
//!
//! One pass sorts by the `RADIX_BITS`-bit digit at `BuildParams::shift` in three dispatches:
//! 1. [`histogram`]: each tile of `TILE` keys counts its digits into the table
//!    `counts[digit * tiles + tile]`;
//! 2. the table scan of [`crate::scan`]: one workgroup turns counts into output offsets;
//! 3. [`scatter`]: each tile ranks its keys stably and writes them to their offsets.
//!
//! In the scatter, invocation `lane` of a tile owns the `ITEMS` consecutive keys starting at
//! `lane * ITEMS`, so order within a tile is (lane, item) = input order, which makes the
//! pass stable. The workgroup keeps one counter per (digit, lane):
//!
//! ```text
//! counts[d * WORKGROUP + lane]   digit-major: an exclusive scan of the whole array gives,
//!                                for lane l, (#keys of tile with digit < d)
//!                                          + (#keys with digit d owned by lanes < l)
//! ```
use crate::scan::{self, BlockScan};
use crate::sync;
use crate::types::{BuildParams, ITEMS, TILE, WORKGROUP};

pub const RADIX_BITS: u32 = 4;
pub const RADIX: u32 = 1 << RADIX_BITS;
const PER_LANE: u32 = RADIX * WORKGROUP / WORKGROUP;
const _: () = assert!(RADIX * WORKGROUP % WORKGROUP == 0 && PER_LANE == RADIX);

/// A key the sort can take apart into digits.
pub trait SortKey: Copy + PartialEq {
    const BITS: u32;
    fn digit(self, shift: u32) -> u32;
    /// Leading zeros of `self ^ other`.
    fn clz_xor(self, other: Self) -> u32;
}

impl SortKey for u32 {
    const BITS: u32 = 32;
    fn digit(self, shift: u32) -> u32 {
        (self >> shift) & (RADIX - 1)
    }
    fn clz_xor(self, other: Self) -> u32 {
        (self ^ other).leading_zeros()
    }
}

impl SortKey for u64 {
    const BITS: u32 = 64;
    fn digit(self, shift: u32) -> u32 {
        ((self >> shift) as u32) & (RADIX - 1)
    }
    fn clz_xor(self, other: Self) -> u32 {
        let x = self ^ other;
        let hi = (x >> 32) as u32;
        if hi != 0 {
            hi.leading_zeros()
        } else {
            32 + (x as u32).leading_zeros()
        }
    }
}

/// Workgroup memory of the histogram kernel.
pub struct HistogramState {
    pub counts: [u32; RADIX as usize],
}

pub fn histogram_clear(lane: u32, st: &mut HistogramState) {
    if lane < RADIX {
        st.counts[lane as usize] = 0;
    }
}

pub fn histogram_count<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut HistogramState,
    p: &BuildParams,
    keys: &[K],
) {
    let mut i = group * TILE + lane;
    let end = (group * TILE + TILE).min(p.n);
    while i < end {
        sync::workgroup_add(&mut st.counts[keys[i as usize].digit(p.shift) as usize], 1);
        i += WORKGROUP;
    }
}

pub fn histogram_store(
    lane: u32,
    group: u32,
    st: &HistogramState,
    p: &BuildParams,
    table: &mut [u32],
) {
    if lane < RADIX {
        table[(lane * p.tiles + group) as usize] = st.counts[lane as usize];
    }
}

/// Workgroup memory of the scatter kernel.
pub struct ScatterState {
    pub counts: [u32; (RADIX * WORKGROUP) as usize],
    /// Per digit: global offset of this tile's first key with that digit, minus the tile-local
    /// exclusive count of smaller digits.
    pub base: [u32; RADIX as usize],
    pub scan: BlockScan,
}

fn owned(lane: u32, group: u32, p: &BuildParams) -> (u32, u32) {
    let start = (group * TILE + lane * ITEMS).min(p.n);
    (start, (start + ITEMS).min(p.n))
}

/// Phase 1: lane counts the digits of the keys it owns into its column.
pub fn scatter_count<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    keys: &[K],
) {
    let mut d = 0;
    while d < RADIX {
        st.counts[(d * WORKGROUP + lane) as usize] = 0;
        d += 1;
    }
    let (start, end) = owned(lane, group, p);
    let mut i = start;
    while i < end {
        st.counts[(keys[i as usize].digit(p.shift) * WORKGROUP + lane) as usize] += 1;
        i += 1;
    }
}

/// Phase 2: lane sums its `RADIX` consecutive entries of the digit-major counter array.
pub fn scatter_scan_load(lane: u32, st: &mut ScatterState) {
    let mut s = 0;
    let mut k = 0;
    while k < PER_LANE {
        s += st.counts[(lane * PER_LANE + k) as usize];
        k += 1;
    }
    st.scan.sums[0][lane as usize] = s;
}

/// Phase 3 (after the block scan): the counters become exclusive prefix sums.
pub fn scatter_scan_store(lane: u32, st: &mut ScatterState) {
    let mut run = scan::exclusive(lane, &st.scan);
    let mut k = 0;
    while k < PER_LANE {
        let i = (lane * PER_LANE + k) as usize;
        let c = st.counts[i];
        st.counts[i] = run;
        run += c;
        k += 1;
    }
}

/// Phase 4: the per-digit base of this tile from the scanned global table.
pub fn scatter_base(lane: u32, group: u32, st: &mut ScatterState, p: &BuildParams, table: &[u32]) {
    if lane < RADIX {
        let global = table[(lane * p.tiles + group) as usize];
        st.base[lane as usize] = global.wrapping_sub(st.counts[(lane * WORKGROUP) as usize]);
    }
}

/// Phase 5: lane writes its keys, in order, to their sorted places.
#[allow(clippy::too_many_arguments)]
pub fn scatter_write<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    keys_in: &[K],
    vals_in: &[u32],
    keys_out: &mut [K],
    vals_out: &mut [u32],
) {
    let (start, end) = owned(lane, group, p);
    let mut i = start;
    while i < end {
        let k = keys_in[i as usize];
        let slot = (k.digit(p.shift) * WORKGROUP + lane) as usize;
        let dst = st.base[k.digit(p.shift) as usize].wrapping_add(st.counts[slot]);
        st.counts[slot] += 1;
        keys_out[dst as usize] = k;
        vals_out[dst as usize] = vals_in[i as usize];
        i += 1;
    }
}

/// Number of digit passes for keys of `bits` significant bits (always even, so that the
/// sorted pairs end in the input buffers).
pub fn passes(bits: u32) -> u32 {
    let p = bits.div_ceil(RADIX_BITS);
    p + (p & 1)
}
