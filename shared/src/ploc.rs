//! H-PLOC (Benthin, Meister, Barczak et al., HPG 2024, "H-PLOC: Hierarchical Parallel
//! Locally-Ordered Clustering for Bounding Volume Hierarchy Construction"): the binary tree
//! and its boxes built bottom-up in one dispatch, with the topology of agglomerative
//! clustering instead of the radix tree's.
//!
//! Each lane starts at a leaf (sorted primitive `GROUP * group + lane`) and climbs the
//! radix tree over the sorted Morton codes without building it (Apetrei 2014: a node's
//! parent lies on the side of the boundary whose codes share the longer prefix; the first
//! child to arrive there leaves its range's end in the boundary's link and stops, the second
//! takes it and goes on). A subtree of at most [`KEEP`] leaves keeps its leaves as clusters;
//! at a larger node the whole workgroup merges its children's clusters (at most
//! `2 * KEEP = GROUP`) by PLOC (Meister and Bittner 2018): every cluster finds its nearest
//! neighbour within [`RADIUS`] places in Morton order (the least surface area of the two
//! boxes' union), mutual neighbours merge into a new node, and this repeats until [`KEEP`]
//! clusters are left (one at the root). They are stored at the start of the node's leaf
//! range for its parent to load.
//!
//! Deterministic, so GPU and CPU trees are equal bit for bit: a node's clusters depend on
//! its subtree alone, whichever lane or workgroup arrives second; neighbour ties break by
//! the pair's places; and a new node's slot is a function of the merge: every cluster has a
//! representative leaf (its first in Morton order), and a merge retires the right
//! cluster's, `rep`, into internal slot `rep - 1`. Leaf 0 is never retired, so the `n - 1`
//! merges fill the slots `0..n - 1` once each; the root is then swapped into slot 0. The
//! layout is the Karras tree's ([`crate::karras`]): internal nodes `0..n-1`, root 0, leaves
//! `n-1..2n-1` in sorted order, `parents` of every node, so the traversal, picking and the
//! counter refit (`refit::refit` without the Karras ranges its block counters need) take it
//! unchanged; the wide collapse, which needs those ranges, does not.
//!
//! The nodes are read and written as 64-bit words through [`crate::node_words`], the links
//! and cluster lists through atomics: another workgroup wrote them in this dispatch.
use crate::karras::delta;
use crate::node_words::{load_box, load_children, store};
use crate::radix_sort::SortKey;
use crate::sync::{self, at, at_mut, elem, elem_mut};
use crate::treelet::half_area;
use crate::types::{prim_box, BuildParams, Sphere, Triangle, INVALID};
use bytemuck::Zeroable;
use seq_macro::seq;

/// Lanes of the workgroup, and the most clusters a merge holds.
pub const GROUP: u32 = 32;
/// Clusters a subtree leaves to its parent.
pub const KEEP: u32 = GROUP / 2;
/// How far in Morton order a cluster looks for its nearest neighbour (the paper's 8).
pub const RADIUS: u32 = 8;
const G: usize = GROUP as usize;

/// Workgroup memory: each lane's node, and the clusters of the node being merged. Sets of
/// lanes or clusters are bit masks (bit `k`: lane or place `k`), built by workgroup atomic
/// `or`s, so no phase loops over the lanes: at the top of the tree one workgroup climbs
/// alone and every step's latency is the build's.
#[derive(Zeroable)]
pub struct PlocState {
    /// Lane's node: its leaf range `[first, last]`, the boundary `split` between its
    /// children (`[first, split]`, `[split + 1, last]`), and 1 while it climbs on.
    pub first: [u32; G],
    pub last: [u32; G],
    pub split: [u32; G],
    pub live: [u32; G],
    /// Lanes that climb on, and those whose node is merged, in rounds of even and odd number.
    pub alive: [u32; 2],
    pub want: [u32; 2],
    /// The clusters: node word, representative leaf, box.
    pub node: [u32; G],
    pub rep: [u32; G],
    pub lo: [[f32; 3]; G],
    pub hi: [[f32; 3]; G],
    /// Places holding a cluster, and clusters merged into their partner.
    pub loaded: u32,
    pub dropped: u32,
    /// Compaction's staging copy of the clusters.
    pub node2: [u32; G],
    pub rep2: [u32; G],
    pub lo2: [[f32; 3]; G],
    pub hi2: [[f32; 3]; G],
    /// Half-area bits of the union of clusters `i` and `i + d` at `i * RADIUS + d - 1`.
    pub area: [u32; G * RADIUS as usize],
    /// Each cluster's nearest neighbour (its place).
    pub nn: [u32; G],
    /// Clusters held.
    pub count: u32,
}

