//! Stable least-significant-digit radix sort of (key, primitive) pairs over many workgroups
//! (reduce-then-scan, Merrill & Grimshaw 2011, without their subgroup tricks), two
//! dispatches per `RADIX_BITS`-bit digit:
//!
//! 1. [`histogram_count`]: each tile of `TILE` keys counts its digits, stores them in the tile
//!    table `counts[digit * tiles + tile]`, and adds them atomically into the super-tile
//!    table `supers[digit * n_supers + tile / SUPER]` of this pass (zero when a build starts:
//!    see [`clear_tables`]).
//! 2. [`scatter_count`] and the phases after it: each tile finds the output offset of every
//!    digit from the two tables, reading at most `RADIX * (n_supers + SUPER)` words, ranks its
//!    keys stably and writes them.
//!
//! Small sorts (at most `COUNTED_MAX` keys, [`counted`]) have no histogram dispatch, one
//! dispatch per digit: the Morton stage counts every pass's digits
//! ([`digits_count`]; a digit's total is the same in every order) and the first pass's per
//! tile (its keys are in their first pass's order), and each scatter adds the key it writes
//! into the next pass's tile table, the tile of its place there ([`scatter_write_keys`]).
//! Each pass has its own tile table (`RADIX * tiles` words from [`table_base`]).
//!
//! The offset of digit `d` for tile `t` in super-tile `s = t / SUPER`:
//!
//! ```text
//! offset(d, t) = sum_{d' < d} sum_S supers[d'][S]      keys with a smaller digit
//!              + sum_{S < s} supers[d][S]              digit d in earlier super-tiles
//!              + sum_{s*SUPER <= t' < t} counts[d][t'] digit d in earlier tiles of s
//! ```
//!
//! In the scatter, lane `l` owns the `ITEMS` consecutive keys at `l * ITEMS`, so order
//! within a tile is (lane, item) = input order: the pass is stable. The tile's keys are put
//! in their sorted order in workgroup memory first and written out from there, lane `l`
//! taking places `l + k * WORKGROUP`: neighbouring lanes write neighbouring words of a
//! digit's run instead of words of 32 different runs. The workgroup keeps one
//! 16-bit counter per (digit, lane), two to a word (CUB's packing): word (c, l) holds digit
//! `c` in its low half and digit `c + HALF` in its high half, column-major. An exclusive scan
//! of the words (no carry crosses the halves: a tile has 2048 keys) gives, in the half of
//! digit `d` at (c, l), (#keys of the tile with a digit below `d` in the same half) +
//! (#keys with digit `d` of lanes < l); subtracting its value at (c, 0) leaves the rank
//! among the tile's keys of digit `d`.
use crate::scan::{self, BlockScan};
use crate::sync::{self, at, at_mut, elem, elem_mut};
use crate::types::{load4, BuildParams, GROUP, ITEMS, TILE, WORKGROUP};
use seq_macro::seq;

pub const RADIX_BITS: u32 = 5;
pub const RADIX: u32 = 1 << RADIX_BITS;
/// Packed counter words per lane in the scatter: two 16-bit digit counters each.
pub const HALF: u32 = RADIX / 2;
const _: () = assert!(TILE < 1 << 16);
// The scatter stages a tile of 64-bit keys in the counters' memory.
const _: () = assert!(2 * TILE as usize <= COUNTERS);
/// Tiles per super-tile.
pub const SUPER: u32 = 64;
/// Lanes that share one digit when the scatter sums the tables.
const LANES_PER_DIGIT: u32 = WORKGROUP / RADIX;
const _: () = assert!(RADIX * LANES_PER_DIGIT == WORKGROUP);
// The loops over digits, counter words and table lanes are written out (`seq!`) with these
// counts: rust-gpu emits no unroll hints, and a loop the driver does not unroll waits out a
// workgroup-memory round trip per iteration.
const _: () = assert!(RADIX == 32 && HALF == 16 && LANES_PER_DIGIT == 8);

