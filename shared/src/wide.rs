//! A 4-wide BVH collapsed from the binary Karras tree on every build, deterministically, in
//! four dispatches after the fit (the wide BVH of Ylitie, Karras & Laine 2017, "Efficient
//! Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", without their
//! quantisation: child boxes are the binary nodes' exact `f32` boxes).
//!
//! **Which binary nodes become wide nodes.** If binary node `p` roots a wide node, its
//! children are its *frontier*: its two children, each either kept or, if `p` absorbs it,
//! replaced by its own frontier. Absorbing a child opens it, as the greedy top-down collapse
//! opens the child of largest area (tinybvh's `BVH4::ConvertFrom`); here the frontier sizes
//! are decided bottom-up, by a climb from the leaves like the refit's (the second arrival at
//! a node decides it): a node absorbs both children when their frontiers fit in four slots
//! together, else the larger subtree's (by primitive count: an exact integer, so every
//! backend decides alike) if it fits beside the other child, else the smaller's, else
//! neither. A node's frontier then depends on its subtree only, and a node roots a wide node
//! exactly when its parent did not absorb it (an absorbed node's frontier is part of its
//! parent's, whoever roots that), so every node knows at once, with no top-down pass.
//! Subtrees of at most [`LEAF_MAX`] primitives are leaves and never absorbed: a range of the
//! sorted order (contiguous, since every subtree of a Karras tree is a key range), so a leaf
//! names its primitives as `order[first..first + count]`. (A first collapse cut the Karras
//! prefix lengths into buckets of two, a 4-ary radix tree decided per node with no climb;
//! 9,121 of the bunny's 15,199 wide nodes then had two children, and it traced 1.5-3x slower
//! than the binary tree on the H100.)
//!
//! **Where each goes.** Wide nodes are numbered in the order of their binary roots, so the
//! numbering is a prefix sum of the root flags, exact on every backend:
//!
//! ```text
//! climb   (per leaf)                          frontier size and absorbed children -> info[]
//! mark    (a workgroup per 256 binary nodes)  root bit of each node -> bits[], the count
//!         before each 32-node word within the group -> word_before[], the group's -> totals[]
//! scan    (one workgroup of 64)               exclusive prefix of the group totals -> before[]
//! write   (per binary node)                   a root writes its wide node at
//!         before[i / 256] + word_before[i / 32] + popcount(bits[i / 32] below bit i % 32)
//! ```
//!
//! The wide nodes' count goes to a word of the scratch buffer ([`Scratch::count`]).
use crate::sync::{
    at, at_mut, atomic_add_device, atomic_load_u32, atomic_store_u32, elem, elem_mut, workgroup_or_ordered,
};
use crate::types::{BuildParams, Node, INVALID, WORKGROUP};
use bytemuck::{Pod, Zeroable};
use core::mem::size_of;

/// Children of a wide node at most.
pub const WIDTH: usize = 4;
/// Primitives of a leaf at most (two bits of a child word hold `count - 1`).
pub const LEAF_MAX: u32 = 2;

/// A child word's leaf bit: the word is `LEAF | (count - 1) << 29 | first` (a leaf of
/// `count` primitives at sorted positions `first..first + count`; a leaf of one names its
/// primitive itself, saving the traversal a dependent load); without it, a wide node's
/// index. [`INVALID`] marks an empty slot, whose box is empty.
///
/// ```text
/// bit  31   30 29      28 ........ 0
///      leaf count - 1  first sorted position (< 2^29)
/// ```
pub const LEAF: u32 = 1 << 31;
const COUNT_SHIFT: u32 = 29;
const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;
/// Primitives a wide BVH can hold: leaves name sorted positions with 29 bits.
pub const MAX_PRIMITIVES: u32 = FIRST_MASK;

/// A wide node (128 bytes): the boxes of up to four children, axis by axis (`lo[axis][k]`),
/// and the children's words (see [`LEAF`]). Empty slots have the box `[+inf, +inf]` on every
/// axis, which both slab tests miss (their entry distance is `+inf`), so the traversal needs
/// no test of its own for them.
#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, Pod, Zeroable)]
pub struct WideNode {
    pub lo: [[f32; 4]; 3],
    pub hi: [[f32; 4]; 3],
    pub child: [u32; 4],
    pub _pad: [u32; 4],
}
const _: () = assert!(size_of::<WideNode>() == 128);

