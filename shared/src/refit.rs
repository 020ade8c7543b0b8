//! Bottom-up box fitting (Karras 2012, sec. 4; the thesis's refit): one invocation per leaf
//! climbs towards the root. At each internal node an acquire-release visit counter lets the
//! first arrival stop and the second, which then sees both children's boxes, fit the node
//! and go on. Boxes are read and written through atomics, device-scope where another
//! workgroup may have written them, so no stale cache line of its write can be seen.
//!
//! A workgroup climbs the leaves `BLOCK * group..` (one per lane). Nodes whose leaves all lie
//! in that block are met only by its lanes: their counters live in workgroup memory, with
//! workgroup-scope ordering, cheaper than a device-scope counter in the
//! storage buffer (`visits`), kept for the nodes above the blocks; and the second arrival
//! there reads its sibling's box with workgroup-scope loads, which the SM's cache may serve
//! (1M 391 -> 389 us, 16M 4.36 -> 4.35 ms on the H100).
//!
//! The kernel sees the node buffer as 64-bit words, 4 per [`crate::types::Node`]:
//! `[min.x | min.y, min.z | a, max.x | max.y, max.z | b]` (low half first), so a box is read
//! or written with four atomic operations instead of six.
use crate::sync::{self, at, at_mut, elem_mut};
use crate::treelet::{self, Boxed};
use crate::types::{prim_box, BuildParams, Sphere, Triangle, INVALID, WORKGROUP};
use seq_macro::seq;

/// Leaves per workgroup, one per lane.
pub const BLOCK: u32 = WORKGROUP;

/// Workgroup memory: the visit counters of internal nodes `BLOCK * group..` (used for those
/// whose leaves all lie in the block).
pub struct RefitState {
    pub visits: [u32; BLOCK as usize],
}

/// Phase 1: clears the block's counters.
pub fn clear(lane: u32, st: &mut RefitState) {
    *elem_mut(&mut st.visits, lane) = 0;
}

const WORDS: u32 = 4;

/// The two floats of a word.
fn split(w: u64) -> (f32, f32) {
    (f32::from_bits(w as u32), f32::from_bits((w >> 32) as u32))
}

/// A word of two 32-bit halves.
fn join(lo: u32, hi: u32) -> u64 {
    lo as u64 | (hi as u64) << 32
}

/// A node's box `(lo, hi)` from its four words.
fn unpack(w: [u64; 4]) -> ([f32; 3], [f32; 3]) {
    let ((x0, y0), (z0, _)) = (split(w[0]), split(w[1]));
    let ((x1, y1), (z1, _)) = (split(w[2]), split(w[3]));
    ([x0, y0, z0], [x1, y1, z1])
}

/// Node `node`'s box through atomic loads (another invocation may have written it in this
/// dispatch): workgroup-scope ones when `LOCAL` (an invocation of this workgroup wrote it:
/// the SM's cache may serve them), else device-scope.
pub fn load_box<const LOCAL: bool>(words: &[u64], node: u32) -> ([f32; 3], [f32; 3]) {
    let b = node * WORDS;
    let load = |k: u32| {
        if LOCAL {
            sync::workgroup_load_u64(at(words, b + k))
        } else {
            sync::atomic_load_u64(at(words, b + k))
        }
    };
    unpack([load(0), load(1), load(2), load(3)])
}

/// Internal node `node`'s children `(a, b)` through atomic loads.
pub fn load_children(words: &[u64], node: u32) -> (u32, u32) {
    let b = node * WORDS;
    let (w1, w3) = (
        sync::atomic_load_u64(at(words, b + 1)),
        sync::atomic_load_u64(at(words, b + 3)),
    );
    ((w1 >> 32) as u32, (w3 >> 32) as u32)
}

/// Writes internal node `node` (box and children) through atomic stores.
pub fn store(words: &mut [u64], node: u32, lo: [f32; 3], hi: [f32; 3], a: u32, b: u32) {
    let w = node * WORDS;
    sync::atomic_store_u64(at_mut(words, w), join(lo[0].to_bits(), lo[1].to_bits()));
    sync::atomic_store_u64(at_mut(words, w + 1), join(lo[2].to_bits(), a));
    sync::atomic_store_u64(at_mut(words, w + 2), join(hi[0].to_bits(), hi[1].to_bits()));
    sync::atomic_store_u64(at_mut(words, w + 3), join(hi[2].to_bits(), b));
}

