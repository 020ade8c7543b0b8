//! Parallel construction of a binary radix tree over sorted Morton codes (Karras 2012,
//! "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees", sec. 4).
//!
//! Invocation `i` builds internal node `i` (for `i < n - 1`; the refit writes the leaves).
//! Equal codes are told apart by their index: `delta(i, j)` is then `BITS + clz(i ^ j)`
//! (Karras, sec. 4).
//! Node layout: internal nodes `0..n-1`, leaves `n-1..2n-1`, root 0; see
//! [`crate::types::Node`].
use crate::radix_sort::SortKey;
use crate::sync::{at, at_mut};
use crate::types::{BuildParams, INVALID, WORKGROUP};
use seq_macro::seq;
use spirv_std::glam::UVec4;

/// Length of the common prefix of keys `i` and `j`; -1 when `j` is outside `0..n`.
pub fn delta<K: SortKey>(keys: &[K], n: u32, i: u32, j: i32) -> i32 {
    if j < 0 || j >= n as i32 {
        return -1;
    }
    let (a, b) = (*at(keys, i), *at(keys, j as u32));
    if a == b {
        (K::BITS + (i ^ j as u32).leading_zeros()) as i32
    } else {
        a.clz_xor(b) as i32
    }
}

/// The range `[first, last]` of leaves under internal node `i`, and its split `gamma`:
/// the left child covers `[first, gamma]`, the right `[gamma + 1, last]`.
pub fn range_and_split<K: SortKey>(keys: &[K], n: u32, i: u32) -> (u32, u32, u32) {
    let ii = i as i32;
    // Direction of the range: towards the neighbour sharing the longer prefix.
    let d: i32 = if delta(keys, n, i, ii + 1) > delta(keys, n, i, ii - 1) {
        1
    } else {
        -1
    };
    let d_min = delta(keys, n, i, ii - d);
    // Upper bound on the range length (a power of two), then binary search for the other
    // end. The bound grows 8x a step, not Karras's 2x: the top nodes' dependent key loads
    // are the kernel's critical path, and this takes ~log2(range) / 1.5 fewer for a few more
    // in the binary search (H100: tree stage bunny 15.6 -> 14.2 us, 16M 662 -> 627; 4x:
    // 14.8 / 631).
    let mut l_max: i32 = 2;
    while delta(keys, n, i, ii + l_max * d) > d_min {
        l_max *= 8;
    }
    let mut l: i32 = 0;
    let mut t = l_max / 2;
    while t >= 1 {
        if delta(keys, n, i, ii + (l + t) * d) > d_min {
            l += t;
        }
        t /= 2;
    }
    let j = ii + l * d;
    // Binary search for the split: the last index sharing more than d_node bits with i.
    let d_node = delta(keys, n, i, j);
    let mut s: i32 = 0;
    let mut div: i32 = 2;
    loop {
        let t = (l + div - 1) / div;
        if delta(keys, n, i, ii + (s + t) * d) > d_node {
            s += t;
        }
        if t <= 1 {
            break;
        }
        div *= 2;
    }
    let gamma = ii + s * d + if d < 0 { -1 } else { 0 };
    (ii.min(j) as u32, ii.max(j) as u32, gamma as u32)
}

/// Keys (as 32-bit words) up to which the tree kernel loads every key before its searches
/// ([`warm`]): 64 KB, a quarter of an H100 or H200 SM's L1 cache and shared memory.
pub const WARM_WORDS: u32 = 16384;
/// Keys from which it does: below, the searches are too short to repay the loads' round trip
/// (H200, tree stage: 37 primitives 6.2 -> 7.6 us with them, 1,000 9.1 -> 8.9).
pub const WARM_FROM: u32 = 1024;

/// Before [`build`] on a GPU, for builds of [`WARM_FROM`] keys up to [`WARM_WORDS`] key
/// words: the lane loads every `WORKGROUP`-th key from its own, so that its workgroup's
/// searches (whose dependent loads are the kernel's critical path) find the keys in the SM's
/// L1 cache rather than in L2 (H200, tree stage: Suzanne 11.4 -> 9.6 us, 10,000 random 11.7
/// -> 10.7; the top level of 10,000 instances built plain 50.2 -> 48.8). Returns whether any
/// key loaded has its top bit set, which no Morton code has (the kernel returns then, so the
/// loads are used and not removed). No effect on the tree: the CPU executor does not run it.
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn warm<K: SortKey>(i: u32, p: &BuildParams, keys: &[K]) -> bool {
    if p.n < WARM_FROM || p.n * K::WORDS > WARM_WORDS {
        return false;
    }
    let lane = i % WORKGROUP;
    let mut any = 0u32;
    seq!(T in 0..64 {
        let j = lane + T * WORKGROUP;
        any |= if j < p.n { at(keys, j).word(K::WORDS - 1) } else { 0 };
    });
    any >> 31 != 0
}
const _: () = assert!(WARM_WORDS / WORKGROUP == 64);

/// Builds internal node `i`, records its children's parents, clears its visit counter and
/// records the far end of its leaf range (`i` is one end) in `visits[n + i]` for the refit.
/// The leaves are written by the refit (see [`crate::refit::fit`]), which gathers each
/// leaf's primitive as it starts its climb: written here, they would cross memory twice more.
/// `node_words` is the node buffer as 16-byte words (node `k`: words `2 k`, `2 k + 1`), so
/// that a node is two vector stores (NVIDIA's compiler stores a `Node` value as narrow words).
pub fn build<K: SortKey>(
    i: u32,
    p: &BuildParams,
    keys: &[K],
    node_words: &mut [UVec4],
    parents: &mut [u32],
    visits: &mut [u32],
) {
    let n = p.n;
    if i >= n {
        return;
    }
    if i == 0 {
        parents[0] = INVALID;
    }
    if i + 1 < n {
        let (first, last, gamma) = range_and_split(keys, n, i);
        let left = if first == gamma { n - 1 + gamma } else { gamma };
        let right = if last == gamma + 1 { n + gamma } else { gamma + 1 };
        let (inf, neg) = (f32::INFINITY.to_bits(), f32::NEG_INFINITY.to_bits());
        *at_mut(node_words, 2 * i) = UVec4::new(inf, inf, inf, left);
        *at_mut(node_words, 2 * i + 1) = UVec4::new(neg, neg, neg, right);
        *at_mut(parents, left) = i;
        *at_mut(parents, right) = i;
        *at_mut(visits, i) = 0;
        *at_mut(visits, n + i) = if first == i { last } else { first };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`warm`] finds no top bit in the largest Morton codes of either width (so the tree
    /// kernel never returns before [`build`]), at the sizes where it loads keys.
    #[test]
    fn warm_keys_never_stop_the_tree_kernel() {
        let p = |n| BuildParams {
            n_tris: n,
            n,
            shift: 0,
            passes: 0,
        };
        let k30 = [(1u32 << 30) - 1; WARM_WORDS as usize];
        let k63 = [(1u64 << 63) - 1; (WARM_WORDS / 2) as usize];
        for n in [WARM_FROM, 5000, WARM_WORDS / 2] {
            for i in [0, 1, WORKGROUP - 1, WORKGROUP, n - 1] {
                assert!(!warm(i, &p(n), &k30), "30-bit codes, n {n}, lane {i}");
                assert!(!warm(i, &p(n), &k63), "63-bit codes, n {n}, lane {i}");
            }
        }
        // The test it relies on: a key with its top bit set is found.
        let mut bad = k30;
        bad[WORKGROUP as usize + 3] = 1 << 31;
        assert!(warm(3, &p(WARM_FROM), &bad));
    }
}