const _: () = assert!(
    GROUP == 32 && RADIUS == 8,
    "masks are u32; the neighbour search is written out for 8"
);

/// The global buffers of a build.
pub struct Buffers<'a, K> {
    pub keys: &'a [K],
    pub order: &'a [u32],
    pub tris: &'a [Triangle],
    pub spheres: &'a [Sphere],
    /// Nodes as [`crate::node_words`].
    pub words: &'a mut [u64],
    pub parents: &'a mut [u32],
    /// The tree kernel's `visits` (`2n` words): `n - 1` boundary links (0: empty, else the
    /// far end of the first arrival's range plus 1), then the cluster lists' node words,
    /// each list at the start of its node's leaf range (`n - 1 + first`). Links must be 0
    /// before a build, as the Karras kernel and every refit leave them, and are left so
    /// (the second arrival empties its link).
    pub visits: &'a mut [u32],
    /// The cluster lists' representatives (`n` words, at `first`): the sort's second value
    /// buffer, free once the sort is done.
    pub reps: &'a mut [u32],
}

/// Phase 1: lane writes its leaf (node `n - 1 + i` for sorted primitive `i`) and starts at
/// it. With one primitive the leaf is the root, node 0.
pub fn start<K: SortKey>(lane: u32, group: u32, st: &mut PlocState, p: &BuildParams, b: &mut Buffers<K>) {
    let i = group * GROUP + lane;
    let n = p.n;
    let live = i < n && n > 1;
    if i < n {
        let prim = *at(b.order, i);
        let (lo, hi) = prim_box(prim, p.n_tris, b.tris, b.spheres);
        store(b.words, n - 1 + i, lo.to_array(), hi.to_array(), prim, INVALID);
    }
    if i == 0 && n == 1 {
        // The leaf is the root; every other leaf's parent is written by its merge.
        *at_mut(b.parents, 0) = INVALID;
    }
    *elem_mut(&mut st.first, lane) = i;
    *elem_mut(&mut st.last, lane) = i;
    *elem_mut(&mut st.live, lane) = live as u32;
    if lane == 0 {
        st.count = 0;
        st.alive[0] = 0;
        st.want[0] = 0;
        st.loaded = 0;
        st.dropped = 0;
    }
}

/// Phase 2 of round `round`: a live lane climbs to its node's parent (see [`step`]) and
/// joins the round's masks: lanes that climb on, and those whose node is merged now (it has
/// more than [`KEEP`] leaves, or it is the root).
pub fn climb<K: SortKey, const ORDERED: bool>(
    lane: u32,
    round: u32,
    st: &mut PlocState,
    p: &BuildParams,
    b: &mut Buffers<K>,
) {
    step::<K, ORDERED>(lane, st, p, b);
    if *elem(&st.live, lane) == 0 {
        return;
    }
    let r = round & 1;
    sync::workgroup_or_ordered::<false>(elem_mut(&mut st.alive, r), 1 << lane);
    let size = *elem(&st.last, lane) - *elem(&st.first, lane) + 1;
    if size > KEEP || size == p.n {
        sync::workgroup_or_ordered::<false>(elem_mut(&mut st.want, r), 1 << lane);
    }
}

/// Phase 3 of round `round`: lane 0 empties the next round's masks. Returns the lanes whose
/// node is merged in this round.
pub fn wanted(lane: u32, round: u32, st: &mut PlocState) -> u32 {
    if lane == 0 {
        *elem_mut(&mut st.alive, (round + 1) & 1) = 0;
        *elem_mut(&mut st.want, (round + 1) & 1) = 0;
    }
    *elem(&st.want, round & 1)
}

