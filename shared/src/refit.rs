//! Bottom-up box fitting (Karras 2012, sec. 4; the thesis's refit), one invocation per leaf
//! climbing towards the root, in two forms:
//!
//! - [`fit`], the build's: a workgroup fits the nodes whose leaves all lie in its block of
//!   `BLOCK` leaves, siblings meeting in workgroup memory, and merges the boxes of those
//!   subtrees' roots into the nodes above with atomic float `min`/`max` (no invocation
//!   waits for another across workgroups). H100, refit stage, B30: Suzanne 34 -> 17 us,
//!   bunny 42 -> 24, 1M 157 -> 151, 16M 1751 -> 1840 against [`refit`]'s counters.
//! - [`refit`], the treelet builds' (a treelet is restructured when its root is fitted, so
//!   these need to know when a node is complete): at each internal node an acquire-release
//!   visit counter lets the first arrival stop and the second, which then sees both
//!   children's boxes, fit the node and go on. Boxes are read and written through atomics,
//!   device-scope where another workgroup may have written them, so no stale cache line of
//!   its write can be seen. Nodes whose leaves all lie in the workgroup's block have their
//!   counters in workgroup memory, and the second arrival there reads its sibling's box with
//!   workgroup-scope loads, which the SM's cache may serve.
//!
//! [`refit`] sees the node buffer as 64-bit words, 4 per [`crate::types::Node`], read and
//! written through [`crate::node_words`], so a box is read or written with four atomic
//! operations instead of six; [`fit`] as 32-bit words.
use crate::node_words::{load_box, store, Boxed, WORDS};
use crate::sync::{self, at, at_mut, elem, elem_mut};
use crate::traverse;
use crate::treelet;
use crate::types::{f32_to_ordered, prim_box, BuildParams, Sphere, Triangle, INVALID, WORKGROUP};
use crate::wide;
use seq_macro::seq;
use spirv_std::glam::UVec4;

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

/// The primitives in their sorted order: `tris[order[i]]` (or `spheres[order[i] - n_tris]`)
/// is leaf `i`'s.
#[derive(Clone, Copy)]
pub struct Prims<'a> {
    pub order: &'a [u32],
    pub tris: &'a [Triangle],
    pub spheres: &'a [Sphere],
}