impl WideNode {
    /// A node with every slot empty.
    pub const EMPTY: WideNode = WideNode {
        lo: [[f32::INFINITY; 4]; 3],
        hi: [[f32::INFINITY; 4]; 3],
        child: [INVALID; 4],
        _pad: [0; 4],
    };

    /// Child `k`'s box `(lo, hi)`.
    pub fn child_box(&self, k: usize) -> ([f32; 3], [f32; 3]) {
        (
            [self.lo[0][k], self.lo[1][k], self.lo[2][k]],
            [self.hi[0][k], self.hi[1][k], self.hi[2][k]],
        )
    }

    /// Puts child `word` with box `b` in slot `k` (constant indices: no bounds checks).
    fn set(&mut self, k: u32, word: u32, b: &Node) {
        match k {
            0 => self.put::<0>(word, b),
            1 => self.put::<1>(word, b),
            2 => self.put::<2>(word, b),
            _ => self.put::<3>(word, b),
        }
    }

    fn put<const K: usize>(&mut self, word: u32, b: &Node) {
        self.child[K] = word;
        self.lo[0][K] = b.min[0];
        self.lo[1][K] = b.min[1];
        self.lo[2][K] = b.min[2];
        self.hi[0][K] = b.max[0];
        self.hi[1][K] = b.max[1];
        self.hi[2][K] = b.max[2];
    }
}

/// The child word of a leaf of `count` (1..=[`LEAF_MAX`]) primitives from sorted position
/// `first`.
pub fn leaf_word(first: u32, count: u32) -> u32 {
    LEAF | (count - 1) << COUNT_SHIFT | first
}

/// `(first, count)` of a leaf's child word.
pub fn leaf_range(word: u32) -> (u32, u32) {
    (word & FIRST_MASK, ((word >> COUNT_SHIFT) & 3) + 1)
}

/// Where the collapse keeps its words in the scratch buffer, for `n` primitives: one slot
/// per binary internal node (one for `n <= 1`), root bits and per-word counts, per-group
/// totals and their prefix, the wide node count, and each node's climb result.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Scratch {
    pub slots: u32,
    pub words: u32,
    pub groups: u32,
}

impl Scratch {
    pub fn new(n: u32) -> Scratch {
        let slots = n.max(2) - 1;
        Scratch {
            slots,
            words: slots.div_ceil(32),
            groups: slots.div_ceil(WORKGROUP),
        }
    }
    fn bits(&self) -> u32 {
        0
    }
    fn word_before(&self) -> u32 {
        self.words
    }
    fn totals(&self) -> u32 {
        2 * self.words
    }
    fn before(&self) -> u32 {
        2 * self.words + self.groups
    }
    /// Index of the word holding the number of wide nodes.
    pub fn count(&self) -> u32 {
        2 * self.words + 2 * self.groups
    }
    /// Where node `i`'s climb result is (see [`climb`]).
    pub fn info(&self) -> u32 {
        self.count() + 1
    }
    /// Words of scratch the collapse needs.
    pub fn total_words(&self) -> u32 {
        self.info() + self.slots
    }
}

/// `[first, last]`: the sorted range under internal node `i` (`i` is one end; the far end is
/// `ends[n + i]`, recorded by [`crate::karras::build`]).
fn range(i: u32, n: u32, ends: &[u32]) -> (u32, u32) {
    let e = *at(ends, n + i);
    (i.min(e), i.max(e))
}

/// Primitives under binary node `c` (a leaf or an internal node).
fn size(c: u32, n: u32, ends: &[u32]) -> u32 {
    if c >= n - 1 {
        1
    } else {
        let (first, last) = range(c, n, ends);
        last - first + 1
    }
}

/// A climb result: frontier size in bits 0..3, the left child absorbed in bit 3, the right
/// in bit 4.
const ABSORB_A: u32 = 1 << 3;
const ABSORB_B: u32 = 1 << 4;

/// Child `c`'s frontier size, and whether it can be absorbed (an internal node of more
/// than [`LEAF_MAX`] primitives), from its climb result.
fn frontier(c: u32, n: u32, ends: &[u32], info: &[u32], s: &Scratch) -> (u32, bool) {
    if size(c, n, ends) <= LEAF_MAX {
        (1, false)
    } else {
        (atomic_load_u32(at(info, s.info() + c)) & 7, true)
    }
}

