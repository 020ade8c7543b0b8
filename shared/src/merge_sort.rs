//! Stable sort of up to [`max`] (key, primitive) pairs in two dispatches of O(n log n)
//! work, which also compute the Morton codes (the build's Morton stage is the first):
//!
//! 1. [`run_load`], [`run_rank`] (the runs kernel): workgroup `g` computes the codes of
//!    primitives `g * RUN..` (a *run*, one a lane), ranks each against the run's others in
//!    workgroup memory and writes the run sorted, with its primitives, to its place in
//!    bindings 3 and 4; the unsorted codes go to binding 5 (what a captured build copies
//!    out). One run is the whole sort: the host binds the pair the tree kernel reads as 3
//!    and 4 then, else the other pair, which the merge kernel reads.
//! 2. [`merge_load`], [`merge_count`], [`merge_place`] (the merge kernel): workgroup `g`
//!    places run `g`'s keys: each key's place in the whole order is its place in its run
//!    plus, for every other run, the number of that run's keys that go before it, found by
//!    a binary search of the sorted run (an equal key goes before when its run comes
//!    earlier: runs hold primitives in order). The runs are staged in workgroup memory
//!    `BATCH` at a time, the batch's searches interleaved.
//!
//! The order is that of a stable sort by key (ties by primitive), as the radix passes give,
//! so GPU = CPU and every sort of the builder makes the same tree. The count sort it
//! replaces ranked every key against every other (n^2 comparisons, 28 us for 10,000 keys on
//! the H100 against a floor of ~10) in two dispatches after the Morton stage's.
use crate::radix_sort::SortKey;
use crate::sync::{at, at_mut, elem, elem_mut};
use crate::types::{BuildParams, WORKGROUP};
use seq_macro::seq;

/// Builds of at most `max(key_bits)` keys sort by merging, above by the radix passes
/// (`crate::radix_sort`). H100 (bench/NOTES.md, session 37), runs and merge kernels against
/// the radix passes' Morton stage and passes, us: 30-bit keys, 1,000 14.3 / 43.3, 10,000
/// 20.6 / 51.9, 32,000 36.2 / 55.0, 48,000 75.2 / 55.9; 63-bit 32,000 55.3 / 137.4, 48,000
/// 140.2 / 134.5 (past 128 runs the merge kernel's workgroups outnumber the SMs).
pub const fn max(key_bits: u32) -> u32 {
    let _ = key_bits;
    32768
}

/// Keys a run holds: one a lane of the runs kernel.
pub const RUN: u32 = WORKGROUP;
/// Steps of a binary search of a run: `RUN / 2^k` for `k` in `0..SEARCH_STEPS`.
const SEARCH_STEPS: u32 = RUN.trailing_zeros() + 1;
const _: () = assert!(RUN.is_power_of_two());

/// Workgroup memory of the runs kernel: the run's keys.
pub struct RunState<K> {
    pub keys: [K; RUN as usize],
}

/// Runs kernel, phase 1: lane stages the code `key` of its primitive `group * RUN + lane`
/// (computed by the caller: `morton::code30` or `code63`) in workgroup memory, and in
/// `codes` (its place there); lanes past the last primitive stage a key above every code.
pub fn run_load<K: SortKey>(lane: u32, group: u32, key: K, st: &mut RunState<K>, p: &BuildParams, codes: &mut [K]) {
    let i = group * RUN + lane;
    let staged = if i < p.n {
        *at_mut(codes, i) = key;
        key
    } else {
        K::ABOVE
    };
    *elem_mut(&mut st.keys, lane) = staged;
}

/// Keys a ranking loop's step compares, written out (`seq!`: rust-gpu emits no unroll hints,
/// and a step per key waits out a workgroup-memory load each).
const STEP: u32 = 8;
const _: () = assert!(RUN.is_multiple_of(STEP) && STEP == 8);

/// Runs kernel, phase 2 (after a barrier): lane's key goes to its place in the run (the keys
/// below it, and the equal ones of lanes before it), in `keys` and `vals` (its primitive).
#[allow(clippy::identity_op)] // `seq!` starts at 0
pub fn run_rank<K: SortKey>(
    lane: u32,
    group: u32,
    st: &RunState<K>,
    p: &BuildParams,
    keys: &mut [K],
    vals: &mut [u32],
) {
    let base = group * RUN;
    let i = base + lane;
    if i >= p.n {
        return;
    }
    let own = *elem(&st.keys, lane);
    // The padding (above every code) never counts.
    let end = (p.n - base).min(RUN).next_multiple_of(STEP);
    let mut rank = 0;
    let mut j = 0;
    while j < end {
        seq!(T in 0..8 {
            let key = *elem(&st.keys, j + T);
            rank += u32::from((key < own) | (key == own) & (j + T < lane));
        });
        j += STEP;
    }
    *at_mut(keys, base + rank) = own;
    *at_mut(vals, base + rank) = i;
}

/// Runs staged at once in the merge kernel's workgroup memory.
pub const BATCH: u32 = 16;

/// Workgroup memory of the merge kernel: a batch of runs, each padded with keys above
/// every code to `RUN`.
pub struct MergeState<K> {
    pub keys: [K; (BATCH * RUN) as usize],
}

/// Merge kernel (workgroup `g` places run `g`'s keys), before its batches: lane's key (above
/// every code past the last).
pub fn merge_key<K: SortKey>(lane: u32, group: u32, p: &BuildParams, keys: &[K]) -> K {
    let i = group * RUN + lane;
    if i < p.n {
        *at(keys, i)
    } else {
        K::ABOVE
    }
}

