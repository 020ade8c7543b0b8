//! Stable sort of at most [`MAX`] (key, primitive) pairs in three dispatches whatever the key
//! width, where the radix passes (`crate::radix_sort`) take one dispatch a 5-bit digit: 6 for
//! 30-bit codes, 13 for 63-bit, each ~8 us on the H100 however few the keys (a pass's latency:
//! claim, load, count, look back, rank, write), most of a small build's time.
//!
//! 1. [`tile_load`], [`tile_stage`], [`tile_write`] (kernel `sort_tile_*`): a workgroup a tile
//!    of `TILE` keys sorts them in workgroup memory by a bitonic network over (key, place in
//!    the tile) pairs (unique, so equal keys keep their order) and writes them, their values,
//!    and each key's place in its tile as its rank so far. A sort of one tile writes its
//!    output in place and is done.
//! 2. [`merge_own`], [`merge_load`], [`merge_count`], [`merge_add`] (kernel `sort_merge_*`):
//!    workgroup (t, c) holds tile t's sorted keys and, for each tile u of the `CHUNK` tiles of
//!    chunk c, loads u's keys into workgroup memory and counts those that go before each of its
//!    own (binary search): the smaller ones, and the equal ones too where u comes before t.
//!    It adds each key's count to its rank with a device atomic (a sum: the same in any order).
//! 3. [`place`] (kernel `sort_place_*`): each key to its rank.
//!
//! A key's rank is then the number of keys that are smaller, or equal and earlier in the input:
//! its place in the stable sort, whose output is unique (the radix passes' too, on both
//! backends). Ranks live in the refit's visit counters (binding 10), which the tree kernel
//! writes after the sort; `place` leaves them zero.
use crate::radix_sort::SortKey;
use crate::sync::{at, at_mut, atomic_add_device, elem, elem_mut};
use crate::types::{BuildParams, ITEMS, TILE, WORKGROUP};
use seq_macro::seq;

/// Tiles of the largest input sorted here; larger inputs take the radix passes. The merge
/// loads every tile once for every tile (`TILES_MAX^2` tile loads at most).
pub const TILES_MAX: u32 = 64;
/// Keys of the largest input sorted here.
pub const MAX: u32 = TILES_MAX * TILE;
/// Tiles one merge workgroup counts against (the grid's second dimension: chunks of them).
pub const CHUNK: u32 = 4;

const T: usize = TILE as usize;

/// Workgroup memory of a tile's sort: the keys, their places in the tile (the network's
/// tie-break, and where each key's value is), the values.
pub struct TileState<K> {
    pub keys: [K; T],
    pub place: [u32; T],
    pub vals: [u32; T],
}

/// Workgroup memory of the merge: the keys of the tile counted against.
pub struct MergeState<K> {
    pub keys: [K; T],
}

/// Keys of tile `tile` of `p.n`.
pub fn tile_len(p: &BuildParams, tile: u32) -> u32 {
    (p.n - tile * TILE).min(TILE)
}

/// Size of the bitonic network that sorts tile `tile`: its keys' count rounded up to a power of
/// two (at least 2). The workgroup loops over the network's stages (`k` from 2 to it doubling,
/// `j` from `k / 2` to 1 halving), calling [`tile_stage`] with a barrier after each.
pub fn network(p: &BuildParams, tile: u32) -> u32 {
    tile_len(p, tile).max(2).next_power_of_two()
}

/// Sort, phase 1: lane loads keys `lane + m * WORKGROUP` of tile `tile` (past the input's end,
/// the largest key), their places and their values.
pub fn tile_load<K: SortKey>(lane: u32, tile: u32, st: &mut TileState<K>, p: &BuildParams, keys: &[K], vals: &[u32]) {
    let len = tile_len(p, tile);
    let mut m = 0;
    while m < ITEMS {
        let s = lane + m * WORKGROUP;
        let i = tile * TILE + s;
        let (key, val) = if s < len {
            (*at(keys, i), *at(vals, i))
        } else {
            (K::MAX, 0)
        };
        *elem_mut(&mut st.keys, s) = key;
        *elem_mut(&mut st.place, s) = s;
        *elem_mut(&mut st.vals, s) = val;
        m += 1;
    }
}

/// Sort, phase 2 (one per stage `(k, j)` of a network of `size`): lane compares and orders
/// pairs `lane + q * WORKGROUP` of the stage: `(i, i + j)`, ascending where `i & k` is zero.
pub fn tile_stage<K: SortKey>(lane: u32, st: &mut TileState<K>, size: u32, k: u32, j: u32) {
    let mut x = lane;
    while x < size / 2 {
        let i = ((x & !(j - 1)) << 1) | (x & (j - 1));
        let o = i | j;
        let (ki, ko) = (*elem(&st.keys, i), *elem(&st.keys, o));
        let (pi, po) = (*elem(&st.place, i), *elem(&st.place, o));
        let greater = ki > ko || ki == ko && pi > po;
        if greater == (i & k == 0) {
            *elem_mut(&mut st.keys, i) = ko;
            *elem_mut(&mut st.keys, o) = ki;
            *elem_mut(&mut st.place, i) = po;
            *elem_mut(&mut st.place, o) = pi;
        }
        x += WORKGROUP;
    }
}