/// The climb result of internal node `p` (of more than [`LEAF_MAX`] primitives), from its
/// children's (see the module's header).
fn decide(p: u32, n: u32, nodes: &[Node], ends: &[u32], info: &[u32], s: &Scratch) -> u32 {
    let m = at(nodes, p);
    let (a, b) = (m.a, m.b);
    let (ga, absorbs_a) = frontier(a, n, ends, info, s);
    let (gb, absorbs_b) = frontier(b, n, ends, info, s);
    let fits = WIDTH as u32;
    if absorbs_a && absorbs_b && ga + gb <= fits {
        return (ga + gb) | ABSORB_A | ABSORB_B;
    }
    // The larger subtree first (ties: the left one).
    let a_first = size(a, n, ends) >= size(b, n, ends);
    let (g1, ok1, bit1, g2, ok2, bit2) = if a_first {
        (ga, absorbs_a, ABSORB_A, gb, absorbs_b, ABSORB_B)
    } else {
        (gb, absorbs_b, ABSORB_B, ga, absorbs_a, ABSORB_A)
    };
    if ok1 && g1 < fits {
        (g1 + 1) | bit1
    } else if ok2 && g2 < fits {
        (g2 + 1) | bit2
    } else {
        2
    }
}

/// Per binary leaf `k` (`climb`): climbs from the leaf's parent; at each internal node the
/// first arrival stops and the second decides the node (its children are decided by then)
/// and goes on. `visits` holds the counters (`0..n-1`, zero from the tree kernel; the fit
/// leaves them so) and the node ranges' far ends (`n..2n-1`). `ORDERED` selects the
/// acquire-release counter that real GPUs need, as in [`crate::refit::refit`] (lavapipe runs
/// the relaxed variant).
pub fn climb<const ORDERED: bool>(
    k: u32,
    p: &BuildParams,
    nodes: &[Node],
    parents: &[u32],
    visits: &mut [u32],
    scratch: &mut [u32],
) {
    let n = p.n;
    if n < 2 || k >= n {
        return;
    }
    let s = Scratch::new(n);
    let mut node = *at(parents, n - 1 + k);
    loop {
        if atomic_add_device::<ORDERED>(at_mut(visits, node), 1) == 0 {
            return;
        }
        if size(node, n, visits) > LEAF_MAX {
            let v = decide(node, n, nodes, visits, scratch, &s);
            atomic_store_u32(at_mut(scratch, s.info() + node), v);
        }
        if node == 0 {
            return;
        }
        node = *at(parents, node);
    }
}

/// Whether binary internal node `i` roots a wide node: the root does; otherwise a node of
/// more than [`LEAF_MAX`] primitives that its parent did not absorb.
pub fn is_root(i: u32, n: u32, nodes: &[Node], parents: &[u32], ends: &[u32], scratch: &[u32]) -> bool {
    if i == 0 {
        return true;
    }
    if size(i, n, ends) <= LEAF_MAX {
        return false;
    }
    let p = *at(parents, i);
    let bit = if at(nodes, p).a == i { ABSORB_A } else { ABSORB_B };
    *at(scratch, Scratch::new(n).info() + p) & bit == 0
}

/// Workgroup memory of [`mark`]: the group's 8 root-bit words and their counts.
pub struct MarkState {
    pub bits: [u32; 8],
    pub counts: [u32; 8],
}

/// Phase 1 of `mark`: clears the group's words.
pub fn mark_clear(lane: u32, st: &mut MarkState) {
    if lane < 8 {
        *elem_mut(&mut st.bits, lane) = 0;
    }
}

/// Phase 2 of `mark`: binary node `WORKGROUP * group + lane` sets its root bit.
#[allow(clippy::too_many_arguments)]
pub fn mark(
    lane: u32,
    group: u32,
    st: &mut MarkState,
    p: &BuildParams,
    nodes: &[Node],
    parents: &[u32],
    ends: &[u32],
    scratch: &[u32],
) {
    let i = group * WORKGROUP + lane;
    let internal = p.n.max(1) - 1;
    if (i < internal && is_root(i, p.n, nodes, parents, ends, scratch)) || i == 0 {
        workgroup_or_ordered::<false>(elem_mut(&mut st.bits, lane / 32), 1 << (lane % 32));
    }
}

