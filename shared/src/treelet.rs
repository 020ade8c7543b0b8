//! Treelet restructuring (Karras & Aila 2013, "Fast Parallel Construction of High-Quality
//! Bounding Volume Hierarchies", sec. 4): during the bottom-up refit, every internal node
//! that an invocation fits becomes the root of a treelet of up to [`LEAVES`] leaves (its
//! children, then repeatedly the largest-area internal leaf opened into its two children),
//! whose topology is replaced by the one of least surface-area cost, found by dynamic
//! programming over the leaves' subsets.
//!
//! Treelet leaves keep their subtrees, so the sum of their costs is the same for every
//! topology: the optimum minimises the summed surface area of the treelet's internal
//! nodes, which is all the program compares. The treelet root keeps its node, its box and
//! its parent; the other internal nodes are reused, leaves stay leaves, so the node layout
//! (internal `0..n-1`, leaves `n-1..2n-1`, root 0) holds.
//!
//! Internal nodes are read and written through device-scope atomics ([`crate::node_words`],
//! as the refit reads and writes them): treelets of later roots read what other workgroups restructured earlier in the
//! same dispatch. Leaves, which no treelet changes, are read plainly.
use crate::node_words::{load_box, load_children, store, Boxed};

/// Leaves of a full treelet. The paper's 7 (127 subsets, ~1100 splits) cut a Cornell-box
/// ray's inner-node steps 10.7 -> 8.6 and the bunny's 12.9 -> 11.4 (CPU count), 5 (31
/// subsets, 90 splits) to 8.7 and 11.9, 4 only a little on the Cornell box; on the H100 one
/// invocation per treelet made 7 leaves cost the bunny's build 6.3 ms, 5 leaves 1.2 ms.
pub const LEAVES: usize = 5;
const SUBSETS: usize = 1 << LEAVES;
/// Node `node` with its box, read through atomics as [`crate::refit::refit`] reads them (the refit writes
/// the leaves, and an earlier treelet in this dispatch may have rewritten an internal node).
fn boxed(words: &[u64], node: u32) -> Boxed {
    let (lo, hi) = load_box::<false>(words, node);
    Boxed { node, lo, hi }
}