/// After round `round`'s merges: whether any lane climbs on.
pub fn any_live(round: u32, st: &PlocState) -> bool {
    *elem(&st.alive, round & 1) != 0
}

/// A live lane climbs to its node's parent. The first child to arrive leaves its
/// range's far end in the boundary's link and stops; the second takes it (resetting the
/// link) and holds the parent. `ORDERED`: the link's exchange is acquire-release (real
/// GPUs; see [`crate::refit::refit`] for lavapipe's relaxed variant).
fn step<K: SortKey, const ORDERED: bool>(lane: u32, st: &mut PlocState, p: &BuildParams, b: &mut Buffers<K>) {
    if *elem(&st.live, lane) == 0 {
        return;
    }
    let n = p.n;
    let (first, last) = (*elem(&st.first, lane), *elem(&st.last, lane));
    if first == 0 && last == n - 1 {
        // The root, merged: done.
        *elem_mut(&mut st.live, lane) = 0;
        return;
    }
    let right = first == 0
        || (last != n - 1 && delta(b.keys, n, last, last as i32 + 1) > delta(b.keys, n, first - 1, first as i32));
    let (link, mine) = if right { (last, first) } else { (first - 1, last) };
    let other = sync::atomic_exchange_device::<ORDERED>(at_mut(b.visits, link), mine + 1);
    if other == 0 {
        *elem_mut(&mut st.live, lane) = 0;
        return;
    }
    let other = other - 1;
    sync::atomic_store_u32(at_mut(b.visits, link), 0);
    *elem_mut(&mut st.split, lane) = link;
    if right {
        *elem_mut(&mut st.last, lane) = other;
    } else {
        *elem_mut(&mut st.first, lane) = other;
    }
}

/// The clusters a child `[first, last]` leaves: its leaves if it has at most [`KEEP`],
/// else the list its merge stored; entry `k` of them (`INVALID` node past the end).
fn child_cluster<K>(k: u32, first: u32, last: u32, n: u32, b: &Buffers<K>) -> (u32, u32) {
    let size = last - first + 1;
    if k >= size.min(KEEP) {
        (INVALID, INVALID)
    } else if size <= KEEP {
        (n - 1 + first + k, first + k)
    } else {
        let node = sync::atomic_load_u32(at(b.visits, n - 1 + first + k));
        let rep = sync::atomic_load_u32(at(b.reps, first + k));
        (node, rep)
    }
}

/// Merge phase 1: lane loads cluster `lane` of lane `w`'s node's children (the left
/// child's first [`KEEP`], then the right's) with its box, in places `lane`.
pub fn load<K>(lane: u32, w: u32, st: &mut PlocState, p: &BuildParams, b: &Buffers<K>) {
    let (first, last, split) = (*elem(&st.first, w), *elem(&st.last, w), *elem(&st.split, w));
    let (node, rep) = if lane < KEEP {
        child_cluster(lane, first, split, p.n, b)
    } else {
        child_cluster(lane - KEEP, split + 1, last, p.n, b)
    };
    *elem_mut(&mut st.node, lane) = node;
    *elem_mut(&mut st.rep, lane) = rep;
    if node != INVALID {
        let (lo, hi) = load_box::<false>(b.words, node);
        *elem_mut(&mut st.lo, lane) = lo;
        *elem_mut(&mut st.hi, lane) = hi;
        sync::workgroup_or_ordered::<false>(&mut st.loaded, 1 << lane);
    }
}

/// Compaction phase 1: lane's cluster, if it holds one not merged away, to its place among
/// those in the staging copy; lane 0 counts them.
pub fn compact_stage(lane: u32, st: &mut PlocState) {
    let held = st.loaded & !st.dropped;
    if lane == 0 {
        st.count = held.count_ones();
    }
    if held >> lane & 1 != 0 {
        let before = (held & ((1 << lane) - 1)).count_ones();
        *elem_mut(&mut st.node2, before) = *elem(&st.node, lane);
        *elem_mut(&mut st.rep2, before) = *elem(&st.rep, lane);
        *elem_mut(&mut st.lo2, before) = *elem(&st.lo, lane);
        *elem_mut(&mut st.hi2, before) = *elem(&st.hi, lane);
    }
}