/// A key the sort can take apart into digits.
pub trait SortKey: Copy + PartialOrd + Default {
    const BITS: u32;
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

/// Number of super-tiles.
pub fn super_count(p: &BuildParams) -> u32 {
    p.tiles().div_ceil(SUPER)
}

/// Keys of the largest counted sort (at most one super-tile).
pub const COUNTED_MAX: u32 = COUNTED_TILES * TILE;
/// Tiles of the largest counted sort. A counted pass saves a histogram dispatch but pays an
/// atomic add per key; on the H100 (B30 totals, counted vs histogram sort) 4,000 keys
/// (2 tiles) build in 95 us instead of 113, 8,000 (4) in 106 instead of 115, but 16,000 (8)
/// in 133 instead of 117 and the bunny (35) in 147 instead of 133.
pub const COUNTED_TILES: u32 = 4;
const _: () = assert!(COUNTED_TILES <= SUPER);

/// Whether the sort of `p.n` keys is counted (no histogram dispatch; see the module docs):
/// more than the rank sort's [`RANK_MAX`], at most one super-tile.
pub fn counted(p: &BuildParams) -> bool {
    p.n > RANK_MAX && p.n <= COUNTED_MAX
}

/// Start of the tile table of the pass at `shift` in the `counts` buffer: one table per pass
/// in a counted sort, one table for all passes otherwise.
pub fn table_base(p: &BuildParams, shift: u32) -> u32 {
    if counted(p) {
        shift / RADIX_BITS * RADIX * p.tiles()
    } else {
        0
    }
}

/// Words of the `counts` buffer a counted sort may use: the tables of every pass of the
/// widest sort (64-bit keys) of the largest counted sort.
pub const COUNTED_WORDS: u32 = passes(64) * RADIX * COUNTED_TILES;

/// Words of the `counts` buffer for sorts of up to `n` keys: one table for every pass of a
/// histogram sort, or every table of a counted one.
pub fn table_words(n: u32) -> u32 {
    (RADIX * n.div_ceil(TILE)).max(COUNTED_WORDS)
}

/// Words of the `counts` buffer the sort of `p.n` keys leaves non-zero: a counted sort's
/// tables; every table word a next counted sort could use after any other (the histogram
/// overwrites its table); none after a rank sort, which uses no table.
fn dirty_table_words(p: &BuildParams) -> u32 {
    if p.n <= RANK_MAX {
        0
    } else if counted(p) {
        p.passes * RADIX * p.tiles()
    } else {
        COUNTED_WORDS
    }
}

/// Start of this pass's super-tile table in the `supers` buffer (`RADIX * supers` per pass).
pub fn supers_base(p: &BuildParams) -> u32 {
    p.shift / RADIX_BITS * RADIX * super_count(p)
}

/// Words of the super-tile tables of every pass of the widest sort (64-bit keys) of `n`
/// keys.
pub fn supers_words(n: u32) -> u32 {
    passes(64) * RADIX * n.div_ceil(TILE).div_ceil(SUPER)
}

/// Zeroes the super-tile tables and the counted sorts' tile tables for the next build (both
/// are added into atomically), invocation `i < p.n` taking every `p.n`-th word. Run by a
/// kernel after the sort, so that no build starts with a fill: between builds every word
/// either uses is zero (the host zeroes the buffers once when it allocates them).
pub fn clear_tables(i: u32, p: &BuildParams, counts: &mut [u32], supers: &mut [u32]) {
    if i >= p.n {
        return;
    }
    let words = supers_words(p.n);
    let mut w = i;
    while w < words {
        *at_mut(supers, w) = 0;
        w += p.n;
    }
    let words = dirty_table_words(p);
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

/// Workgroup memory of the Morton stage of a counted sort: per pass, per digit, the
/// workgroup's keys.
pub struct DigitCounts {
    pub counts: [u32; DIGIT_WORDS],
}

/// Morton stage of a counted sort, phase 1: clears the counters.
pub fn digits_clear(lane: u32, st: &mut DigitCounts) {
    let mut w = lane;
    while w < DIGIT_WORDS as u32 {
        *elem_mut(&mut st.counts, w) = 0;
        w += WORKGROUP;
    }
}

/// Morton stage of a counted sort, phase 2 (after a barrier): counts key `i`'s digit of
/// every pass, if it exists.
pub fn digits_count<K: SortKey>(i: u32, st: &mut DigitCounts, p: &BuildParams, key: K) {
    if i < p.n {
        let mut pass = 0;
        while pass < p.passes {
            let d = key.digit(pass * RADIX_BITS);
            sync::workgroup_add(elem_mut(&mut st.counts, pass * RADIX + d), 1);
            pass += 1;
        }
    }
}

/// Morton stage of a counted sort, phase 3 (after a barrier): adds the workgroup's counts
/// (of keys `WORKGROUP * group..`, all in one tile) into every pass's digit totals (its
/// super-tile table: one super-tile) and the first pass's tile table.
pub fn digits_store(lane: u32, group: u32, st: &DigitCounts, p: &BuildParams, counts: &mut [u32], supers: &mut [u32]) {
    let tile = group / (TILE / WORKGROUP);
    let mut w = lane;
    while w < p.passes * RADIX {
        let c = *elem(&st.counts, w);
        if c != 0 {
            let d = w % RADIX;
            // `supers_base` of pass `w / RADIX` with one super-tile: `w - d`.
            sync::atomic_add_device::<false>(at_mut(supers, w), c);
            if w < RADIX {
                sync::atomic_add_device::<false>(at_mut(counts, d * p.tiles() + tile), c);
            }
        }
        w += WORKGROUP;
    }
}

/// Workgroup memory of the histogram kernel.
pub struct HistogramState {
    pub counts: [u32; RADIX as usize],
}

pub fn histogram_clear(lane: u32, st: &mut HistogramState) {
    if lane < RADIX {
        *elem_mut(&mut st.counts, lane) = 0;
    }
}

pub fn histogram_count<K: SortKey>(lane: u32, group: u32, st: &mut HistogramState, p: &BuildParams, keys: &[K]) {
    let mut k = 0;
    while k < ITEMS {
        let first = group * TILE + k * WORKGROUP + lane;
        let g = load4(keys, first, WORKGROUP, p.n);
        for j in 0..GROUP {
            if first + j * WORKGROUP < p.n {
                sync::workgroup_add(elem_mut(&mut st.counts, g[j as usize].digit(p.shift)), 1);
            }
        }
        k += GROUP;
    }
}

pub fn histogram_store(
    lane: u32,
    group: u32,
    st: &HistogramState,
    p: &BuildParams,
    counts: &mut [u32],
    supers: &mut [u32],
) {
    if lane < RADIX {
        let c = *elem(&st.counts, lane);
        *at_mut(counts, lane * p.tiles() + group) = c;
        if c != 0 {
            sync::atomic_add_device::<false>(
                at_mut(supers, supers_base(p) + lane * super_count(p) + group / SUPER),
                c,
            );
        }
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
    /// Per lane: its share of the tables' sums (all of its digit; before this tile).
    pub total: [u32; WORKGROUP as usize],
    pub before: [u32; WORKGROUP as usize],
    /// Per digit: keys in all tiles; keys in the tiles before this one.
    pub digit_total: [u32; RADIX as usize],
    pub digit_before: [u32; RADIX as usize],
    /// Per digit: global offset of this tile's first key with that digit, minus the tile's
    /// count of keys with a smaller digit (the digit's first place in the tile's order).
    pub base: [u32; RADIX as usize],
    pub scan: BlockScan,
}

fn owned(lane: u32, group: u32) -> u32 {
    group * TILE + lane * ITEMS
}

// A lane owns two groups of four keys; the item loops below are written out so that every
// key stays in a register (see `types::load4` for why loops are not).
const _: () = assert!(ITEMS == 2 * GROUP);

/// Counts key `i` (if it exists) into lane's column.
fn count_key<K: SortKey>(st: &mut ScatterState, lane: u32, p: &BuildParams, i: u32, key: K) {
    if i < p.n {
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

/// Key `i`'s place in the tile's sorted order (if it exists; `TILE` if not), counting it.
fn rank_key<K: SortKey>(st: &mut ScatterState, lane: u32, p: &BuildParams, i: u32, key: K) -> u32 {
    if i < p.n {
        let (c, half) = column(key.digit(p.shift));
        let at = slot(c * WORKGROUP + lane);
        let v = *elem(&st.counts, at);
        *elem_mut(&mut st.counts, at) = v + (1 << half);
        ((v >> half) & 0xffff) + lower_half(st, half)
    } else {
        TILE
    }
}

/// Super-tile `x`'s sum `v` as (its share of the digit's total, of the count before super-tile
/// `s`); nothing past the last super-tile.
fn super_share(x: u32, v: u32, n_supers: u32, s: u32) -> (u32, u32) {
    if x >= n_supers {
        (0, 0)
    } else if x < s {
        (v, v)
    } else {
        (v, 0)
    }
}

/// Tile `t`'s count `v` if it comes before this tile (`group`), else 0.
fn tile_share(t: u32, v: u32, group: u32) -> u32 {
    if t < group {
        v
    } else {
        0
    }
}

/// Phase 1: lane counts the digits of the keys it owns into its column, and sums its share
/// of the tables for the tile offsets. Returns the keys and their values for [`scatter_rank`]
/// (held in registers: reloading them there cost a round trip a pass, 1M 99 -> 93 us).
#[allow(clippy::too_many_arguments)]
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_count<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    keys: &[K],
    vals: &[u32],
    counts: &[u32],
    supers: &[u32],
) -> Owned<K> {
    seq!(C in 0..16 {
        *elem_mut(&mut st.counts, slot(C * WORKGROUP + lane)) = 0;
    });
    let start = owned(lane, group);
    let (a, b) = (load4(keys, start, 1, p.n), load4(keys, start + GROUP, 1, p.n));
    // The values are loaded now, in the shadow of the counting and the table sums, and held
    // with the keys until the ranking.
    let (va, vb) = (load4(vals, start, 1, p.n), load4(vals, start + GROUP, 1, p.n));
    count_key(st, lane, p, start, a[0]);
    count_key(st, lane, p, start + 1, a[1]);
    count_key(st, lane, p, start + 2, a[2]);
    count_key(st, lane, p, start + 3, a[3]);
    count_key(st, lane, p, start + 4, b[0]);
    count_key(st, lane, p, start + 5, b[1]);
    count_key(st, lane, p, start + 6, b[2]);
    count_key(st, lane, p, start + 7, b[3]);
    // Table sums: lane = digit * LANES_PER_DIGIT + j takes every LANES_PER_DIGIT-th entry.
    let d = lane / LANES_PER_DIGIT;
    let j = lane % LANES_PER_DIGIT;
    let n_supers = super_count(p);
    let row = supers_base(p) + d * n_supers;
    let s = group / SUPER;
    // Four table entries per round, loaded before any is used (see `load4`).
    let mut total = 0;
    let mut before = 0;
    let mut x = j;
    while x < n_supers {
        let v = load4(supers, row + x, LANES_PER_DIGIT, row + n_supers);
        let (t0, b0) = super_share(x, v[0], n_supers, s);
        let (t1, b1) = super_share(x + LANES_PER_DIGIT, v[1], n_supers, s);
        let (t2, b2) = super_share(x + 2 * LANES_PER_DIGIT, v[2], n_supers, s);
        let (t3, b3) = super_share(x + 3 * LANES_PER_DIGIT, v[3], n_supers, s);
        total += t0 + t1 + t2 + t3;
        before += b0 + b1 + b2 + b3;
        x += GROUP * LANES_PER_DIGIT;
    }
    let tile_row = table_base(p, p.shift) + d * p.tiles();
    let mut t = s * SUPER + j;
    while t < group {
        let v = load4(counts, tile_row + t, LANES_PER_DIGIT, tile_row + group);
        before += tile_share(t, v[0], group)
            + tile_share(t + LANES_PER_DIGIT, v[1], group)
            + tile_share(t + 2 * LANES_PER_DIGIT, v[2], group)
            + tile_share(t + 3 * LANES_PER_DIGIT, v[3], group);
        t += GROUP * LANES_PER_DIGIT;
    }
    *elem_mut(&mut st.total, lane) = total;
    *elem_mut(&mut st.before, lane) = before;
    Owned {
        keys: [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]],
        vals: [va[0], va[1], va[2], va[3], vb[0], vb[1], vb[2], vb[3]],
    }
}

/// The keys and values a lane owns, loaded once by [`scatter_count`] for [`scatter_rank`].
pub struct Owned<K> {
    pub keys: [K; ITEMS as usize],
    pub vals: [u32; ITEMS as usize],
}

/// Phase 2: lane sums its `HALF` consecutive counter words for the block scan; lanes below
/// `RADIX` also finish the table sums of their digit.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_sums(lane: u32, st: &mut ScatterState) {
    let mut s = 0;
    seq!(K in 0..16 {
        s += *elem(&st.counts, slot(lane * HALF + K));
    });
    *elem_mut(&mut st.scan.sums, lane) = s;
    if lane < RADIX {
        let (mut total, mut before) = (0, 0);
        seq!(J in 0..8 {
            total += *elem(&st.total, lane * LANES_PER_DIGIT + J);
            before += *elem(&st.before, lane * LANES_PER_DIGIT + J);
        });
        *elem_mut(&mut st.digit_total, lane) = total;
        *elem_mut(&mut st.digit_before, lane) = before;
    }
}

/// Phase 3 (after the block scan): the counters become exclusive prefix sums, and lanes
/// below `RADIX` find the global offset of their digit for this tile (see the module docs).
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn scatter_offsets(lane: u32, st: &mut ScatterState) {
    let mut run = scan::exclusive(lane, &st.scan);
    seq!(K in 0..16 {
        let c~K = *elem(&st.counts, slot(lane * HALF + K));
    });
    seq!(K in 0..16 {
        *elem_mut(&mut st.counts, slot(lane * HALF + K)) = run;
        run += c~K;
    });
    if lane < RADIX {
        // The scan's value in this digit's half at word (column, lane 0); block-scan lane
        // `column * WORKGROUP / HALF` starts with that word.
        let (c, half) = column(lane);
        let smaller = (scan::exclusive(c * WORKGROUP / HALF, &st.scan) >> half) & 0xffff;
        let mut offset = *elem(&st.digit_before, lane);
        seq!(D in 0..32 {
            offset += if D < lane { *elem(&st.digit_total, D) } else { 0 };
        });
        *elem_mut(&mut st.base, lane) = offset.wrapping_sub(smaller + lower_half(st, half));
    }
}

/// The keys a lane owns, their values and their ranks: places in the sorted order (of the
/// scatter's tile, or of all keys in the rank sort).
pub struct Ranked<K> {
    pub keys: [K; ITEMS as usize],
    pub vals: [u32; ITEMS as usize],
    pub ranks: [u32; ITEMS as usize],
}

/// Phase 4: lane ranks its keys within the tile (stably: in order).
pub fn scatter_rank<K: SortKey>(
    lane: u32,
    group: u32,
    st: &mut ScatterState,
    p: &BuildParams,
    o: Owned<K>,
) -> Ranked<K> {
    let start = owned(lane, group);
    let k = o.keys;
    let ranks = [
        rank_key(st, lane, p, start, k[0]),
        rank_key(st, lane, p, start + 1, k[1]),
        rank_key(st, lane, p, start + 2, k[2]),
        rank_key(st, lane, p, start + 3, k[3]),
        rank_key(st, lane, p, start + 4, k[4]),
        rank_key(st, lane, p, start + 5, k[5]),
        rank_key(st, lane, p, start + 6, k[6]),
        rank_key(st, lane, p, start + 7, k[7]),
    ];
    Ranked {
        keys: o.keys,
        vals: o.vals,
        ranks,
    }
}

/// Stages one key (or value) in the counters' memory (free once every lane has ranked its
/// keys).
fn stage_key<K: SortKey>(st: &mut ScatterState, place: u32, key: K) {
    if place < TILE {
        *elem_mut(&mut st.counts, place * K::WORDS) = key.word(0);
        if K::WORDS == 2 {
            *elem_mut(&mut st.counts, 2 * place + 1) = key.word(1);
        }
    }
}

/// Stages the lane's eight keys (or values) at their places.
fn stage_items<T: SortKey>(st: &mut ScatterState, places: &[u32; ITEMS as usize], items: &[T; ITEMS as usize]) {
    stage_key(st, places[0], items[0]);
    stage_key(st, places[1], items[1]);
    stage_key(st, places[2], items[2]);
    stage_key(st, places[3], items[3]);
    stage_key(st, places[4], items[4]);
    stage_key(st, places[5], items[5]);
    stage_key(st, places[6], items[6]);
    stage_key(st, places[7], items[7]);
}

/// Phase 5 (after a barrier): the lane puts its keys at their places in workgroup memory.
pub fn scatter_stage_keys<K: SortKey>(st: &mut ScatterState, s: &Ranked<K>) {
    stage_items(st, &s.ranks, &s.keys);
}

/// Writes the staged key at `place` (if the tile has one there) to its global place, which
/// it returns (`u32::MAX` if none); in a counted sort, counts it into the next pass's tile
/// table (`next` is that table's start, `u32::MAX` after the last pass).
fn write_key<K: SortKey>(
    st: &ScatterState,
    p: &BuildParams,
    group: u32,
    place: u32,
    next: u32,
    keys_out: &mut [K],
    counts: &mut [u32],
) -> u32 {
    if group * TILE + place >= p.n {
        return u32::MAX;
    }
    let hi = if K::WORDS == 2 {
        *elem(&st.counts, 2 * place + 1)
    } else {
        0
    };
    let key = K::from_words(*elem(&st.counts, place * K::WORDS), hi);
    let to = elem(&st.base, key.digit(p.shift)).wrapping_add(place);
    *at_mut(keys_out, to) = key;
    if next != u32::MAX {
        let d = key.digit(p.shift + RADIX_BITS);
        sync::atomic_add_device::<false>(at_mut(counts, next + d * p.tiles() + to / TILE), 1);
    }
    to
}

/// Phase 6 (after a barrier): lane writes the tile's sorted places `lane + k * WORKGROUP`
/// out, so that neighbouring lanes write neighbouring words of a digit's run; returns where.
/// A counted sort's keys are counted into the next pass's table here (see the module docs).
pub fn scatter_write_keys<K: SortKey>(
    lane: u32,
    group: u32,
    st: &ScatterState,
    p: &BuildParams,
    keys_out: &mut [K],
    counts: &mut [u32],
) -> [u32; ITEMS as usize] {
    let next_shift = p.shift + RADIX_BITS;
    let next = if counted(p) && next_shift < p.passes * RADIX_BITS {
        table_base(p, next_shift)
    } else {
        u32::MAX
    };
    [
        write_key(st, p, group, lane, next, keys_out, counts),
        write_key(st, p, group, lane + WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 2 * WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 3 * WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 4 * WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 5 * WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 6 * WORKGROUP, next, keys_out, counts),
        write_key(st, p, group, lane + 7 * WORKGROUP, next, keys_out, counts),
    ]
}

/// Phase 7 (after a barrier): the lane puts its values at their places in workgroup memory.
pub fn scatter_stage_vals<K: SortKey>(st: &mut ScatterState, s: &Ranked<K>) {
    stage_items(st, &s.ranks, &s.vals);
}

fn write_val(st: &ScatterState, place: u32, at: u32, vals_out: &mut [u32]) {
    if at != u32::MAX {
        *at_mut(vals_out, at) = *elem(&st.counts, place);
    }
}

/// Phase 8 (after a barrier): lane writes the values of the places it wrote keys of.
pub fn scatter_write_vals(lane: u32, st: &ScatterState, at: &[u32; ITEMS as usize], vals_out: &mut [u32]) {
    write_val(st, lane, at[0], vals_out);
    write_val(st, lane + WORKGROUP, at[1], vals_out);
    write_val(st, lane + 2 * WORKGROUP, at[2], vals_out);
    write_val(st, lane + 3 * WORKGROUP, at[3], vals_out);
    write_val(st, lane + 4 * WORKGROUP, at[4], vals_out);
    write_val(st, lane + 5 * WORKGROUP, at[5], vals_out);
    write_val(st, lane + 6 * WORKGROUP, at[6], vals_out);
    write_val(st, lane + 7 * WORKGROUP, at[7], vals_out);
}

/// Inputs of at most `RANK_MAX` keys (one tile) skip the radix passes: one workgroup of one
/// dispatch gives every key its stable rank, the number of keys that are smaller or equal and
/// earlier ([`rank`]), and after a barrier writes it there ([`place`]). The same order as the
/// radix passes (a stable sort's output is unique) for one dispatch instead of
/// `2 * passes(bits)`: the fixed cost that dominates small scenes' builds.
pub const RANK_MAX: u32 = TILE;

/// Rank sort, phase 1: ranks the keys lane owns against all `p.n` keys, each rank counted in
/// a register over one sweep of the keys.
pub fn rank<K: SortKey>(lane: u32, p: &BuildParams, keys: &[K], vals: &[u32]) -> Ranked<K> {
    let mut r = Ranked {
        keys: [K::default(); ITEMS as usize],
        vals: [0; ITEMS as usize],
        ranks: [0; ITEMS as usize],
    };
    let items = p.n.div_ceil(WORKGROUP);
    let mut k = 0;
    while k < items {
        let i = lane + k * WORKGROUP;
        if i < p.n {
            let own = *at(keys, i);
            let mut rank = 0;
            let mut j = 0;
            while j < p.n {
                let key = *at(keys, j);
                if key < own || key == own && j < i {
                    rank += 1;
                }
                j += 1;
            }
            r.keys[k as usize] = own;
            r.vals[k as usize] = *at(vals, i);
            r.ranks[k as usize] = rank;
        }
        k += 1;
    }
    r
}

/// Rank sort, phase 2 (after every lane's phase 1): writes the lane's keys to their ranks.
pub fn place<K: SortKey>(lane: u32, p: &BuildParams, r: &Ranked<K>, keys: &mut [K], vals: &mut [u32]) {
    for k in 0..ITEMS {
        if lane + k * WORKGROUP < p.n {
            let at = r.ranks[k as usize] as usize;
            keys[at] = r.keys[k as usize];
            vals[at] = r.vals[k as usize];
        }
    }
}
