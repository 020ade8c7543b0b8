//! A 4-wide BVH collapsed from the binary Karras tree on every build, deterministically, by
//! the build's fit and one dispatch after it (the wide BVH of Ylitie, Karras & Laine 2017, "Efficient
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
//! **Where each goes.** A wide node takes the index of the binary internal node that roots
//! it (node 0, the root, included), so no numbering pass is needed: the wide BVH's buffer has
//! a slot per binary internal node (the worst case, which it had to hold anyway), the
//! traversal reads only the slots of roots, and a slot that roots nothing is never written.
//! Two passes, both after the binary tree is built:
//!
//! ```text
//! fit_wide (the build's fit, a workgroup     each node's climb result -> scratch[node]:
//!           per 256 leaves)                  inside a block where the fit's climb meets
//!                                            in workgroup memory, above the blocks by an
//!                                            arrival flag in the same word (`arrive`)
//! write    (per binary internal node)        a root writes its wide node at its own index
//! ```
//!
//! (Until session 43 the climb was a dispatch of its own with a device counter at every
//! level, and the nodes were numbered densely by two more dispatches, a mark and a scan of the
//! root flags: bunny 82 us for the four.)
use crate::sync::{at, at_mut, atomic_exchange_device, atomic_store_u32, elem, elem_mut};
use crate::types::{BuildParams, Node, INVALID};
use bytemuck::{Pod, Zeroable};
use core::mem::size_of;
use spirv_std::glam::UVec4;

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
const _: () = assert!(size_of::<WideNode>() == 128 && size_of::<Node>() == 32);

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

    /// Puts child `word` with the box of binary node words `(lo, hi)` (see [`node_at`]) in
    /// slot `k` (constant indices: no bounds checks).
    fn set(&mut self, k: u32, word: u32, (lo, hi): (UVec4, UVec4)) {
        match k {
            0 => self.put::<0>(word, lo, hi),
            1 => self.put::<1>(word, lo, hi),
            2 => self.put::<2>(word, lo, hi),
            _ => self.put::<3>(word, lo, hi),
        }
    }

    fn put<const K: usize>(&mut self, word: u32, lo: UVec4, hi: UVec4) {
        self.child[K] = word;
        self.lo[0][K] = f32::from_bits(lo.x);
        self.lo[1][K] = f32::from_bits(lo.y);
        self.lo[2][K] = f32::from_bits(lo.z);
        self.hi[0][K] = f32::from_bits(hi.x);
        self.hi[1][K] = f32::from_bits(hi.y);
        self.hi[2][K] = f32::from_bits(hi.z);
    }

    /// Stores the node as wide node `i` of `words` (8 16-byte words a node), in vector
    /// stores.
    fn store(&self, words: &mut [UVec4], i: u32) {
        let bits = |v: [f32; 4]| UVec4::new(v[0].to_bits(), v[1].to_bits(), v[2].to_bits(), v[3].to_bits());
        let c = self.child;
        *at_mut(words, 8 * i) = bits(self.lo[0]);
        *at_mut(words, 8 * i + 1) = bits(self.lo[1]);
        *at_mut(words, 8 * i + 2) = bits(self.lo[2]);
        *at_mut(words, 8 * i + 3) = bits(self.hi[0]);
        *at_mut(words, 8 * i + 4) = bits(self.hi[1]);
        *at_mut(words, 8 * i + 5) = bits(self.hi[2]);
        *at_mut(words, 8 * i + 6) = UVec4::new(c[0], c[1], c[2], c[3]);
        *at_mut(words, 8 * i + 7) = UVec4::ZERO;
    }
}