/// Compaction phase 2: the staged clusters back in places `0..count`.
pub fn compact_back(lane: u32, st: &mut PlocState) {
    let count = st.count;
    if lane < count {
        *elem_mut(&mut st.node, lane) = *elem(&st.node2, lane);
        *elem_mut(&mut st.rep, lane) = *elem(&st.rep2, lane);
        *elem_mut(&mut st.lo, lane) = *elem(&st.lo2, lane);
        *elem_mut(&mut st.hi, lane) = *elem(&st.hi2, lane);
    }
    if lane == 0 {
        st.loaded = if count >= GROUP { u32::MAX } else { (1 << count) - 1 };
        st.dropped = 0;
    }
}

/// The clusters lane `w`'s node keeps: one at the root, else [`KEEP`].
pub fn target(w: u32, st: &PlocState, p: &BuildParams) -> u32 {
    if *elem(&st.first, w) == 0 && *elem(&st.last, w) == p.n - 1 {
        1
    } else {
        KEEP
    }
}

/// The order of candidate pairs `first < second` whose union has half-area bits `area`:
/// the area, then the pair's places (a total order, so the least pair is each one's
/// nearest: a mutual pair always exists). Among equal areas the closer pair goes first, then
/// the pair whose left place is even: clusters of equal boxes (equal centroids) then pair up
/// `(0, 1), (2, 3), ..` and merge at once, a balanced tree, where ordering by places alone
/// would merge one pair an iteration into a chain.
fn pair_key(area: u32, first: u32, second: u32) -> u64 {
    (area as u64) << 32 | ((second - first) << 16 | (first & 1) << 8 | first) as u64
}

/// PLOC phase 1: lane's cluster `i` computes the half-areas of its unions with clusters
/// `i + 1..=i + RADIUS` (written out: independent loads and arithmetic).
#[allow(clippy::identity_op)]
pub fn areas(lane: u32, st: &mut PlocState) {
    let count = st.count;
    if lane >= count {
        return;
    }
    let (la, ha) = (*elem(&st.lo, lane), *elem(&st.hi, lane));
    seq!(D in 1..=8 {
        let j = lane + D;
        let a = if j < count {
            let (lb, hb) = (*elem(&st.lo, j), *elem(&st.hi, j));
            let lo = [la[0].min(lb[0]), la[1].min(lb[1]), la[2].min(lb[2])];
            let hi = [ha[0].max(hb[0]), ha[1].max(hb[1]), ha[2].max(hb[2])];
            half_area(lo, hi).to_bits() & 0x7fff_ffff
        } else {
            u32::MAX
        };
        *elem_mut(&mut st.area, lane * RADIUS + D - 1) = a;
    });
}

/// PLOC phase 2: lane's cluster finds its nearest neighbour within [`RADIUS`] places.
#[allow(clippy::identity_op, unused_assignments)] // `seq!` starts at 1; the last `best` is not read
pub fn nearest(lane: u32, st: &mut PlocState) {
    let count = st.count;
    if lane >= count {
        return;
    }
    let mut best = u64::MAX;
    let mut nn = lane;
    seq!(D in 1..=8 {
        if lane + D < count {
            let key = pair_key(*elem(&st.area, lane * RADIUS + D - 1), lane, lane + D);
            if key < best {
                best = key;
                nn = lane + D;
            }
        }
        if lane >= D {
            let key = pair_key(*elem(&st.area, (lane - D) * RADIUS + D - 1), lane - D, lane);
            if key < best {
                best = key;
                nn = lane - D;
            }
        }
    });
    *elem_mut(&mut st.nn, lane) = nn;
}