/// Half the surface area of a box (the factor 2 is the same for all and left out). The
/// `max(0)`s change nothing (extents are not negative) but stand between each product and
/// the sum: NVIDIA's driver fused them into multiply-adds despite the `NoContraction`
/// decoration, and the 1-ulp different areas turned near ties among 16M random triangles the
/// other way than the CPU.
pub fn half_area(lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let (x, y, z) = (hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
    (x * y).max(0.0) + (y * z).max(0.0) + (z * x).max(0.0)
}

/// A half-area as an integer number of units of `2^(e - 167)`, where `e` is the biased
/// exponent of the treelet root's half-area: exact shifts of the mantissa (no rounding that a
/// driver could do differently), at least 17 bits finer than the root's leading bit. The
/// program's sums are then exact, so ties (duplicate primitives) stay ties on every backend;
/// in floats Mesa's lavapipe broke them differently from the CPU.
pub fn fixed(area: f32, root_exp: u32) -> u64 {
    let bits = area.to_bits();
    let e = (bits >> 23 & 0xff) as i32;
    if e == 0 {
        return 0;
    }
    let m = (bits & 0x7f_ffff | 0x80_0000) as u64;
    let shift = e - root_exp as i32 + 17;
    if shift >= 0 {
        m << shift as u32
    } else if shift > -32 {
        m >> (-shift) as u32
    } else {
        0
    }
}

/// The best split of subset `s` found so far: its cost and the part holding `s`'s lowest leaf.
struct Best {
    cost: u64,
    part: u32,
}

/// Steps `q` to the next smaller submask of `rest` and considers splitting `s` into part
/// `low | q` and the rest, keeping the cheaper; true once `q` reached 0 (the last part).
#[inline(always)]
fn next_split(cost: &[u64; SUBSETS], s: u32, low: u32, rest: u32, q: &mut u32, best: &mut Best) -> bool {
    *q = (*q - 1) & rest;
    let p = low | *q;
    let c = cost[p as usize] + cost[(s ^ p) as usize];
    if c < best.cost {
        best.cost = c;
        best.part = p;
    }
    *q == 0
}

/// Restructures the treelet rooted at internal node `root.node`, whose children are `left`
/// and `right` (the refit has all three boxes at hand), in a tree whose first leaf is
/// `first_leaf`; the subtree under the root must be complete (fitted and restructured).
pub fn restructure(root: Boxed, left: Boxed, right: Boxed, first_leaf: u32, parents: &mut [u32], words: &mut [u64]) {
    // Form the treelet: open the largest-area internal leaf until there are LEAVES leaves.
    let mut leaf = [left; LEAVES];
    leaf[1] = right;
    let mut inner = [0u32; LEAVES];
    let mut k = 2;
    let mut m = 0;
    while k < LEAVES {
        let mut pick = LEAVES;
        let mut largest = -1.0;
        let mut j = 0;
        while j < k {
            let area = half_area(leaf[j].lo, leaf[j].hi);
            if leaf[j].node < first_leaf && area > largest {
                largest = area;
                pick = j;
            }
            j += 1;
        }
        if pick == LEAVES {
            break;
        }
        inner[m] = leaf[pick].node;
        m += 1;
        let (c, d) = load_children(words, leaf[pick].node);
        leaf[pick] = boxed(words, c);
        leaf[k] = boxed(words, d);
        k += 1;
    }
    if k < 3 {
        return;
    }

    // cost[s]: least summed half-area (in `fixed` units) of the internal nodes of a tree over the leaves in s
    // (s itself included); split[s]: the part holding s's lowest leaf in that tree. Every
    // proper subset of s is a smaller number, so one ascending sweep sees parts first. A
    // subset's box is its lowest leaf's box grown by the box of the others. (The loops are
    // written to take few iterations: llvmpipe, our CI's device, stops an invocation's loops
    // after 65535 iterations in all.)
    let full = (1u32 << k) - 1;
    let root_exp = half_area(root.lo, root.hi).to_bits() >> 23 & 0xff;
    let mut cost = [0u64; SUBSETS];
    let mut split = [0u32; SUBSETS];
    let mut s_lo = [[0f32; 3]; SUBSETS];
    let mut s_hi = [[0f32; 3]; SUBSETS];
    let mut s = 1u32;
    while s <= full {
        let low = s.isolate_lowest_one();
        let j = low.trailing_zeros() as usize;
        let rest = s ^ low;
        let (lo, hi) = (leaf[j].lo, leaf[j].hi);
        if rest == 0 {
            s_lo[s as usize] = lo;
            s_hi[s as usize] = hi;
        } else {
            let (r_lo, r_hi) = (s_lo[rest as usize], s_hi[rest as usize]);
            let u_lo = [lo[0].min(r_lo[0]), lo[1].min(r_lo[1]), lo[2].min(r_lo[2])];
            let u_hi = [hi[0].max(r_hi[0]), hi[1].max(r_hi[1]), hi[2].max(r_hi[2])];
            s_lo[s as usize] = u_lo;
            s_hi[s as usize] = u_hi;
            // Every part p = low | q, q a proper submask of rest, in descending order; four
            // per iteration.
            let mut best = Best {
                cost: u64::MAX,
                part: low,
            };
            let mut q = rest;
            while !(next_split(&cost, s, low, rest, &mut q, &mut best)
                || next_split(&cost, s, low, rest, &mut q, &mut best)
                || next_split(&cost, s, low, rest, &mut q, &mut best)
                || next_split(&cost, s, low, rest, &mut q, &mut best))
            {}
            cost[s as usize] = fixed(half_area(u_lo, u_hi), root_exp) + best.cost;
            split[s as usize] = best.part;
        }
        s += 1;
    }

    // Rebuild: the root keeps its node (and box); the opened nodes take the inner subsets in
    // the order they are reached.
    let mut todo_node = [0u32; LEAVES];
    let mut todo_set = [0u32; LEAVES];
    todo_node[0] = root.node;
    todo_set[0] = full;
    let mut sp = 1;
    let mut next = 0;
    while sp > 0 {
        sp -= 1;
        let (node, set) = (todo_node[sp], todo_set[sp]);
        let p = split[set as usize];
        let mut child = [0u32; 2];
        let parts = [p, set ^ p];
        for c in 0..2 {
            let part = parts[c];
            if part & (part - 1) == 0 {
                child[c] = leaf[part.trailing_zeros() as usize].node;
            } else {
                child[c] = inner[next];
                next += 1;
                todo_node[sp] = child[c];
                todo_set[sp] = part;
                sp += 1;
            }
            parents[child[c] as usize] = node;
        }
        // The root keeps its box exactly (the refit combined it in its own order).
        let (u_lo, u_hi) = if node == root.node {
            (root.lo, root.hi)
        } else {
            (s_lo[set as usize], s_hi[set as usize])
        };
        store(words, node, u_lo, u_hi, child[0], child[1]);
    }
}