/// Binary node `c` of the node buffer seen as 16-byte words: `(min, a)` and `(max, b)`, two
/// vector loads (the write pass moved nodes as `Node` values before: bunny 18.7 us).
fn node_at(nodes: &[UVec4], c: u32) -> (UVec4, UVec4) {
    (*at(nodes, 2 * c), *at(nodes, 2 * c + 1))
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

/// Slots of the wide BVH's buffer for `n` primitives, and words of the collapse's scratch:
/// one per binary internal node (one for `n <= 1`), a wide node rooted there and the node's
/// climb result ([`decide`]) with the above-block climb's arrival flag.
pub fn slots(n: u32) -> u32 {
    n.max(2) - 1
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
/// A scratch word's flag: the first child has arrived at the node in the climb above the
/// blocks, its frontier in the bits from [`FRONTIER_SHIFT`] (see [`arrive`]).
const ARRIVED: u32 = 1 << 5;
const FRONTIER_SHIFT: u32 = 8;

/// What the climb carries for a binary node: its primitive count and its frontier size,
/// with [`ABSORBABLE`] where it is an internal node of more than [`LEAF_MAX`] primitives.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Part {
    pub size: u32,
    pub frontier: u32,
}

/// A [`Part`]'s flag: the node can be absorbed by its parent.
const ABSORBABLE: u32 = 1 << 3;

impl Part {
    /// A binary leaf's.
    pub const LEAF: Part = Part { size: 1, frontier: 1 };

    /// A node of `size` primitives whose climb result is `info` (read only where `size`
    /// exceeds [`LEAF_MAX`]: a smaller subtree is one leaf of the wide BVH).
    fn of(size: u32, info: u32) -> Part {
        Part {
            size,
            frontier: if size <= LEAF_MAX { 1 } else { (info & 7) | ABSORBABLE },
        }
    }
}

/// Decides an internal node from its children's parts (see the module's header): its climb
/// result, and its own part.
pub fn decide(a: Part, b: Part) -> (u32, Part) {
    let size = a.size + b.size;
    let (ga, absorbs_a) = (a.frontier & 7, a.frontier & ABSORBABLE != 0);
    let (gb, absorbs_b) = (b.frontier & 7, b.frontier & ABSORBABLE != 0);
    let fits = WIDTH as u32;
    let info = if absorbs_a && absorbs_b && ga + gb <= fits {
        (ga + gb) | ABSORB_A | ABSORB_B
    } else {
        // The larger subtree first (ties: the left one).
        let a_first = a.size >= b.size;
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
    };
    (info, Part::of(size, info))
}

/// Above the blocks (the build's fit with the collapse, [`crate::refit::fit`]): the child
/// `node`, with part `part`, arrives at its parent `a`, whose left child is `left` and
/// whose leaves are `ends[n + a]`'s range. Each arrival swaps [`ARRIVED`]
/// and its frontier into the parent's word; the first finds no flag there and stops; the
/// second finds the first's frontier, decides the parent from it and its own part, stores
/// the parent's climb result (which clears the flag, so every word is free of it after a
/// build and the next build needs no fill) and returns `true` and the parent's part.
/// Everything the second arrival needs travels in the one word, so relaxed atomics suffice:
/// no fence waits for this lane's box merges (a first version, with acquire-release arrivals
/// reading the sibling's result from its own word, took the bunny's wide fit to 51 us on the
/// H200 and 16M to 2.9 ms; this one 38 us and 2.2 ms, the plain fit 25 us and 1.8 ms).
pub fn arrive(a: u32, node: u32, part: Part, left: u32, n: u32, ends: &[u32], scratch: &mut [u32]) -> (bool, Part) {
    let old = atomic_exchange_device::<false>(at_mut(scratch, a), ARRIVED | part.frontier << FRONTIER_SHIFT);
    if old & ARRIVED == 0 {
        return (false, part);
    }
    let sibling = Part {
        size: size(a, n, ends) - part.size,
        frontier: (old >> FRONTIER_SHIFT) & 15,
    };
    let (info, up) = if left == node {
        decide(part, sibling)
    } else {
        decide(sibling, part)
    };
    atomic_store_u32(at_mut(scratch, a), info);
    (true, up)
}

/// Whether binary internal node `i` roots a wide node: the root does; otherwise a node of
/// more than [`LEAF_MAX`] primitives that its parent did not absorb.
fn is_root(i: u32, n: u32, nodes: &[UVec4], parents: &[u32], ends: &[u32], scratch: &[u32]) -> bool {
    if i == 0 {
        return true;
    }
    if size(i, n, ends) <= LEAF_MAX {
        return false;
    }
    let p = *at(parents, i);
    let bit = if at(nodes, 2 * p).w == i { ABSORB_A } else { ABSORB_B };
    *at(scratch, p) & bit == 0
}

/// The child word of binary node `c` (its node words `lo`, see [`node_at`]) as a child of a
/// wide node: a leaf for a binary leaf or a subtree of at most [`LEAF_MAX`] primitives, else
/// the wide node it roots (numbered as the binary node).
fn child_word(c: u32, lo: UVec4, n: u32, ends: &[u32]) -> u32 {
    if c >= n - 1 {
        return leaf_word(lo.w, 1);
    }
    let (first, last) = range(c, n, ends);
    if last - first < LEAF_MAX {
        leaf_word(first, last - first + 1)
    } else {
        c
    }
}

/// A stack entry of [`write`]: node `c`, [`ABSORBED`] where its parent `v` absorbs it.
fn entry(c: u32, v: u32, bit: u32) -> u32 {
    c | if v & bit != 0 { ABSORBED } else { 0 }
}

/// Per binary internal node `i` (`write`): a root writes its wide node at index `i`, its
/// frontier's nodes as children in sorted order (an explicit stack: absorbed nodes are
/// replaced by their children, left before right). `nodes` is the binary tree as 16-byte
/// words ([`node_at`]), `wide` the wide BVH's buffer as 16-byte words (8 a node).
pub fn write(
    i: u32,
    p: &BuildParams,
    nodes: &[UVec4],
    parents: &[u32],
    ends: &[u32],
    scratch: &[u32],
    wide: &mut [UVec4],
) {
    let n = p.n;
    if n == 0 || i >= slots(n) || !is_root(i, n, nodes, parents, ends, scratch) {
        return;
    }
    let mut w = WideNode::EMPTY;
    let root = node_at(nodes, 0);
    if n <= LEAF_MAX {
        // One leaf of every primitive under the root (for n == 1, the root is that leaf).
        let word = if n == 1 {
            leaf_word(root.0.w, 1)
        } else {
            leaf_word(0, n)
        };
        w.set(0, word, root);
    } else {
        // Nodes to place, right ones deeper in the stack; an absorbed one is opened.
        let mut stack = [0u32; 2 * WIDTH];
        let (lo, hi) = node_at(nodes, i);
        let v = *at(scratch, i);
        *elem_mut(&mut stack, 0) = entry(hi.w, v, ABSORB_B);
        *elem_mut(&mut stack, 1) = entry(lo.w, v, ABSORB_A);
        let mut sp = 2;
        let mut k = 0;
        while sp > 0 && k < WIDTH as u32 {
            sp -= 1;
            let e = *elem(&stack, sp);
            let c = e & !ABSORBED;
            let (lo, hi) = node_at(nodes, c);
            if e & ABSORBED != 0 && sp + 2 <= 2 * WIDTH as u32 {
                let v = *at(scratch, c);
                *elem_mut(&mut stack, sp) = entry(hi.w, v, ABSORB_B);
                *elem_mut(&mut stack, sp + 1) = entry(lo.w, v, ABSORB_A);
                sp += 2;
            } else {
                w.set(k, child_word(c, lo, n, ends), (lo, hi));
                k += 1;
            }
        }
    }
    w.store(wide, i);
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
    fn decisions_from_both_sides() {
        // Two absorbable children of frontier 2 fill the four slots.
        let two = Part::of(40, 2);
        assert_eq!(decide(two, two), (4 | ABSORB_A | ABSORB_B, Part::of(80, 4)));
        // Frontiers of 3 and 2 do not fit together: the larger subtree is absorbed.
        let (deep, big) = (Part::of(30, 3), Part::of(50, 2));
        assert_eq!(decide(deep, big).0, 3 | ABSORB_B);
        assert_eq!(decide(big, deep).0, 3 | ABSORB_A);
        // Leaves are never absorbed; two leaves make a leaf of two.
        assert_eq!(decide(Part::LEAF, Part::LEAF), (2, Part::of(2, 0)));
        assert_eq!(Part::of(2, 0).frontier, 1);
    }
}
