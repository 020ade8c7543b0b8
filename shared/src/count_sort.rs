//! Stable sort of a few thousand (key, primitive) pairs by counting: every key's place is
//! the number of keys that go before it (smaller, or equal and earlier), counted by many
//! workgroups at once, then each key is written there. Two dispatches whatever the key
//! width, where the radix passes take `passes(bits)` (six for 30-bit keys, fourteen for
//! 63-bit), each a chain of workgroup phases and global round trips that costs the same
//! however few the keys: at these sizes a build is a chain of latencies (bench/NOTES.md,
//! session 35), and the n^2 comparisons are cheaper than four more links in it.
//!
//! 1. [`chunk_load`], [`chunk_count`]: workgroup `(s, c)` ranks the keys of span `s`
//!    (`SPAN` consecutive keys, `OWN` a lane) against the keys of chunk `c` (`CHUNK`
//!    consecutive keys), staged in workgroup memory, and adds each count to the key's rank
//!    with a device atomic (the ranks live in the refit's visit counters, which the Morton
//!    stage zeroes first: between builds some hold a wide collapse's counts or an earlier
//!    build's leaf ranges, see [`clear_rank`]). Integer adds commute: the ranks are the same
//!    in any order of the workgroups, so GPU = CPU bit for bit.
//! 2. [`place`]: key `i` and its value go to place `rank(i)` of the other buffers.
//!
//! The keys are read from and written to the buffer pair the radix passes would end in
//! reversed (the Morton stage writes them to the second pair): the output is in the first
//! pair, where the tree kernel reads it.
use crate::radix_sort::SortKey;
use crate::sync::{self, at, at_mut, elem, elem_mut};
use crate::types::{BuildParams, WORKGROUP};
use seq_macro::seq;

/// Keys a lane ranks.
pub const OWN: u32 = 4;
/// Keys a workgroup ranks: a span.
pub const SPAN: u32 = OWN * WORKGROUP;
/// Keys a workgroup ranks them against, one staged a lane: a chunk (inside one span).
pub const CHUNK: u32 = WORKGROUP;
const _: () = assert!(SPAN.is_multiple_of(CHUNK) && OWN == 4);

/// Builds of more than `RANK_MAX` and at most `max(key_bits)` keys sort by counting (at most
/// `RANK_MAX`: one workgroup's rank sort, `radix_sort::rank`; above: the radix passes).
/// Measured on the H100 (bench/NOTES.md, session 36): the counts cost n^2 comparisons
/// spread over the GPU (30-bit keys: 300 to 4,000 keys 16 us, 10,000 28, 16,000 49), the
/// radix passes ~46 us for 30-bit keys (six) and ~120 us for 63-bit ones (fourteen) at any
/// of these sizes; 63-bit counts cost 36 us at 10,000 keys, 62 at 16,000, 118 at 24,000.
pub const fn max(key_bits: u32) -> u32 {
    if key_bits <= 32 {
        12288
    } else {
        20480
    }
}

/// Workgroup memory of the counting stage: the chunk ranked against.
pub struct ChunkState<K> {
    pub keys: [K; CHUNK as usize],
}

/// The counting stage's grid: `(spans, chunks)` of `n` keys, a workgroup for each pair.
pub fn grid(n: u32) -> (u32, u32) {
    (n.div_ceil(SPAN), n.div_ceil(CHUNK))
}

/// Zeroes key `i`'s rank, run by the Morton stage for every key before the counting stage.
pub fn clear_rank(i: u32, p: &BuildParams, ranks: &mut [u32]) {
    if i < p.n {
        *at_mut(ranks, i) = 0;
    }
}

/// Counting stage, phase 1: lane stages its key of chunk `c` in workgroup memory; places
/// past the last key get a key above every Morton code (never before any), so that the
/// counting loops run whole steps of `STEP`.
pub fn chunk_load<K: SortKey>(lane: u32, c: u32, st: &mut ChunkState<K>, p: &BuildParams, keys: &[K]) {
    let j = c * CHUNK + lane;
    *elem_mut(&mut st.keys, lane) = if j < p.n { *at(keys, j) } else { K::ABOVE };
}