/// Phase 3 of `mark`: lanes 0..8 store their word and its count.
pub fn mark_words(lane: u32, group: u32, st: &mut MarkState, p: &BuildParams, scratch: &mut [u32]) {
    let s = Scratch::new(p.n);
    let w = group * 8 + lane;
    if lane < 8 {
        let bits = *elem(&st.bits, lane);
        *elem_mut(&mut st.counts, lane) = bits.count_ones();
        if w < s.words {
            *at_mut(scratch, s.bits() + w) = bits;
        }
    }
}

/// Phase 4 of `mark`: lanes 0..8 store the count of roots before their word in the group,
/// lane 0 the group's total.
pub fn mark_counts(lane: u32, group: u32, st: &MarkState, p: &BuildParams, scratch: &mut [u32]) {
    let s = Scratch::new(p.n);
    let w = group * 8 + lane;
    if lane < 8 {
        let mut before = 0;
        let mut k = 0;
        while k < lane {
            before += *elem(&st.counts, k);
            k += 1;
        }
        if w < s.words {
            *at_mut(scratch, s.word_before() + w) = before;
        }
        if lane == 0 {
            let mut total = 0;
            let mut k = 0;
            while k < 8 {
                total += *elem(&st.counts, k);
                k += 1;
            }
            *at_mut(scratch, s.totals() + group) = total;
        }
    }
}

/// Invocations of the `scan` kernel. Debian's validation layer counts the workgroup memory
/// of every entry point of the module against lavapipe's 32 KB, and the module left 536 bytes:
/// a block scan of 256 lanes (1 KB) did not fit, 64 lanes' sums do.
pub const SCAN_LANES: u32 = 64;

/// Workgroup memory of `scan`: each lane's sum of its run of group totals.
pub struct ScanState {
    pub sums: [u32; SCAN_LANES as usize],
}

/// The group totals lane `lane` of `scan` sums: a run of `ceil(groups / SCAN_LANES)`.
fn lane_run(lane: u32, s: &Scratch) -> (u32, u32) {
    let run = s.groups.div_ceil(SCAN_LANES);
    let first = (lane * run).min(s.groups);
    (first, (first + run).min(s.groups))
}

/// Phase 1 of `scan` (one workgroup of [`SCAN_LANES`]): each lane sums its run of group
/// totals.
pub fn scan_sum(lane: u32, st: &mut ScanState, p: &BuildParams, scratch: &[u32]) {
    let s = Scratch::new(p.n);
    let (first, end) = lane_run(lane, &s);
    let mut sum = 0;
    let mut g = first;
    while g < end {
        sum += *at(scratch, s.totals() + g);
        g += 1;
    }
    *elem_mut(&mut st.sums, lane) = sum;
}

/// Phase 2 of `scan`: lane 0 turns the sums into exclusive prefixes and stores the wide
/// node count.
pub fn scan_lanes(lane: u32, st: &mut ScanState, p: &BuildParams, scratch: &mut [u32]) {
    if lane == 0 {
        let mut before = 0;
        let mut l = 0;
        while l < SCAN_LANES {
            let sum = *elem(&st.sums, l);
            *elem_mut(&mut st.sums, l) = before;
            before += sum;
            l += 1;
        }
        *at_mut(scratch, Scratch::new(p.n).count()) = before;
    }
}

/// Phase 3 of `scan`: each lane writes the exclusive prefix of every group total of its run.
pub fn scan_write(lane: u32, st: &ScanState, p: &BuildParams, scratch: &mut [u32]) {
    let s = Scratch::new(p.n);
    let (first, end) = lane_run(lane, &s);
    let mut before = *elem(&st.sums, lane);
    let mut g = first;
    while g < end {
        *at_mut(scratch, s.before() + g) = before;
        before += *at(scratch, s.totals() + g);
        g += 1;
    }
}

/// Whether binary internal node `i` roots a wide node (its bit from [`mark`]).
fn root_bit(s: &Scratch, scratch: &[u32], i: u32) -> bool {
    (*at(scratch, s.bits() + i / 32) >> (i % 32)) & 1 != 0
}