/// The primitives in their sorted order: `tris[order[i]]` (or `spheres[order[i] - n_tris]`)
/// is leaf `i`'s.
#[derive(Clone, Copy)]
pub struct Prims<'a> {
    pub order: &'a [u32],
    pub tris: &'a [Triangle],
    pub spheres: &'a [Sphere],
}

/// Phase 2: writes leaf `BLOCK * group + lane` (its primitive's box) and climbs from it,
/// fitting every internal node this invocation arrives at second. The invocation carries the box it just fitted and reads only
/// the sibling's; children are combined in (left, right) order so that `min(-0.0, +0.0)` is
/// the same on every backend. A node's leaf range is `[node, visits[n + node]]` or the
/// reverse (recorded by [`crate::karras::build`]): when it lies in the block, the node's
/// counter is the workgroup's.
///
/// `ORDERED` selects the acquire-release counter that real GPUs need. Mesa 22.3's lavapipe
/// (Debian 12, our CI device) loses the second arrival when any acquire/release semantics or
/// memory barrier sits in this divergent loop (its coroutine barrier lowering); there the
/// host runs the relaxed variant, which is sound on lavapipe's coherent x86 memory.
///
/// With `TREELETS`, every node fitted becomes the root of a treelet restructured for the
/// least surface-area cost (see [`crate::treelet`]).
#[allow(clippy::too_many_arguments)]
pub fn refit<const ORDERED: bool, const TREELETS: bool>(
    lane: u32,
    group: u32,
    st: &mut RefitState,
    p: &BuildParams,
    prims: Prims,
    parents: &mut [u32],
    visits: &mut [u32],
    words: &mut [u64],
) {
    let n = p.n;
    let base = group * BLOCK;
    let i = base + lane;
    if i >= n {
        return;
    }
    let mut node = n - 1 + i;
    let prim = *at(prims.order, i);
    let (l, h) = prim_box(prim, p.n_tris, prims.tris, prims.spheres);
    let (mut lo, mut hi) = (l.to_array(), h.to_array());
    store(words, node, lo, hi, prim, INVALID);
    let mut parent = *at(parents, node);
    while parent != INVALID {
        // Immutable during the refit, so loaded before the counter, in its shadow.
        let pb = parent * WORDS;
        let left = (*at(words, pb + 1) >> 32) as u32;
        let right = (*at(words, pb + 3) >> 32) as u32;
        let grandparent = *at(parents, parent);
        let far = *at(visits, n + parent);
        let local = parent.wrapping_sub(base) < BLOCK && far.wrapping_sub(base) < BLOCK;
        // The first arrival at a node stops; the second fits it and climbs on.
        let earlier = if local {
            sync::workgroup_add_ordered::<ORDERED>(elem_mut(&mut st.visits, parent - base), 1)
        } else {
            sync::atomic_add_device::<ORDERED>(at_mut(visits, parent), 1)
        };
        if earlier == 0 {
            return;
        }
        let sibling = if left == node { right } else { left };
        let (s_lo, s_hi) = if local {
            load_box::<true>(words, sibling)
        } else {
            load_box::<false>(words, sibling)
        };
        let (c_lo, c_hi) = (lo, hi);
        // Written out (rust-gpu emits no unroll hints).
        seq!(K in 0..3 {
            let (l_lo, r_lo, l_hi, r_hi) = if left == node {
                (lo[K], s_lo[K], hi[K], s_hi[K])
            } else {
                (s_lo[K], lo[K], s_hi[K], hi[K])
            };
            lo[K] = l_lo.min(r_lo);
            hi[K] = l_hi.max(r_hi);
        });
        store(words, parent, lo, hi, left, right);
        if TREELETS {
            let here = Boxed {
                node,
                lo: c_lo,
                hi: c_hi,
            };
            let there = Boxed {
                node: sibling,
                lo: s_lo,
                hi: s_hi,
            };
            let (l, r) = if left == node { (here, there) } else { (there, here) };
            let root = Boxed { node: parent, lo, hi };
            treelet::restructure(root, l, r, n - 1, parents, words);
        }
        node = parent;
        parent = grandparent;
    }
}