/// Leaf `i`'s primitive and its box `(lo, hi)`.
fn leaf_box(i: u32, p: &BuildParams, prims: Prims) -> Leaf {
    let prim = *at(prims.order, i);
    let (l, h) = prim_box(prim, p.n_tris, prims.tris, prims.spheres);
    (prim, l.to_array(), h.to_array())
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
///
/// `BLOCKS` keeps the counters of nodes whose leaves all lie in the block in workgroup memory,
/// which needs the Karras tree's leaf ranges (`visits[n..]`). A tree restructured once no
/// longer has them (a treelet's nodes cover other leaves after it), so a refit of it, or a
/// further round of restructuring, runs without: every counter device-scope. The second
/// arrival at a node zeroes its device counter, so a refit leaves every counter as the tree
/// kernel does (zero) and the next refit or round needs no fill before it.
#[allow(clippy::too_many_arguments)]
pub fn refit<const ORDERED: bool, const TREELETS: bool, const BLOCKS: bool>(
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
    let (prim, mut lo, mut hi) = leaf_box(i, p, prims);
    store(words, node, lo, hi, prim, INVALID);
    let mut parent = *at(parents, node);
    while parent != INVALID {
        // Immutable during the refit, so loaded before the counter, in its shadow.
        let pb = parent * WORDS;
        let left = (*at(words, pb + 1) >> 32) as u32;
        let right = (*at(words, pb + 3) >> 32) as u32;
        let grandparent = *at(parents, parent);
        let local = BLOCKS && parent.wrapping_sub(base) < BLOCK && {
            let far = *at(visits, n + parent);
            far.wrapping_sub(base) < BLOCK
        };
        // The first arrival at a node stops; the second fits it and climbs on.
        let earlier = if local {
            sync::workgroup_add_ordered::<ORDERED>(elem_mut(&mut st.visits, parent - base), 1)
        } else {
            sync::atomic_add_device::<ORDERED>(at_mut(visits, parent), 1)
        };
        if earlier == 0 {
            return;
        }
        if !local {
            // Left zero for the next refit of the tree, which then needs no fill before it.
            sync::atomic_store_u32(at_mut(visits, parent), 0);
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

/// The `fit` kernel's specialisation constant, a sum of these: acquire-release arrival
/// flags (real GPUs; lavapipe runs without, see [`refit`]).
pub const FIT_ORDERED: u32 = 1;
/// The `fit` kernel's specialisation-constant bit for [`fit`]'s `PAIRS`: each box written
/// where the binary walk reads it, in its parent's pair, rather than in its own node.
pub const FIT_PAIRS: u32 = 2;

/// [`restructured`]'s variant bit: acquire-release counters (real GPUs; lavapipe runs
/// without, see [`refit`]).
pub const ORDERED_COUNTERS: u32 = 1;
/// [`restructured`]'s variant bit: restructure treelets again (a further round).
pub const RESTRUCTURE: u32 = 2;

/// The counter refit of a tree restructured before: [`refit`] without the block's counters
/// (every visit counter device-scope, zero as the tree kernel or the refit before left it),
/// `variant` a sum of [`ORDERED_COUNTERS`] and
/// [`RESTRUCTURE`] (the `refit_restructured` kernel's specialisation constant).
#[allow(clippy::too_many_arguments)]
pub fn restructured(
    variant: u32,
    lane: u32,
    group: u32,
    st: &mut RefitState,
    p: &BuildParams,
    prims: Prims,
    parents: &mut [u32],
    visits: &mut [u32],
    words: &mut [u64],
) {
    const BOTH: u32 = ORDERED_COUNTERS | RESTRUCTURE;
    match variant & BOTH {
        BOTH => refit::<true, true, false>(lane, group, st, p, prims, parents, visits, words),
        RESTRUCTURE => refit::<false, true, false>(lane, group, st, p, prims, parents, visits, words),
        ORDERED_COUNTERS => refit::<true, false, false>(lane, group, st, p, prims, parents, visits, words),
        _ => refit::<false, false, false>(lane, group, st, p, prims, parents, visits, words),
    }
}

/// Workgroup memory of [`fit`]: a box slot per lane and a link word per internal node and
/// leaf of the block (8 KB).
pub struct FitState {
    /// The box `(lo, hi)` of the node where lane `l` arrived last: `boxes[6 * l..6 * l + 6]`.
    pub boxes: [f32; 6 * BLOCK as usize],
    /// Internal node `BLOCK * group + s`'s way up ([`LOCAL`], [`LEFT`] and its parent's slot
    /// in the low byte, or 0 where its parent is outside the block), and in bits 16.. the
    /// lane + 1 of the first child to arrive at it.
    pub links: [u32; BLOCK as usize],
    /// Leaf `BLOCK * group + s`'s way up, as in `links`.
    pub leaf_links: [u32; BLOCK as usize],
}

/// The node buffer as [`fit`] sees it: 32-bit words, 8 per [`crate::types::Node`] (the
/// links' reads, the boxes' stores and atomic merges), and on the GPU the same buffer bound
/// again as 16-byte words (`quads`), through which the fit writes each leaf whole in two
/// vector stores: NVIDIA's compiler makes a store of each 32-bit word, eight a leaf (H200:
/// the fit of 10M primitives 1.58 -> 1.43 ms, of the bunny 30 -> 26 us). Writing the nodes
/// inside a block whole too, their links kept in workgroup memory by [`fit_links`], made
/// the fit of 10M primitives slower (1.66 ms; bench/NOTES.md, session 46). The CPU executor
/// sees its words as quads by a cast.
pub struct FitNodes<'a> {
    pub words: &'a mut [u32],
    #[cfg(target_arch = "spirv")]
    pub quads: &'a mut [UVec4],
}

impl<'a> FitNodes<'a> {
    /// The GPU's view: `quads` is binding `words` again. (Off the GPU, where the shader
    /// crate's kernels are only compiled, `quads` is dropped: the CPU executor makes its
    /// `FitNodes` of the words alone.)
    pub fn bound(words: &'a mut [u32], quads: &'a mut [UVec4]) -> Self {
        #[cfg(target_arch = "spirv")]
        return FitNodes { words, quads };
        #[cfg(not(target_arch = "spirv"))]
        {
            let _ = quads;
            FitNodes { words }
        }
    }

    /// The node buffer as 16-byte words.
    fn quads(&mut self) -> &mut [UVec4] {
        #[cfg(target_arch = "spirv")]
        return &mut *self.quads;
        #[cfg(not(target_arch = "spirv"))]
        bytemuck::cast_slice_mut(&mut *self.words)
    }

    /// Writes leaf node `node`: its primitive `prim` and box `(lo, hi)`.
    fn store_leaf(&mut self, node: u32, prim: u32, lo: [f32; 3], hi: [f32; 3]) {
        let quads = self.quads();
        *at_mut(quads, 2 * node) = bits(lo, prim);
        *at_mut(quads, 2 * node + 1) = bits(hi, INVALID);
    }

    /// Writes node `node`'s entry in its parent's pair (of an `n`-primitive tree; its left
    /// child's entry where `left`), as [`traverse::write_pairs`] copies it: its box `(lo,
    /// hi)`, the node, and its primitive `prim` ([`INVALID`] for an internal node).
    #[allow(clippy::too_many_arguments)]
    fn store_entry(&mut self, n: u32, parent: u32, left: bool, node: u32, prim: u32, lo: [f32; 3], hi: [f32; 3]) {
        let k = entry_at(n, parent, left);
        let quads = self.quads();
        *at_mut(quads, k) = bits(lo, node);
        *at_mut(quads, k + 1) = bits(hi, prim);
    }
}

/// A box's corner and a word as a 16-byte word.
fn bits(v: [f32; 3], w: u32) -> UVec4 {
    UVec4::new(v[0].to_bits(), v[1].to_bits(), v[2].to_bits(), w)
}

/// The 16-byte word where internal node `parent`'s pair holds its left (`left`) or right
/// child's entry, in the node buffer of an `n`-primitive tree ([`traverse::write_pairs`]).
fn entry_at(n: u32, parent: u32, left: bool) -> u32 {
    2 * (traverse::pairs_at(n) + 2 * parent + u32::from(!left))
}

/// Whether internal node `x` of an `n`-primitive Karras tree (its leaf range's far end at
/// `visits[n + x]`) is *local*: its leaves all lie in one block, so [`fit`] fits it in
/// workgroup memory (a node's index is one end of its leaf range).
pub fn local(x: u32, n: u32, visits: &[u32]) -> bool {
    *at(visits, n + x) / BLOCK == x / BLOCK
}

/// After [`fit`] with `PAIRS`: writes internal node `x`'s entry in its parent's pair where
/// the fit did not, for a node above the blocks (not [`local`]), whose box the fit merged by
/// atomics from many lanes and is final only now; `words` is the node buffer as 16-byte
/// words, `parents` the tree's. (The `pairs_write` pass specialised, reading a word a node
/// where the full pass reads three nodes and writes a pair.)
pub fn pair_entry_above(x: u32, n: u32, parents: &[u32], visits: &[u32], words: &mut [UVec4]) {
    if x + 1 >= n || local(x, n, visits) {
        return;
    }
    let parent = *at(parents, x);
    if parent == INVALID {
        return;
    }
    let left = at(words, 2 * parent).w == x;
    let (lo, hi) = (*at(words, 2 * x), *at(words, 2 * x + 1));
    let k = entry_at(n, parent, left);
    *at_mut(words, k) = UVec4::new(lo.x, lo.y, lo.z, x);
    *at_mut(words, k + 1) = UVec4::new(hi.x, hi.y, hi.z, INVALID);
}

/// A link's flag: the parent's leaves all lie in the block (its slot is the low byte).
const LOCAL: u32 = 1 << 8;
/// A link's flag: the node is its parent's left child.
const LEFT: u32 = 1 << 9;
/// Where a link word records the first arrival (lane + 1, 9 bits), and (with the wide
/// collapse) its node's frontier (4 bits).
const ARRIVAL: u32 = 16;
const ARRIVAL_MASK: u32 = 0x1ff;
const FRONTIER: u32 = 25;
const _: () = assert!(BLOCK <= ARRIVAL_MASK && ARRIVAL + 9 == FRONTIER);

/// Merges the box `(lo, hi)` into node `node`'s, above the blocks: loads the node's box and
/// merges the sides the box extends (in the order where -0.0 < +0.0); whether it merged any.
#[allow(clippy::identity_op)] // `seq!` starts at 0
fn grow(words: &mut [u32], node: u32, lo: [f32; 3], hi: [f32; 3]) -> bool {
    let w = 8 * node;
    let mut held = [0u32; 6];
    seq!(K in 0..3 {
        held[K] = sync::atomic_load_u32(at(words, w + K));
        held[3 + K] = sync::atomic_load_u32(at(words, w + 4 + K));
    });
    let mut grew = false;
    seq!(K in 0..3 {
        if f32_to_ordered(lo[K]) < f32_to_ordered(f32::from_bits(held[K])) {
            sync::atomic_fmin_bits(at_mut(words, w + K), lo[K]);
            grew = true;
        }
        if f32_to_ordered(hi[K]) > f32_to_ordered(f32::from_bits(held[3 + K])) {
            sync::atomic_fmax_bits(at_mut(words, w + 4 + K), hi[K]);
            grew = true;
        }
    });
    grew
}

/// Writes node `node`'s box (its 32-bit words 0-2 and 4-6; the links are the tree kernel's).
#[allow(clippy::identity_op)] // `seq!` starts at 0
fn store_box(words: &mut [u32], node: u32, lo: [f32; 3], hi: [f32; 3]) {
    let w = 8 * node;
    seq!(K in 0..3 {
        *at_mut(words, w + K) = lo[K].to_bits();
        *at_mut(words, w + 4 + K) = hi[K].to_bits();
    });
}

/// Before [`fit`] runs again on a kept tree (a refit: the primitives moved, the Karras tree,
/// its parents and its leaf ranges stay): empties internal node `i`'s box, as the tree
/// kernel leaves it in a build, since the fit merges into the boxes above its blocks. The
/// boxes of the leaves and of the nodes inside a block are written whole by the fit.
pub fn empty_box(i: u32, p: &BuildParams, words: &mut [u32]) {
    if i + 1 < p.n {
        store_box(words, i, [f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    }
}

/// Phase 1 of [`fit`]: clears the block's links.
pub fn fit_clear(lane: u32, st: &mut FitState) {
    *elem_mut(&mut st.links, lane) = 0;
    *elem_mut(&mut st.leaf_links, lane) = 0;
}

/// Phase 2 (after a barrier): lane `s` writes the way up of internal node
/// `BLOCK * group + s`'s children if the node is local (its leaves, and so its children,
/// lie in the block; its index is one end of its leaf range, so a local node's lane is
/// in the block's workgroup). `words` is the node buffer as 32-bit words, 8 per
/// [`crate::types::Node`] (children `a` and `b` at 3 and 7).
pub fn fit_links(lane: u32, group: u32, st: &mut FitState, p: &BuildParams, visits: &[u32], words: &[u32]) {
    let base = group * BLOCK;
    let x = base + lane;
    if x + 1 >= p.n {
        return;
    }
    let (a, b) = (*at(words, 8 * x + 3), *at(words, 8 * x + 7));
    if local(x, p.n, visits) {
        set_link(st, p.n, base, a, LOCAL | LEFT | lane);
        set_link(st, p.n, base, b, LOCAL | lane);
    }
}

/// Records child `c`'s (an internal node or a leaf of the block) way up.
fn set_link(st: &mut FitState, n: u32, base: u32, c: u32, link: u32) {
    if c >= n - 1 {
        *elem_mut(&mut st.leaf_links, c - (n - 1) - base) = link;
    } else {
        *elem_mut(&mut st.links, c - base) = link;
    }
}

/// A leaf's primitive and box (`lo`, `hi`).
pub type Leaf = (u32, [f32; 3], [f32; 3]);

/// Leaf `BLOCK * group + lane`'s primitive and box for [`fit`], loaded before the links'
/// phases so that the loads overlap them (`INVALID` past the last leaf).
pub fn fit_leaf(lane: u32, group: u32, p: &BuildParams, prims: Prims) -> Leaf {
    let i = group * BLOCK + lane;
    if i < p.n {
        leaf_box(i, p, prims)
    } else {
        (INVALID, [0.0; 3], [0.0; 3])
    }
}

/// Phase 3 (after a barrier): the box fit without the visit counters' chain across the
/// GPU. Lane `l` writes leaf `BLOCK * group + l` (its [`fit_leaf`]) and climbs while the
/// parent's leaves all lie in the block (a *local* node), meeting its sibling in workgroup
/// memory: it leaves its box in its slot and sets its lane in the parent's link word; the
/// first to arrive stops, the second reads the first's box from its slot, fits the parent
/// (children in (left, right) order, so that `min(-0.0, +0.0)` is the same on every backend)
/// and goes on. A lane stops at most once, so its slot is read at most once, after its last
/// write.
///
/// At a node whose parent is not local (a *local root*), the lane merges its box into its
/// ancestors ([`grow`]: the sides it extends, by atomic float `min`/`max` on their bits; the
/// tree kernel left them empty), from the parent up, and stops at the first ancestor whose
/// box (as loaded: it only grows) already holds its own. No invocation waits for another,
/// so a level above the blocks costs a load of the parent and its box instead of a
/// device-scope counter, a fence and the sibling's box, and the early stop and the merges of
/// only the sides that grow keep the atomics off the top of the tree, which every local root
/// reaches (all six merged at every level but the tests' top ones cost the H200's fit of the
/// top level of 10,000 instances ~3 us of its critical path: bench/NOTES.md, session 44).
/// Each node's box is still exactly the union of its leaves, whatever the order: every value
/// a node's side holds was merged by a lane that went on to the parent, where it merged it
/// or found a value at least as far out; so, from the root down, every ancestor of a node
/// ends with each value the node held, and every local root's box is in each ancestor's.
/// Boxes of nodes above the blocks order -0.0 below +0.0 (in the merges and the tests).
///
/// `ORDERED` makes the link word's `or` acquire-release on workgroup memory; lavapipe runs
/// the relaxed variant (see [`refit`]).
///
/// `WIDE` decides the wide collapse's nodes on the way (`fit_wide`; [`crate::wide`]): each
/// lane carries its node's [`wide::Part`], a first arrival inside the block leaves its
/// frontier in the link word with its lane, the second decides the parent from its own part
/// and that and stores the parent's climb result in `scratch[parent]`; above the block the
/// lane climbs on from its local root after its box merges, by [`wide::arrive`]'s flags,
/// until it arrives first. (The first arrival's part in a workgroup array of its own, 1 KB
/// more, cost the binary fit 2% at 16M primitives on the H200.)
///
/// `PAIRS` (not with `WIDE`; a tree of at least two primitives, with room for its pairs
/// after it) writes each leaf's and each local node's box where the binary walk reads it,
/// as its entry in its parent's pair ([`traverse::write_pairs`]), instead of in its own node:
/// the same bytes stored, and no pass over the whole tree after the fit, only
/// [`pair_entry_above`] for the nodes above the blocks, whose boxes the atomics merge (the
/// root's box is kept in its node; the other leaves and local nodes keep only their links).
#[allow(clippy::too_many_arguments)]
#[allow(clippy::identity_op)] // `seq!` starts at 0
pub fn fit<const ORDERED: bool, const WIDE: bool, const PAIRS: bool>(
    lane: u32,
    group: u32,
    st: &mut FitState,
    p: &BuildParams,
    leaf: Leaf,
    parents: &[u32],
    visits: &[u32],
    nodes: &mut FitNodes,
    scratch: &mut [u32],
) {
    let n = p.n;
    let base = group * BLOCK;
    let i = base + lane;
    if i >= n {
        return;
    }
    let mut node = n - 1 + i;
    let (mut prim, mut lo, mut hi) = leaf;
    if !PAIRS {
        nodes.store_leaf(node, prim, lo, hi);
    }
    let mut part = wide::Part::LEAF;
    let mut up = *elem(&st.leaf_links, lane);
    while up & LOCAL != 0 {
        if PAIRS {
            nodes.store_entry(n, base + (up & 0xff), up & LEFT != 0, node, prim, lo, hi);
        }
        let slot = 6 * lane;
        seq!(K in 0..3 {
            *elem_mut(&mut st.boxes, slot + K) = lo[K];
            *elem_mut(&mut st.boxes, slot + 3 + K) = hi[K];
        });
        let s = up & 0xff;
        let arrival = (lane + 1) << ARRIVAL | if WIDE { part.frontier << FRONTIER } else { 0 };
        let old = sync::workgroup_or_ordered::<ORDERED>(elem_mut(&mut st.links, s), arrival);
        let first = (old >> ARRIVAL) & ARRIVAL_MASK;
        if first == 0 {
            return;
        }
        if WIDE {
            // The first arrival's frontier came in the link word; its size is the parent's
            // (from its leaf range) less this lane's.
            let x = base + s;
            let theirs = wide::Part {
                size: at(visits, n + x).abs_diff(x) + 1 - part.size,
                frontier: old >> FRONTIER,
            };
            let (info, parent) = if up & LEFT != 0 {
                wide::decide(part, theirs)
            } else {
                wide::decide(theirs, part)
            };
            if parent.size > wide::LEAF_MAX {
                *at_mut(scratch, base + s) = info;
            }
            part = parent;
        }
        let other = 6 * (first - 1);
        seq!(K in 0..3 {
            let (m_lo, m_hi) = (*elem(&st.boxes, other + K), *elem(&st.boxes, other + 3 + K));
            let (l_lo, r_lo, l_hi, r_hi) = if up & LEFT != 0 {
                (lo[K], m_lo, hi[K], m_hi)
            } else {
                (m_lo, lo[K], m_hi, hi[K])
            };
            lo[K] = l_lo.min(r_lo);
            hi[K] = l_hi.max(r_hi);
        });
        node = base + s;
        prim = INVALID;
        if !PAIRS {
            store_box(nodes.words, node, lo, hi);
        }
        up = old & 0xffff;
    }
    let mut a = *at(parents, node);
    if PAIRS {
        // A local root: its box is final, so its entry is written now (the nodes above get
        // theirs from `pair_entry_above`); the tree's root where all of it is local.
        if a != INVALID {
            let left = *at(nodes.words, 8 * a + 3) == node;
            nodes.store_entry(n, a, left, node, prim, lo, hi);
        } else if prim == INVALID {
            store_box(nodes.words, node, lo, hi);
        } else {
            nodes.store_leaf(node, prim, lo, hi);
        }
    }
    while a != INVALID {
        let next = *at(parents, a);
        if !grow(nodes.words, a, lo, hi) {
            break;
        }
        a = next;
    }
    if WIDE {
        loop {
            let a = *at(parents, node);
            if a == INVALID {
                return;
            }
            let left = *at(nodes.words, 8 * a + 3);
            let (second, up) = wide::arrive(a, node, part, left, n, visits, scratch);
            if !second {
                return;
            }
            (node, part) = (a, up);
        }
    }
}