/// Sort, phase 3: lane writes keys `lane + m * WORKGROUP` of the sorted tile and their values:
/// in place (`keys`, `vals`) where the input is one tile, else to `sorted_keys` and
/// `sorted_vals` with each one's place in the tile in `ranks`.
#[allow(clippy::too_many_arguments)]
pub fn tile_write<K: SortKey>(
    lane: u32,
    tile: u32,
    st: &TileState<K>,
    p: &BuildParams,
    keys: &mut [K],
    vals: &mut [u32],
    sorted_keys: &mut [K],
    sorted_vals: &mut [u32],
    ranks: &mut [u32],
) {
    let len = tile_len(p, tile);
    let mut m = 0;
    while m < ITEMS {
        let s = lane + m * WORKGROUP;
        if s < len {
            let i = tile * TILE + s;
            let key = *elem(&st.keys, s);
            let val = *elem(&st.vals, *elem(&st.place, s));
            if p.n <= TILE {
                *at_mut(keys, i) = key;
                *at_mut(vals, i) = val;
            } else {
                *at_mut(sorted_keys, i) = key;
                *at_mut(sorted_vals, i) = val;
                *at_mut(ranks, i) = s;
            }
        }
        m += 1;
    }
}

/// The keys a merge lane holds (`lane + m * WORKGROUP` of its tile; past the end, unused) and
/// how many keys of the other tiles go before each.
pub struct Own<K> {
    pub keys: [K; ITEMS as usize],
    pub before: [u32; ITEMS as usize],
}

/// Merge, phase 1: lane loads its keys of sorted tile `tile`.
#[allow(clippy::identity_op, clippy::erasing_op)] // `seq!` starts at 0
pub fn merge_own<K: SortKey>(lane: u32, tile: u32, p: &BuildParams, sorted_keys: &[K]) -> Own<K> {
    let len = tile_len(p, tile);
    let mut own = Own {
        keys: [K::MAX; ITEMS as usize],
        before: [0; ITEMS as usize],
    };
    seq!(M in 0..8 {
        if lane + M * WORKGROUP < len {
            own.keys[M] = *at(sorted_keys, tile * TILE + lane + M * WORKGROUP);
        }
    });
    own
}

/// The tiles merge workgroup `chunk` counts against: `CHUNK` of them from `chunk * CHUNK`
/// (fewer at the end).
pub fn chunk_tiles(p: &BuildParams, chunk: u32) -> (u32, u32) {
    let first = chunk * CHUNK;
    (first, (first + CHUNK).min(p.tiles()))
}

/// Merge, phase 2 (for each tile `u` of the chunk but the workgroup's own): lane loads keys
/// `lane + m * WORKGROUP` of sorted tile `u`.
pub fn merge_load<K: SortKey>(lane: u32, u: u32, st: &mut MergeState<K>, p: &BuildParams, sorted_keys: &[K]) {
    let len = tile_len(p, u);
    let mut m = 0;
    while m < ITEMS {
        let s = lane + m * WORKGROUP;
        if s < len {
            *elem_mut(&mut st.keys, s) = *at(sorted_keys, u * TILE + s);
        }
        m += 1;
    }
}

/// Merge, phase 3 (after a barrier): lane counts the keys of tile `u` that go before each of
/// its own (of tile `tile`): smaller ones, and equal ones where `u < tile`. A binary search of
/// a fixed number of steps, the lane's eight searches interleaved.
#[allow(clippy::identity_op, clippy::erasing_op)] // `seq!` starts at 0
pub fn merge_count<K: SortKey>(u: u32, tile: u32, st: &MergeState<K>, p: &BuildParams, own: &mut Own<K>) {
    let len = tile_len(p, u);
    let equal_before = u < tile;
    let mut pos = [0u32; ITEMS as usize];
    let mut step = TILE;
    while step > 0 {
        seq!(M in 0..8 {
            let next = pos[M] + step;
            if next <= len {
                let key = *elem(&st.keys, next - 1);
                if key < own.keys[M] || equal_before && key == own.keys[M] {
                    pos[M] = next;
                }
            }
        });
        step /= 2;
    }
    seq!(M in 0..8 {
        own.before[M] += pos[M];
    });
}

/// Merge, phase 4: lane adds its keys' counts to their ranks.
#[allow(clippy::identity_op, clippy::erasing_op)] // `seq!` starts at 0
pub fn merge_add<K: SortKey>(lane: u32, tile: u32, p: &BuildParams, own: &Own<K>, ranks: &mut [u32]) {
    let len = tile_len(p, tile);
    seq!(M in 0..8 {
        if lane + M * WORKGROUP < len && own.before[M] != 0 {
            atomic_add_device::<false>(at_mut(ranks, tile * TILE + lane + M * WORKGROUP), own.before[M]);
        }
    });
}

/// Place (one invocation a key, after the merge): writes key `i` of the sorted tiles and its
/// value to its rank, and zeroes the rank.
pub fn place<K: SortKey>(
    i: u32,
    p: &BuildParams,
    sorted_keys: &[K],
    sorted_vals: &[u32],
    ranks: &mut [u32],
    keys: &mut [K],
    vals: &mut [u32],
) {
    if i >= p.n {
        return;
    }
    let r = *at(ranks, i);
    *at_mut(keys, r) = *at(sorted_keys, i);
    *at_mut(vals, r) = *at(sorted_vals, i);
    *at_mut(ranks, i) = 0;
}