/// Keys a counting loop's step compares, written out (`seq!`: rust-gpu emits no unroll
/// hints, and a loop step per key waits out a workgroup-memory load each).
const STEP: u32 = 8;
const _: () = assert!(CHUNK.is_multiple_of(STEP) && STEP == 8);

/// Counting stage, phase 2 (after a barrier): lane's keys of span `s` (`s * SPAN + lane`
/// and every `WORKGROUP` after it) count the keys of chunk `c` (in `st`) that go before them,
/// and add the counts to their ranks in `ranks`.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn chunk_count<K: SortKey>(
    lane: u32,
    s: u32,
    c: u32,
    st: &ChunkState<K>,
    p: &BuildParams,
    keys: &[K],
    ranks: &mut [u32],
) {
    let first = s * SPAN + lane;
    if first >= p.n {
        return;
    }
    let mut own = [K::ABOVE; OWN as usize];
    seq!(O in 0..4 {
        let i = first + O * WORKGROUP;
        if i < p.n {
            own[O] = *at(keys, i);
        }
    });
    let end = (p.n - c * CHUNK).min(CHUNK).next_multiple_of(STEP);
    // An equal key goes before where it comes earlier: every one of a chunk before the span,
    // none of one after, those before own key `i` (local place below `i - c * CHUNK`) in a
    // chunk of the span. The three loops differ only in that test, kept out of the first
    // two; every test is branch-free (`&`, `|` on the comparisons).
    let mut count = [0u32; OWN as usize];
    let mut j = 0;
    let (span_start, chunk_start) = (s * SPAN, c * CHUNK);
    if chunk_start + CHUNK <= span_start {
        while j < end {
            seq!(T in 0..8 {
                let key = *elem(&st.keys, j + T);
                seq!(O in 0..4 {
                    count[O] += u32::from(key <= own[O]);
                });
            });
            j += STEP;
        }
    } else if chunk_start >= span_start + SPAN {
        while j < end {
            seq!(T in 0..8 {
                let key = *elem(&st.keys, j + T);
                seq!(O in 0..4 {
                    count[O] += u32::from(key < own[O]);
                });
            });
            j += STEP;
        }
    } else {
        let mut below = [0u32; OWN as usize];
        seq!(O in 0..4 {
            let i = first + O * WORKGROUP;
            // Written out: rust-gpu has no `saturating_sub`.
            #[allow(clippy::implicit_saturating_sub)]
            let b = if i > chunk_start { i - chunk_start } else { 0 };
            below[O] = b;
        });
        while j < end {
            seq!(T in 0..8 {
                let key = *elem(&st.keys, j + T);
                seq!(O in 0..4 {
                    count[O] += u32::from((key < own[O]) | (key == own[O]) & (j + T < below[O]));
                });
            });
            j += STEP;
        }
    }
    seq!(O in 0..4 {
        let i = first + O * WORKGROUP;
        if i < p.n && count[O] > 0 {
            sync::atomic_add_device::<false>(at_mut(ranks, i), count[O]);
        }
    });
}

/// Placing stage: key `i` and its value to their rank in `keys_out` and `vals_out` (the
/// counters are zeroed by the next build's Morton stage, or its tree kernel, not here).
pub fn place<K: SortKey>(
    i: u32,
    p: &BuildParams,
    keys: &[K],
    vals: &[u32],
    ranks: &[u32],
    keys_out: &mut [K],
    vals_out: &mut [u32],
) {
    if i >= p.n {
        return;
    }
    let r = *at(ranks, i);
    *at_mut(keys_out, r) = *at(keys, i);
    *at_mut(vals_out, r) = *at(vals, i);
}