/// PLOC phase 3: the left cluster of each mutual pair becomes their new node (in the slot
/// its partner's representative retires), the right one is dropped.
pub fn merge<K>(lane: u32, st: &mut PlocState, b: &mut Buffers<K>) {
    if lane >= st.count {
        return;
    }
    let j = *elem(&st.nn, lane);
    if j <= lane || *elem(&st.nn, j) != lane {
        return;
    }
    let slot = *elem(&st.rep, j) - 1;
    let (la, ha) = (*elem(&st.lo, lane), *elem(&st.hi, lane));
    let (lb, hb) = (*elem(&st.lo, j), *elem(&st.hi, j));
    let lo = [la[0].min(lb[0]), la[1].min(lb[1]), la[2].min(lb[2])];
    let hi = [ha[0].max(hb[0]), ha[1].max(hb[1]), ha[2].max(hb[2])];
    let (a, c) = (*elem(&st.node, lane), *elem(&st.node, j));
    store(b.words, slot, lo, hi, a, c);
    sync::atomic_store_u32(at_mut(b.parents, a), slot);
    sync::atomic_store_u32(at_mut(b.parents, c), slot);
    *elem_mut(&mut st.node, lane) = slot;
    *elem_mut(&mut st.lo, lane) = lo;
    *elem_mut(&mut st.hi, lane) = hi;
    sync::workgroup_or_ordered::<false>(&mut st.dropped, 1 << j);
}

/// Merge's last phase: lane stores its cluster in the node's list (`INVALID` nodes after
/// the last, up to [`KEEP`]); at the root, lane 0 swaps the root into slot 0.
pub fn finish<K>(lane: u32, w: u32, st: &mut PlocState, p: &BuildParams, b: &mut Buffers<K>) {
    let (first, last) = (*elem(&st.first, w), *elem(&st.last, w));
    let n = p.n;
    if lane == 0 {
        // The next merge's loads start from no places.
        st.loaded = 0;
    }
    if first == 0 && last == n - 1 {
        if lane == 0 {
            to_slot_zero(*elem(&st.node, 0), b);
        }
        return;
    }
    if lane < st.count {
        sync::atomic_store_u32(at_mut(b.visits, n - 1 + first + lane), *elem(&st.node, lane));
        sync::atomic_store_u32(at_mut(b.reps, first + lane), *elem(&st.rep, lane));
    } else if lane < KEEP {
        sync::atomic_store_u32(at_mut(b.visits, n - 1 + first + lane), INVALID);
    }
}

/// Swaps the root (slot `root`) with the node in slot 0, and mends the links to both.
fn to_slot_zero<K>(root: u32, b: &mut Buffers<K>) {
    sync::atomic_store_u32(at_mut(b.parents, root), INVALID);
    if root == 0 {
        return;
    }
    let (rlo, rhi) = load_box::<false>(b.words, root);
    let (ra, rb) = load_children(b.words, root);
    let (zlo, zhi) = load_box::<false>(b.words, 0);
    let (za, zb) = load_children(b.words, 0);
    let zp = sync::atomic_load_u32(at(b.parents, 0));
    // The root's children that were slot 0 now name its new slot.
    let fix = |c: u32| if c == 0 { root } else { c };
    store(b.words, 0, rlo, rhi, fix(ra), fix(rb));
    store(b.words, root, zlo, zhi, za, zb);
    sync::atomic_store_u32(at_mut(b.parents, fix(ra)), 0);
    sync::atomic_store_u32(at_mut(b.parents, fix(rb)), 0);
    sync::atomic_store_u32(at_mut(b.parents, za), root);
    sync::atomic_store_u32(at_mut(b.parents, zb), root);
    sync::atomic_store_u32(at_mut(b.parents, 0), INVALID);
    if zp != root {
        // Slot 0's old parent names it again at its new slot.
        let (pa, pb) = load_children(b.words, zp);
        let (plo, phi) = load_box::<false>(b.words, zp);
        store(b.words, zp, plo, phi, fix(pa), fix(pb));
        sync::atomic_store_u32(at_mut(b.parents, root), zp);
    } else {
        sync::atomic_store_u32(at_mut(b.parents, root), 0);
    }
}
