//! Stable least-significant-digit radix sort of (key, primitive) pairs over many workgroups,
//! one dispatch per `RADIX_BITS`-bit digit (Adinets & Merrill 2022, "Onesweep", without its
//! subgroup tricks):
//!
//! 1. The Morton stage counts every pass's digits ([`count_codes`]): a digit's total is the
//!    same in every order, so one sweep gives every pass its digit totals (`totals`, zero when
//!    a build starts: see [`clear_tables`]).
//! 2. Each pass's scatter claims its tile in start order ([`scatter_claim`]), counts its
//!    keys' digits, publishes them in the pass's status table and looks back over the tiles
//!    before it for each digit's count there (chained scan with decoupled look-back, Merrill
//!    & Garland 2016: a tile publishes its own counts at once and, when it knows them, the
//!    counts up to and including itself, so a later tile stops at the first such word); then
//!    it ranks its keys stably and writes them.
//!
//! The offset of digit `d` for tile `t`:
//!
//! ```text
//! offset(d, t) = sum_{d' < d} totals[d']       keys with a smaller digit
//!              + sum_{t' < t} count(d, t')     digit d in earlier tiles (the look-back)
//! ```
//!
//! A tile waits only for tiles that claimed theirs before it, which run or have run: the
//! look-back needs no more of the GPU's scheduling (nor lavapipe's threads) than that.
//!
//! In the scatter, lane `l` owns the `SORT_ITEMS` consecutive keys at `l * SORT_ITEMS`, so order
//! within a tile is (lane, item) = input order: the pass is stable. The tile's keys are put
//! in their sorted order in workgroup memory first and written out from there, lane `l`
//! taking places `l + k * WORKGROUP`: neighbouring lanes write neighbouring words of a
//! digit's run instead of words of 32 different runs. The workgroup keeps one
//! 16-bit counter per (digit, lane), two to a word (CUB's packing): word (c, l) holds digit
//! `c` in its low half and digit `c + HALF` in its high half, column-major. An exclusive scan
//! of the words (no carry crosses the halves: a tile has at most 4096 keys) gives, in the half of
//! digit `d` at (c, l), (#keys of the tile with a digit below `d` in the same half) +
//! (#keys with digit `d` of lanes < l); subtracting its value at (c, 0) leaves the rank
//! among the tile's keys of digit `d`.
use crate::scan::{self, BlockScan};
use crate::sync::{self, at, at_mut, elem, elem_mut};
use crate::types::{items_per_lane, load4, BuildParams, OrderedBounds, GROUP, SORT_ITEMS, TILE, WORKGROUP};
use seq_macro::seq;

pub const RADIX_BITS: u32 = 5;
pub const RADIX: u32 = 1 << RADIX_BITS;
/// Packed counter words per lane in the scatter: two 16-bit digit counters each.
pub const HALF: u32 = RADIX / 2;
const _: () = assert!(TILE < 1 << 16);
// The scatter stages a word of every key of a tile in the counters' memory.
const _: () = assert!(TILE as usize <= COUNTERS);
/// Lanes per digit in a look-back step.
const LANES_PER_DIGIT: u32 = WORKGROUP / RADIX;
const _: () = assert!(RADIX * LANES_PER_DIGIT == WORKGROUP);
// The loops over digits, counter words and table lanes are written out (`seq!`) with these
// counts: rust-gpu emits no unroll hints, and a loop the driver does not unroll waits out a
// workgroup-memory round trip per iteration.
const _: () = assert!(RADIX == 32 && HALF == 16 && LANES_PER_DIGIT == 8);

/// A key the sort can take apart into digits.
pub trait SortKey: Copy + PartialOrd + Default {
    const BITS: u32;
    /// A key above every Morton code of this width (the merge sort's padding).
    const ABOVE: Self;
    /// 32-bit words per key.
    const WORDS: u32;
    /// Word `i` of the key (low first).
    fn word(self, i: u32) -> u32;
    fn from_words(lo: u32, hi: u32) -> Self;
    fn digit(self, shift: u32) -> u32;
    /// Leading zeros of `self ^ other`.
    fn clz_xor(self, other: Self) -> u32;
}