/// The wide node rooted at binary node `i` (a root).
fn wide_index(s: &Scratch, scratch: &[u32], i: u32) -> u32 {
    let w = i / 32;
    let below = *at(scratch, s.bits() + w) & ((1u32 << (i % 32)) - 1);
    *at(scratch, s.before() + i / WORKGROUP) + *at(scratch, s.word_before() + w) + below.count_ones()
}

/// The child word of binary node `c` as a child of a wide node: a leaf for a binary leaf or
/// a subtree of at most [`LEAF_MAX`] primitives, else the wide node it roots.
fn child_word(c: u32, n: u32, nodes: &[Node], s: &Scratch, scratch: &[u32], ends: &[u32]) -> u32 {
    if c >= n - 1 {
        return leaf_word(at(nodes, c).a, 1);
    }
    let (first, last) = range(c, n, ends);
    if last - first < LEAF_MAX {
        leaf_word(first, last - first + 1)
    } else {
        wide_index(s, scratch, c)
    }
}

/// Per binary node `i` (`write`): a root writes its wide node, its frontier's nodes as
/// children in sorted order (an explicit stack: absorbed nodes are replaced by their
/// children, left before right).
pub fn write(i: u32, p: &BuildParams, nodes: &[Node], ends: &[u32], scratch: &[u32], wide: &mut [WideNode]) {
    let n = p.n;
    let s = Scratch::new(n);
    if n == 0 || i >= s.slots || !root_bit(&s, scratch, i) {
        return;
    }
    let mut w = WideNode::EMPTY;
    if n <= LEAF_MAX {
        // One leaf of every primitive under the root (for n == 1, the root is that leaf).
        let word = if n == 1 {
            leaf_word(at(nodes, 0).a, 1)
        } else {
            leaf_word(0, n)
        };
        w.set(0, word, at(nodes, 0));
    } else {
        // Nodes to place, right ones deeper in the stack; an absorbed one is opened.
        let mut stack = [0u32; 2 * WIDTH];
        let m = at(nodes, i);
        let v = *at(scratch, s.info() + i);
        *elem_mut(&mut stack, 0) = m.b | if v & ABSORB_B != 0 { ABSORBED } else { 0 };
        *elem_mut(&mut stack, 1) = m.a | if v & ABSORB_A != 0 { ABSORBED } else { 0 };
        let mut sp = 2;
        let mut k = 0;
        while sp > 0 && k < WIDTH as u32 {
            sp -= 1;
            let e = *elem(&stack, sp);
            let c = e & !ABSORBED;
            if e & ABSORBED != 0 && sp + 2 <= 2 * WIDTH as u32 {
                let m = at(nodes, c);
                let v = *at(scratch, s.info() + c);
                *elem_mut(&mut stack, sp) = m.b | if v & ABSORB_B != 0 { ABSORBED } else { 0 };
                *elem_mut(&mut stack, sp + 1) = m.a | if v & ABSORB_A != 0 { ABSORBED } else { 0 };
                sp += 2;
            } else {
                w.set(k, child_word(c, n, nodes, &s, scratch, ends), at(nodes, c));
                k += 1;
            }
        }
    }
    *at_mut(wide, wide_index(&s, scratch, i)) = w;
}

/// Marks a node on [`write`]'s stack as absorbed (node indices are below `2^31`).
const ABSORBED: u32 = 1 << 31;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaf_words_round_trip() {
        for (first, count) in [(0, 1), (7, 4), (MAX_PRIMITIVES - 1, 3)] {
            let w = leaf_word(first, count);
            assert_ne!(w & LEAF, 0);
            assert_eq!(leaf_range(w), (first, count));
        }
    }

    #[test]
    fn scratch_regions_do_not_overlap() {
        for n in [0, 1, 2, 33, 257, 70_000] {
            let s = Scratch::new(n);
            assert!(s.words * 32 >= s.slots && s.groups * WORKGROUP >= s.slots);
            assert!(s.bits() + s.words <= s.word_before());
            assert!(s.word_before() + s.words <= s.totals());
            assert!(s.totals() + s.groups <= s.before());
            assert!(s.before() + s.groups <= s.count());
        }
    }
}