/// Merge kernel, a batch's phase 1: lane stages key `lane` of runs `first..first + BATCH`
/// (of the sorted runs in `keys`) in workgroup memory.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn merge_load<K: SortKey>(lane: u32, first: u32, st: &mut MergeState<K>, p: &BuildParams, keys: &[K]) {
    seq!(B in 0..16 {
        let j = (first + B) * RUN + lane;
        *elem_mut(&mut st.keys, B * RUN + lane) = if j < p.n { *at(keys, j) } else { K::ABOVE };
    });
}

/// Merge kernel, a batch's phase 2 (after a barrier): how many keys of the batch's runs
/// (all but the workgroup's own) go before `key`, each run's found by a binary search of its
/// staged keys, the sixteen searches interleaved. An equal key goes before where its run
/// comes earlier; the padding never does.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn merge_count<K: SortKey>(group: u32, first: u32, key: K, st: &MergeState<K>) -> u32 {
    // Per run: whether an equal key of it goes before (`u32`: rust-gpu makes no arrays of
    // `bool`), and how many of its keys are found to (binary lifting: grows by `step`
    // while the key at `below + step - 1` goes before).
    let mut earlier = [0u32; BATCH as usize];
    let mut below = [0u32; BATCH as usize];
    seq!(B in 0..16 {
        earlier[B] = u32::from(first + B < group);
    });
    let mut step = RUN;
    let mut k = 0;
    while k < SEARCH_STEPS {
        seq!(B in 0..16 {
            let probe = below[B] + step;
            let other = *elem(&st.keys, B * RUN + probe.min(RUN) - 1);
            if (probe <= RUN) & ((other < key) | (earlier[B] != 0) & (other == key)) {
                below[B] = probe;
            }
        });
        step /= 2;
        k += 1;
    }
    let mut count = 0;
    seq!(B in 0..16 {
        if first + B != group {
            count += below[B];
        }
    });
    count
}

/// Merge kernel, last: lane's key (at `place` in the whole order: its place in its run
/// plus every [`merge_count`]) and its primitive to `keys_out` and `vals_out`.
#[allow(clippy::too_many_arguments)]
pub fn merge_place<K: SortKey>(
    lane: u32,
    group: u32,
    place: u32,
    p: &BuildParams,
    key: K,
    vals: &[u32],
    keys_out: &mut [K],
    vals_out: &mut [u32],
) {
    let i = group * RUN + lane;
    if i < p.n {
        *at_mut(keys_out, place) = key;
        *at_mut(vals_out, place) = *at(vals, i);
    }
}

const _: () = assert!(BATCH == 16);

#[cfg(test)]
mod tests {
    use super::*;

    /// The two kernels run as the CPU executor runs them, against a stable sort.
    fn sorted(keys: &[u32]) -> (Vec<u32>, Vec<u32>) {
        let n = keys.len() as u32;
        let p = BuildParams {
            n_tris: n,
            n,
            ..Default::default()
        };
        let (mut codes, mut run_keys, mut run_vals) = (vec![0; keys.len()], vec![0; keys.len()], vec![0; keys.len()]);
        for g in 0..n.div_ceil(RUN) {
            let mut st = RunState {
                keys: [0u32; RUN as usize],
            };
            for l in 0..RUN {
                let i = g * RUN + l;
                let key = if i < n { keys[i as usize] } else { 0 };
                run_load(l, g, key, &mut st, &p, &mut codes);
            }
            for l in 0..RUN {
                run_rank(l, g, &st, &p, &mut run_keys, &mut run_vals);
            }
        }
        assert_eq!(codes, keys);
        let (mut out_keys, mut out_vals) = (vec![u32::MAX; keys.len()], vec![u32::MAX; keys.len()]);
        let runs = n.div_ceil(RUN);
        for g in 0..runs {
            let mut st = MergeState {
                keys: [0u32; (BATCH * RUN) as usize],
            };
            let own: Vec<u32> = (0..RUN).map(|l| merge_key(l, g, &p, &run_keys)).collect();
            let mut place: Vec<u32> = (0..RUN).collect();
            let mut first = 0;
            while first < runs {
                (0..RUN).for_each(|l| merge_load(l, first, &mut st, &p, &run_keys));
                (0..RUN).for_each(|l| place[l as usize] += merge_count(g, first, own[l as usize], &st));
                first += BATCH;
            }
            for l in 0..RUN {
                let (k, at) = (own[l as usize], place[l as usize]);
                merge_place(l, g, at, &p, k, &run_vals, &mut out_keys, &mut out_vals);
            }
        }
        (out_keys, out_vals)
    }

    #[test]
    fn the_merge_sorts_stably_at_every_edge_of_a_run() {
        for n in [1usize, 2, 7, 255, 256, 257, 511, 512, 513, 1000, 1023, 1024, 1025, 3000] {
            // Few distinct keys (long runs of ties across runs), and all distinct.
            for distinct in [3u32, 1 << 30] {
                let keys: Vec<u32> = (0..n as u32)
                    .map(|i| (i.wrapping_mul(2_654_435_761) >> 2) % distinct)
                    .collect();
                let mut want: Vec<(u32, u32)> = keys.iter().copied().zip(0..).collect();
                want.sort_by_key(|&(k, _)| k);
                let (k, v) = sorted(&keys);
                assert_eq!(
                    k,
                    want.iter().map(|w| w.0).collect::<Vec<_>>(),
                    "{n} keys, {distinct} distinct"
                );
                assert_eq!(
                    v,
                    want.iter().map(|w| w.1).collect::<Vec<_>>(),
                    "{n} keys, {distinct} distinct"
                );
            }
        }
    }
}