impl SortKey for u32 {
    const BITS: u32 = 32;
    const ABOVE: u32 = u32::MAX;
    const WORDS: u32 = 1;
    fn word(self, _: u32) -> u32 {
        self
    }
    fn from_words(lo: u32, _: u32) -> u32 {
        lo
    }
    fn digit(self, shift: u32) -> u32 {
        if shift >= Self::BITS {
            0
        } else {
            (self >> shift) & (RADIX - 1)
        }
    }
    fn clz_xor(self, other: Self) -> u32 {
        (self ^ other).leading_zeros()
    }
}

impl SortKey for u64 {
    const BITS: u32 = 64;
    const ABOVE: u64 = u64::MAX;
    const WORDS: u32 = 2;
    fn word(self, i: u32) -> u32 {
        (self >> (32 * i)) as u32
    }
    fn from_words(lo: u32, hi: u32) -> u64 {
        lo as u64 | (hi as u64) << 32
    }
    fn digit(self, shift: u32) -> u32 {
        if shift >= Self::BITS {
            0
        } else {
            ((self >> shift) as u32) & (RADIX - 1)
        }
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

/// A status word's flags: the tile's own count of the digit; the count of it in every tile
/// up to and including this one. No flag: not published yet.
pub const AGGREGATE: u32 = 1 << 30;
pub const PREFIX: u32 = 1 << 31;
const COUNT: u32 = AGGREGATE - 1;

/// Status word of digit `d` of tile `tile` in the pass at `p.shift`, in the `counts` buffer.
pub fn status(p: &BuildParams, tile: u32, d: u32) -> u32 {
    ((p.shift / RADIX_BITS) * p.tiles() + tile) * RADIX + d
}

/// Words of the `counts` buffer for sorts of up to `n` keys: a status table per pass of the
/// widest sort (64-bit keys), `RADIX` words per tile of the smallest.
pub fn table_words(n: u32) -> u32 {
    passes(64) * RADIX * n.div_ceil(WORKGROUP * FEW).max(1)
}

/// Keys a lane of the scatter owns in a sort of `n` keys ([`BuildParams::tile_keys`]): `SORT_ITEMS`
/// from `MANY` keys, where they halve what each key pays of a tile's fixed work (its lanes'
/// counter words, the block scan, the look-back); `FEW` below, where the GPU is not full and
/// a tile's length is what a pass waits for. The scatter kernel is compiled for each (the
/// functions' `I`), so that the small sort's holds no registers for slots it leaves empty:
/// one kernel choosing at run time was slower at both sizes.
pub fn items(n: u32) -> u32 {
    if n >= MANY {
        SORT_ITEMS
    } else {
        FEW
    }
}
/// Keys a lane of the scatter owns in a small sort.
pub const FEW: u32 = 8;
/// The smallest sort whose lanes own `SORT_ITEMS` keys: above the sixteen bunnies (1.1M,
/// slower with them; 1.2M random keys too, 151 -> 174 us on the H200: bench/NOTES.md, session
/// 58) and below lavapipe's largest binary tree (2^21 primitives in a 128 MiB binding), so
/// that CI builds with both kernels.
pub const MANY: u32 = 3 << 19;

/// The `totals` buffer: every pass's digit totals (`pass * RADIX + d`), then every pass's
/// tile counter.
pub const TOTALS_WORDS: u32 = DIGIT_WORDS as u32 + passes(64);

/// Tile counter of the pass at `p.shift` in the `totals` buffer.
fn tile_counter(p: &BuildParams) -> u32 {
    DIGIT_WORDS as u32 + p.shift / RADIX_BITS
}

/// Zeroes what the sort of `p.n` keys added into or published (the digit totals, the tile
/// counters, the status tables) for the next build, invocation `i < p.n` taking every
/// `p.n`-th word. Run by a kernel after the sort, so that no build starts with a fill:
/// between builds every word is zero (the host zeroes the buffers once when it allocates
/// them). A build that sorts otherwise (`p.passes` zero: the merge sort of
/// `crate::merge_sort`) uses none of them.
pub fn clear_tables(i: u32, p: &BuildParams, counts: &mut [u32], totals: &mut [u32]) {
    if i >= p.n || p.passes == 0 {
        return;
    }
    let mut w = i;
    while w < TOTALS_WORDS {
        *at_mut(totals, w) = 0;
        w += p.n;
    }
    let words = p.passes * RADIX * p.tiles();
    let mut w = i;
    while w < words {
        *at_mut(counts, w) = 0;
        w += p.n;
    }
}

/// Number of digit passes for keys of `bits` significant bits (always even, so that the
/// sorted pairs end in the input buffers; a last pass past the key's bits only copies).
pub const fn passes(bits: u32) -> u32 {
    let p = bits.div_ceil(RADIX_BITS);
    p + (p & 1)
}

/// Digit counters of the widest sort's passes.
pub const DIGIT_WORDS: usize = (passes(64) * RADIX) as usize;

/// Workgroup memory of the Morton stage: per pass, per digit, the workgroup's keys.
pub struct DigitCounts {
    pub counts: [u32; DIGIT_WORDS],
}

/// Morton stage, phase 1: clears the counters.
pub fn digits_clear(lane: u32, st: &mut DigitCounts) {
    let mut w = lane;
    while w < DIGIT_WORDS as u32 {
        *elem_mut(&mut st.counts, w) = 0;
        w += WORKGROUP;
    }
}

/// Morton stage, phase 2 (after a barrier): lane's primitives of workgroup `group`
/// ([`items_per_lane`] of them, `WORKGROUP` apart) get their keys from `code` (the Morton
/// step, `morton::morton30` or `morton63`), and each key's digit of every pass is counted.
#[allow(clippy::too_many_arguments)]
pub fn count_codes<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut DigitCounts,
    p: &BuildParams,
    b: &OrderedBounds,
    summaries: &[[f32; 4]],
    keys: &mut [K],
    vals: &mut [u32],
    code: impl Fn(u32, &BuildParams, &OrderedBounds, &[[f32; 4]], &mut [K], &mut [u32]) -> K,
) {
    let items = items_per_lane(p.n);
    let mut k = 0;
    while k < items {
        let i = (group * items + k) * WORKGROUP + lane;
        let key = code(i, p, b, summaries, keys, vals);
        if i < p.n {
            let mut pass = 0;
            while pass < p.passes {
                let d = key.digit(pass * RADIX_BITS);
                sync::workgroup_add(elem_mut(&mut st.counts, pass * RADIX + d), 1);
                pass += 1;
            }
        }
        k += 1;
    }
}

/// Morton stage, phase 3 (after a barrier): adds the workgroup's counts into every pass's
/// digit totals.
pub fn digits_store(lane: u32, st: &DigitCounts, p: &BuildParams, totals: &mut [u32]) {
    let mut w = lane;
    while w < p.passes * RADIX {
        let c = *elem(&st.counts, w);
        if c != 0 {
            sync::atomic_add_device::<false>(at_mut(totals, w), c);
        }
        w += WORKGROUP;
    }
}

/// Words of the scatter's packed (digit pair, lane) counters: one padding word after every
/// `HALF`, so that lanes reading `HALF` consecutive words hit different banks.
pub const COUNTERS: usize = (HALF * WORKGROUP + WORKGROUP) as usize;

/// Address of flat counter word `f = column * WORKGROUP + lane` in the padded array.
fn slot(f: u32) -> u32 {
    f + f / HALF
}

/// Digit `d`'s (column, bit shift of its half) in the packed counters.
fn column(d: u32) -> (u32, u32) {
    (d % HALF, 16 * (d / HALF))
}

/// Workgroup memory of the scatter kernel.
pub struct ScatterState {
    /// Per (digit, lane) key counts, packed two to a word, column-major and padded (see
    /// [`slot`] and [`column`]); then their exclusive prefix sums.
    pub counts: [u32; COUNTERS],
    /// The look-back's chunk sums and stops ([`lookback_load`]), two words per lane.
    pub window: [u32; 2 * WORKGROUP as usize],
    /// Per digit: keys in all tiles; this tile's keys; keys in the tiles before it.
    pub digit_total: [u32; RADIX as usize],
    pub own: [u32; RADIX as usize],
    pub digit_before: [u32; RADIX as usize],
    /// Per digit: the tile the look-back reads back from (exclusive).
    pub end: [u32; RADIX as usize],
    /// Per digit: global offset of this tile's first key with that digit, minus the tile's
    /// count of keys with a smaller digit (the digit's first place in the tile's order).
    pub base: [u32; RADIX as usize],
    /// The tile this workgroup claimed; the digits whose look-back is not done.
    pub tile: u32,
    pub pending: u32,
    pub scan: BlockScan,
}

/// The first key lane owns in tile `tile` (lanes owning `I` keys).
fn owned<const I: u32>(lane: u32, tile: u32) -> u32 {
    (tile * WORKGROUP + lane) * I
}

// A lane owns four groups of four keys; the item loops below are written out (`seq!`) so
// that every key stays in a register (see `types::load4` for why loops are not).
const _: () = assert!(SORT_ITEMS == 4 * GROUP && SORT_ITEMS == 16);

/// The lane's `I` items from `first` on, loaded four at a time (the slots past them repeat
/// the first ones).
#[allow(clippy::erasing_op, clippy::identity_op, clippy::eq_op)] // `seq!` starts at 0
fn load_owned<T: Copy, const I: u32>(buf: &[T], first: u32, p: &BuildParams) -> [T; SORT_ITEMS as usize] {
    let a = load4(buf, first, 1, p.n);
    let b = load4(buf, first + GROUP, 1, p.n);
    let (c, d) = if I > 2 * GROUP {
        (
            load4(buf, first + 2 * GROUP, 1, p.n),
            load4(buf, first + 3 * GROUP, 1, p.n),
        )
    } else {
        (a, b)
    };
    let g = [a, b, c, d];
    seq!(I in 0..16 { [#(g[I / 4][I % 4],)*] })
}

/// Counts the lane's key `k`, key `i` of the input (if it exists), into lane's column.
fn count_key<K: SortKey, const I: u32>(st: &mut ScatterState, lane: u32, p: &BuildParams, k: u32, i: u32, key: K) {
    if k < I && i < p.n {
        let (c, half) = column(key.digit(p.shift));
        *elem_mut(&mut st.counts, slot(c * WORKGROUP + lane)) += 1 << half;
    }
}

/// Keys of the tile whose digit is in the low half of the packed counters, added to the
/// place of every key in the high half (`half` is 16 there).
fn lower_half(st: &ScatterState, half: u32) -> u32 {
    if half == 0 {
        0
    } else {
        scan::total(&st.scan) & 0xffff
    }
}

/// The place of the lane's key `k`, key `i` of the input, in the tile's sorted order (if it
/// exists; `TILE` if not), counting it.
fn rank_key<K: SortKey, const I: u32>(
    st: &mut ScatterState,
    lane: u32,
    p: &BuildParams,
    k: u32,
    i: u32,
    key: K,
) -> u32 {
    if k < I && i < p.n {
        let (c, half) = column(key.digit(p.shift));
        let at = slot(c * WORKGROUP + lane);
        let v = *elem(&st.counts, at);
        *elem_mut(&mut st.counts, at) = v + (1 << half);
        ((v >> half) & 0xffff) + lower_half(st, half)
    } else {
        TILE
    }
}

/// Phase 0: lane 0 claims the workgroup's tile, the next of the pass in start order (so
/// that every tile it waits for in the look-back has started).
pub fn scatter_claim(lane: u32, st: &mut ScatterState, p: &BuildParams, totals: &mut [u32]) {
    if lane == 0 {
        st.tile = sync::atomic_add_device::<false>(at_mut(totals, tile_counter(p)), 1);
    }
}

/// Phase 1 (after a barrier): lane counts the digits of the keys it owns into its column;
/// lanes below `RADIX` load their digit's total. Returns the keys and their values for
/// [`scatter_rank`] (held in registers: reloading them there cost a round trip a pass, 1M
/// 99 -> 93 us).
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_count<K: SortKey, const I: u32>(
    lane: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    keys: &[K],
    vals: &[u32],
    totals: &[u32],
) -> Owned<K> {
    seq!(C in 0..16 {
        *elem_mut(&mut st.counts, slot(C * WORKGROUP + lane)) = 0;
    });
    let start = owned::<I>(lane, st.tile);
    let keys = load_owned::<_, I>(keys, start, p);
    // The values are loaded now, in the shadow of the counting, and held with the keys until
    // the ranking.
    let vals = load_owned::<_, I>(vals, start, p);
    if lane < RADIX {
        *elem_mut(&mut st.digit_total, lane) = *at(totals, p.shift / RADIX_BITS * RADIX + lane);
    }
    seq!(N in 0..16 {
        count_key::<K, I>(st, lane, p, N, start + N, keys[N]);
    });
    Owned { keys, vals }
}

/// The keys and values a lane owns, loaded once by [`scatter_count`] for [`scatter_rank`].
pub struct Owned<K> {
    pub keys: [K; SORT_ITEMS as usize],
    pub vals: [u32; SORT_ITEMS as usize],
}

/// Phase 2: lane sums its `HALF` consecutive counter words for the block scan.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_sums(lane: u32, st: &mut ScatterState) {
    let mut s = 0;
    seq!(K in 0..16 {
        s += *elem(&st.counts, slot(lane * HALF + K));
    });
    *elem_mut(&mut st.scan.sums, lane) = s;
}

/// The block scan's value in digit `d`'s half at the start of its column: the tile's keys
/// with a smaller digit in that half.
fn smaller(st: &ScatterState, d: u32) -> u32 {
    let (c, half) = column(d);
    // Block-scan lane `column * WORKGROUP / HALF` starts with word (column, lane 0).
    (scan::exclusive(c * WORKGROUP / HALF, &st.scan) >> half) & 0xffff
}

/// Phase 3 (after the block scan): the counters become exclusive prefix sums; lanes below
/// `RADIX` publish the tile's count of their digit (tile 0: as its prefix, ending its
/// look-back) and start their digit's base (see the module docs) from the totals.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_offsets(lane: u32, st: &mut ScatterState, p: &BuildParams, counts: &mut [u32]) {
    let mut run = scan::exclusive(lane, &st.scan);
    seq!(K in 0..16 {
        let c~K = *elem(&st.counts, slot(lane * HALF + K));
    });
    seq!(K in 0..16 {
        *elem_mut(&mut st.counts, slot(lane * HALF + K)) = run;
        run += c~K;
    });
    let tile = st.tile;
    if lane < RADIX {
        let (c, half) = column(lane);
        let first = smaller(st, lane);
        let next = if c + 1 < HALF {
            smaller(st, lane + 1)
        } else {
            (scan::total(&st.scan) >> half) & 0xffff
        };
        let own = next - first;
        let flag = if tile == 0 { PREFIX } else { AGGREGATE };
        sync::atomic_store_u32(at_mut(counts, status(p, tile, lane)), flag | own);
        *elem_mut(&mut st.own, lane) = own;
        *elem_mut(&mut st.digit_before, lane) = 0;
        *elem_mut(&mut st.end, lane) = tile;
        let mut offset = 0u32;
        seq!(D in 0..32 {
            offset += if D < lane { *elem(&st.digit_total, D) } else { 0 };
        });
        *elem_mut(&mut st.base, lane) = offset.wrapping_sub(first + lower_half(st, half));
    }
    if lane == 0 {
        st.pending = if tile == 0 { 0 } else { RADIX };
    }
}

/// Whether a look-back step is due (every lane reads the same, after a barrier).
pub fn looking_back(st: &ScatterState) -> bool {
    st.pending != 0
}

/// Status words a lane reads in a look-back step, and the tiles a step covers per digit.
pub const CHUNK: u32 = 8;
pub const WINDOW: u32 = CHUNK * LANES_PER_DIGIT;
const _: () = assert!(CHUNK == 8);

/// `end` of a digit whose look-back is done.
const DONE: u32 = u32::MAX;

/// What a chunk of status words (newest first) adds to the count before the tile:
/// `(sum, stop)`, `sum` of the counts up to and including the first prefix, or up to the
/// first word not yet published, `stop` that word's place in the chunk and a flag
/// ([`PREFIX`] or 0), or `CHUNK` if the chunk has neither.
#[allow(clippy::identity_op)] // `seq!` starts at 0
fn chunk_sum(v: [u32; CHUNK as usize]) -> (u32, u32) {
    let mut sum = 0;
    let mut stop = CHUNK;
    // Written out (see `RADIX`).
    seq!(K in 0..8 {
        if stop == CHUNK {
            let w = v[K];
            if w == 0 {
                stop = K;
            } else {
                sum += w & COUNT;
                if w & PREFIX != 0 {
                    stop = K | PREFIX;
                }
            }
        }
    });
    (sum, stop)
}

/// Digit `d`'s status word of tile `end - 1 - k`; a prefix of 0 before tile 0.
fn status_word(p: &BuildParams, counts: &[u32], end: u32, k: u32, d: u32) -> u32 {
    if k < end {
        sync::atomic_load_u32(at(counts, status(p, end - 1 - k, d)))
    } else {
        PREFIX
    }
}

/// Look-back phase 1: lane `q * RADIX + d` sums digit `d`'s status words of the chunk of
/// tiles `end - 1 - q * CHUNK - m`, `m` in `0..CHUNK` ([`chunk_sum`]; 32 neighbouring lanes
/// read one tile's row at a time), into `window[d * LANES_PER_DIGIT + q]`. Before tile
/// 0 it reads a prefix of 0 (never reached: tile 0's word is a prefix).
pub fn lookback_load(lane: u32, st: &mut ScatterState, p: &BuildParams, counts: &[u32]) {
    let (q, d) = (lane / RADIX, lane % RADIX);
    let end = *elem(&st.end, d);
    if end == DONE {
        return;
    }
    let k = q * CHUNK;
    let v = [
        status_word(p, counts, end, k, d),
        status_word(p, counts, end, k + 1, d),
        status_word(p, counts, end, k + 2, d),
        status_word(p, counts, end, k + 3, d),
        status_word(p, counts, end, k + 4, d),
        status_word(p, counts, end, k + 5, d),
        status_word(p, counts, end, k + 6, d),
        status_word(p, counts, end, k + 7, d),
    ];
    let (sum, stop) = chunk_sum(v);
    let at = 2 * (d * LANES_PER_DIGIT + q);
    *elem_mut(&mut st.window, at) = sum;
    *elem_mut(&mut st.window, at + 1) = stop;
}

/// Look-back phase 2 (after a barrier): lane `d < RADIX` adds its digit's chunk sums in
/// order up to the first chunk that stopped: at a prefix it knows the count before its
/// tile and publishes its own prefix; at a word not yet published the next step reloads
/// from there.
pub fn lookback_sum(lane: u32, st: &mut ScatterState, p: &BuildParams, counts: &mut [u32]) {
    if lane >= RADIX {
        return;
    }
    let end = *elem(&st.end, lane);
    if end == DONE {
        return;
    }
    let mut before = *elem(&st.digit_before, lane);
    let mut read = 0;
    let mut stop = CHUNK;
    let mut q = 0;
    while q < LANES_PER_DIGIT && stop == CHUNK {
        let at = 2 * (lane * LANES_PER_DIGIT + q);
        before += *elem(&st.window, at);
        stop = *elem(&st.window, at + 1);
        read += if stop == CHUNK { CHUNK } else { stop & !PREFIX };
        q += 1;
    }
    *elem_mut(&mut st.digit_before, lane) = before;
    if stop & PREFIX != 0 {
        let own = *elem(&st.own, lane);
        sync::atomic_store_u32(at_mut(counts, status(p, st.tile, lane)), PREFIX | (before + own));
        *elem_mut(&mut st.end, lane) = DONE;
        *elem_mut(&mut st.base, lane) = elem(&st.base, lane).wrapping_add(before);
        sync::workgroup_add(&mut st.pending, u32::MAX);
    } else {
        *elem_mut(&mut st.end, lane) = end - read;
    }
}

/// The keys a lane owns, their values and their ranks: places in the sorted order of the
/// scatter's tile.
pub struct Ranked<K> {
    pub keys: [K; SORT_ITEMS as usize],
    pub vals: [u32; SORT_ITEMS as usize],
    pub ranks: [u32; SORT_ITEMS as usize],
}

/// Phase 4: lane ranks its keys within the tile (stably: in order).
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_rank<K: SortKey, const I: u32>(
    lane: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    o: Owned<K>,
) -> Ranked<K> {
    let start = owned::<I>(lane, st.tile);
    let k = o.keys;
    let ranks = seq!(N in 0..16 { [#(rank_key::<K, I>(st, lane, p, N, start + N, k[N]),)*] });
    Ranked {
        keys: o.keys,
        vals: o.vals,
        ranks,
    }
}

/// Stages one word at its place in the counters' memory (free once every lane has ranked its
/// keys).
fn stage_word(st: &mut ScatterState, place: u32, word: u32) {
    if place < TILE {
        *elem_mut(&mut st.counts, place) = word;
    }
}

/// Phase 5 (after a barrier): the lane puts word `w` of each of its keys at the key's place
/// in workgroup memory. The tile's keys are staged a word at a time (64-bit keys in two
/// rounds: [`scatter_staged`] reads the low words back first), so that the counters' memory
/// holds a tile.
#[allow(clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_stage_keys<K: SortKey>(st: &mut ScatterState, s: &Ranked<K>, w: u32) {
    seq!(I in 0..16 {
        stage_word(st, s.ranks[I], s.keys[I].word(w));
    });
}

/// Phase 6 (after a barrier): the staged words at the tile's sorted places `lane + k *
/// WORKGROUP`, the places the lane writes out.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_staged<const I: u32>(lane: u32, st: &ScatterState) -> [u32; SORT_ITEMS as usize] {
    let staged = |k: u32| {
        if k < I {
            *elem(&st.counts, lane + k * WORKGROUP)
        } else {
            0
        }
    };
    seq!(N in 0..16 { [#(staged(N),)*] })
}

/// Writes the key at the lane's `k`-th sorted place (if the tile has one there; `lo` its low
/// word, its high word staged) to its global place, which it returns (`u32::MAX` if none).
fn write_key<K: SortKey, const I: u32>(
    st: &ScatterState,
    p: &BuildParams,
    lane: u32,
    k: u32,
    lo: u32,
    keys_out: &mut [K],
) -> u32 {
    let place = lane + k * WORKGROUP;
    if k >= I || st.tile * WORKGROUP * I + place >= p.n {
        return u32::MAX;
    }
    let hi = if K::WORDS == 2 { *elem(&st.counts, place) } else { 0 };
    let key = K::from_words(lo, hi);
    let to = elem(&st.base, key.digit(p.shift)).wrapping_add(place);
    *at_mut(keys_out, to) = key;
    to
}

/// Phase 7 (64-bit keys: after a barrier, phase 5 for the high words and another barrier):
/// lane writes the tile's sorted places `lane + k * WORKGROUP` out, so that neighbouring lanes write
/// neighbouring words of a digit's run; returns where.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_write_keys<K: SortKey, const I: u32>(
    lane: u32,
    st: &ScatterState,
    p: &BuildParams,
    lo: &[u32; SORT_ITEMS as usize],
    keys_out: &mut [K],
) -> [u32; SORT_ITEMS as usize] {
    seq!(N in 0..16 { [#(write_key::<K, I>(st, p, lane, N, lo[N], keys_out),)*] })
}

/// Phase 8 (after a barrier): the lane puts its values at their places in workgroup memory.
#[allow(clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_stage_vals<K: SortKey>(st: &mut ScatterState, s: &Ranked<K>) {
    seq!(I in 0..16 {
        stage_word(st, s.ranks[I], s.vals[I]);
    });
}

fn write_val(st: &ScatterState, place: u32, at: u32, vals_out: &mut [u32]) {
    if at != u32::MAX {
        *at_mut(vals_out, at) = *elem(&st.counts, place);
    }
}

/// Phase 9 (after a barrier): lane writes the values of the places it wrote keys of.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_write_vals(lane: u32, st: &ScatterState, at: &[u32; SORT_ITEMS as usize], vals_out: &mut [u32]) {
    seq!(I in 0..16 {
        write_val(st, lane + I * WORKGROUP, at[I], vals_out);
    });
}
