//! Ray queries against the scene's primitives: closest hit and any hit, through the BVH with
//! a fixed-size stack (nearest child first, far child pushed; each node's children read as
//! one pair, [`write_pairs`]), or by testing every primitive
//! (the thesis's brute force, kept for comparison), or through the 4-wide BVH collapsed from
//! it (`crate::wide`, [`VARIANT_WIDE_BVH`]): one node read gives four children's boxes, leaves
//! hold up to two primitives, hit children are visited nearest first. Rays with a
//! non-finite origin or direction miss.
use crate::alpha::{self, Coverage};
use crate::instance::{Instance, MeshRef, Placed};
use crate::intersect::{self, TriRay};
use crate::math::finite3;
use crate::sync::{at, at_mut, elem, elem_mut, word_at};
use crate::transform;
use crate::types::{
    xyz, Hit, Node, Object, Sphere, Triangle, FEATURE_ALPHA, FEATURE_INSTANCES, FEATURE_SPHERES, FEATURE_TRIANGLES,
    INVALID, VARIANT_MOLLER_TRUMBORE, VARIANT_NO_PAIRS, VARIANT_PLAIN_SLAB, VARIANT_SPLIT_PRODUCTS, VARIANT_WIDE_BVH,
};
use crate::wide::{self, WideNode, LEAF};
use core::mem::MaybeUninit;
use seq_macro::seq;
use spirv_std::glam::{UVec4, Vec3};

/// Entries of the traversal stack. A Karras tree over `n` primitives with 30- or 63-bit
/// codes is at most `bits + ceil(log2 n)` deep; deeper subtrees are skipped (never reached
/// by the inputs the builder accepts). The stacks are left uninitialised (`MaybeUninit`, an
/// entry read only after its push): zeroing 96 entries per query took 17% of the H100's
/// primary-ray throughput (bench/NOTES.md, session 19).
pub const STACK: usize = 96;

/// The primitives of a scene and its BVH (`nodes` empty for brute force). A flattened
/// scene's binary walk reads `nodes` as [`traced_nodes`] of them: the tree, then its pairs.
/// Triangles and nodes are read as 16-byte words ([`triangle_of`], [`node_of`], [`wide_of`]:
/// three words a triangle, two a node, eight a wide node), which NVIDIA's compiler loads as
/// vectors, where it splits a `Triangle` or `Node` read into a load per scalar.
#[derive(Copy, Clone)]
pub struct Scene<'a> {
    pub tris: &'a [UVec4],
    pub spheres: &'a [Sphere],
    pub nodes: &'a [UVec4],
    /// The wide BVH (traversed instead of `nodes` with [`VARIANT_WIDE_BVH`]; may be empty
    /// otherwise) and the sorted primitive order its leaves index.
    pub wide: &'a [UVec4],
    pub order: &'a [u32],
    pub n_tris: u32,
    pub n_prims: u32,
    /// With [`FEATURE_INSTANCES`]: the top level's first node in `nodes` (a BVH over
    /// `instances`' world boxes, numbered from 0; its leaves' `a`: the instance), and the
    /// instances. `nodes` then holds every mesh's BVH too (each at its instances' `nodes`,
    /// numbered from 0), `tris` and `spheres` the meshes' model-space primitives, `n_tris` and
    /// `n_prims` their counts. (One node buffer for both levels: lavapipe binds at most 32
    /// storage buffers a kernel, and the tracers use 31 without the instances.)
    pub top: u32,
    pub instances: &'a [Instance],
    pub n_instances: u32,
    /// Materials and textures, for the holes of alpha-tested triangles (with
    /// [`FEATURE_ALPHA`]; [`Coverage::NONE`] where every primitive is opaque).
    pub coverage: Coverage<'a>,
    /// `FEATURE_*` bits: primitive kinds left out are never intersected (a specialisation
    /// constant on the GPU, so their code is gone). Must include every kind present. And
    /// `VARIANT_*` bits: the less robust tests to use instead.
    pub features: u32,
}

/// Node `i` of a node buffer read as 16-byte words (see [`Scene`]).
#[inline(always)]
pub fn node_of(words: &[UVec4], i: u32) -> Node {
    let (lo, hi) = (word_at(words, 2 * i), word_at(words, 2 * i + 1));
    Node {
        min: [f32::from_bits(lo.x), f32::from_bits(lo.y), f32::from_bits(lo.z)],
        a: lo.w,
        max: [f32::from_bits(hi.x), f32::from_bits(hi.y), f32::from_bits(hi.z)],
        b: hi.w,
    }
}

/// Wide node `i` of a wide BVH read as 16-byte words (see [`Scene`]; eight a node, the
/// padding word not read).
#[inline(always)]
pub fn wide_of(words: &[UVec4], i: u32) -> WideNode {
    let row = |k: u32| floats(word_at(words, 8 * i + k));
    let c = word_at(words, 8 * i + 6);
    WideNode {
        lo: [row(0), row(1), row(2)],
        hi: [row(3), row(4), row(5)],
        child: [c.x, c.y, c.z, c.w],
        _pad: [0; 4],
    }
}

/// Triangle `i` of a triangle buffer read as 16-byte words (see [`Scene`]).
#[inline(always)]
pub fn triangle_of(words: &[UVec4], i: u32) -> Triangle {
    let v = |k: u32| floats(word_at(words, 3 * i + k));
    Triangle {
        v0: v(0),
        v1: v(1),
        v2: v(2),
    }
}

/// A 16-byte word's four floats, bit for bit.
#[inline(always)]
fn floats(w: UVec4) -> [f32; 4] {
    [
        f32::from_bits(w.x),
        f32::from_bits(w.y),
        f32::from_bits(w.z),
        f32::from_bits(w.w),
    ]
}

impl Scene<'_> {
    /// Whether primitive `prim` is a triangle; with one kind of primitive enabled the
    /// answer is a constant.
    pub fn is_triangle(&self, prim: u32) -> bool {
        if self.features & FEATURE_SPHERES == 0 {
            true
        } else if self.features & FEATURE_TRIANGLES == 0 {
            false
        } else {
            prim < self.n_tris
        }
    }
}

/// Intersects primitive `prim`; returns `(t, b1, b2)` with `t = INFINITY` for a miss (and
/// for a hit on a hole of an alpha-tested triangle).
pub fn primitive(s: &Scene, r: &TriRay, prim: u32, t_max: f32) -> (f32, f32, f32) {
    primitive_of(s, r, prim, INVALID, t_max)
}

/// [`primitive`] shown by `object` (its material decides an alpha-tested triangle's holes;
/// [`INVALID`]: the primitive's own object, `prim_object`).
fn primitive_of(s: &Scene, r: &TriRay, prim: u32, object: u32, t_max: f32) -> (f32, f32, f32) {
    if prim < s.n_tris {
        if s.features & FEATURE_TRIANGLES == 0 {
            return (f32::INFINITY, 0.0, 0.0);
        }
        let tri = &triangle_of(s.tris, prim);
        let hit = if s.features & VARIANT_MOLLER_TRUMBORE != 0 {
            intersect::triangle_moller_trumbore(r, tri, t_max)
        } else {
            intersect::triangle(r, tri, t_max)
        };
        if s.features & FEATURE_ALPHA != 0
            && hit.0 < t_max
            && !alpha::covers(&s.coverage, prim, object, hit.1, hit.2, r.origin, r.dir, s.features)
        {
            return (f32::INFINITY, 0.0, 0.0);
        }
        hit
    } else if s.features & FEATURE_SPHERES == 0 {
        (f32::INFINITY, 0.0, 0.0)
    } else {
        let split = s.features & VARIANT_SPLIT_PRODUCTS != 0;
        let t = intersect::sphere(r.origin, r.dir, at(s.spheres, prim - s.n_tris), t_max, split);
        (t, 0.0, 0.0)
    }
}

/// Whether a query can hit anything: finite origin and direction, a direction not zero, and
/// a range `(0, t_max)` that is not empty or NaN. Tested explicitly: Vulkan drivers need not
/// keep NaN semantics in comparisons (the H100's any-hit query with `t_max` NaN hit).
pub fn usable(origin: Vec3, dir: Vec3, t_max: f32) -> bool {
    finite3(origin) && finite3(dir) && dir != Vec3::ZERO && !t_max.is_nan() && t_max > 0.0
}

/// Closest hit in `(0, t_max)`, testing every primitive. (llvmpipe, and so lavapipe, ends
/// any loop after 65535 iterations: there the brute-force queries see only that many
/// primitives.)
pub fn closest_brute(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
    let mut best = Hit::MISS;
    if !usable(origin, dir, t_max) {
        return best;
    }
    let r = TriRay::new(origin, dir);
    let mut limit = t_max;
    let mut prim = 0;
    while prim < s.n_prims {
        let (t, u, v) = primitive(s, &r, prim, limit);
        if t < limit {
            limit = t;
            best = Hit { t, prim, u, v };
        }
        prim += 1;
    }
    best
}

/// Whether anything lies in `(0, t_max)`, testing every primitive.
pub fn any_brute(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
    if !usable(origin, dir, t_max) {
        return false;
    }
    let r = TriRay::new(origin, dir);
    let mut prim = 0;
    while prim < s.n_prims {
        if primitive(s, &r, prim, t_max).0 < t_max {
            return true;
        }
        prim += 1;
    }
    false
}

/// Closest hit in `(0, t_max)` through the BVH.
pub fn closest(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
    if s.features & FEATURE_INSTANCES != 0 {
        walk_levels::<false>(s, origin, dir, t_max).0
    } else if s.features & VARIANT_WIDE_BVH != 0 {
        walk_wide::<false>(s, origin, dir, t_max)
    } else {
        walk::<false>(s, origin, dir, t_max)
    }
}

/// Whether anything lies in `(0, t_max)`, through the BVH; stops at the first hit.
pub fn any(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
    let hit = if s.features & FEATURE_INSTANCES != 0 {
        walk_levels::<true>(s, origin, dir, t_max).0
    } else if s.features & VARIANT_WIDE_BVH != 0 {
        walk_wide::<true>(s, origin, dir, t_max)
    } else {
        walk::<true>(s, origin, dir, t_max)
    };
    hit.prim != INVALID
}

/// Stack traversal of the wide BVH. The stack holds child words, wide nodes and leaves
/// alike, and each iteration takes one: a leaf's primitives are intersected; a node's four
/// boxes are tested together (empty slots miss), the children hit sorted by entry distance
/// (a sorting network; misses sort last), the nearest taken next and the others pushed
/// farthest first. One place intersects primitives and one tests boxes, so the kernel holds
/// one copy of each (four inlined copies of the primitive tests made the H100's bunny
/// trace 1.5-3x slower; intersecting a node's leaves at once, in one loop, was 10-20%
/// slower than this). Any-hit queries intersect a node's leaves at once instead (H100, herd
/// shadow rays: pushed leaves were 8x slower than the binary walk). At most three pushes a
/// node; deeper subtrees than [`STACK`] allows are skipped, as in [`walk`].
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
fn walk_wide<const ANY: bool>(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
    let mut best = Hit::MISS;
    if s.n_prims == 0 || !usable(origin, dir, t_max) {
        return best;
    }
    let r = TriRay::new(origin, dir);
    let mut limit = t_max;
    let mut stack = [MaybeUninit::<u32>::uninit(); STACK];
    let mut sp = 0usize;
    // Wide node 0, the root.
    let mut item = 0u32;
    loop {
        let mut next = false;
        if item & LEAF != 0 {
            leaf(s, &r, item, &mut limit, &mut best);
            if ANY && best.prim != INVALID {
                return found(best, limit);
            }
        } else {
            let w = wide_of(s.wide, item);
            seq!(K in 0..4 {
                let c~K = w.child[K];
                let t~K = box_entry(s, &r, Vec3::new(w.lo[0][K], w.lo[1][K], w.lo[2][K]),
                    Vec3::new(w.hi[0][K], w.hi[1][K], w.hi[2][K]), limit);
            });
            // Shadow rays: the leaves hit are intersected at once (a far leaf, such as the
            // light itself, ends the query), not after every nearer subtree.
            if ANY {
                let mut k = 0;
                while k < 4 {
                    let (t, c) = pick(k, (t0, c0), (t1, c1), (t2, c2), (t3, c3));
                    if t < f32::INFINITY && c & LEAF != 0 {
                        leaf(s, &r, c, &mut limit, &mut best);
                        if best.prim != INVALID {
                            return found(best, limit);
                        }
                    }
                    k += 1;
                }
            }
            seq!(K in 0..4 {
                let t~K = if ANY && c~K & LEAF != 0 { f32::INFINITY } else { t~K };
            });
            // Sorting network for four: (0 1) (2 3) (0 2) (1 3) (1 2).
            let ((t0, c0), (t1, c1)) = order2((t0, c0), (t1, c1));
            let ((t2, c2), (t3, c3)) = order2((t2, c2), (t3, c3));
            let ((t0, c0), (t2, c2)) = order2((t0, c0), (t2, c2));
            let ((t1, c1), (t3, c3)) = order2((t1, c1), (t3, c3));
            let ((t1, c1), (t2, c2)) = order2((t1, c1), (t2, c2));
            push(&mut stack, &mut sp, t3, c3);
            push(&mut stack, &mut sp, t2, c2);
            push(&mut stack, &mut sp, t1, c1);
            if t0 < f32::INFINITY {
                item = c0;
                next = true;
            }
        }
        if !next {
            if sp == 0 {
                return found(best, limit);
            }
            sp -= 1;
            // SAFETY: entry `sp` was written by its push.
            item = unsafe { elem(&stack, sp as u32).assume_init() };
        }
    }
}

/// Entry `k` (0..4) of four, chosen by comparisons (an array indexed by `k` would live in
/// local memory).
fn pick(k: u32, a: (f32, u32), b: (f32, u32), c: (f32, u32), d: (f32, u32)) -> (f32, u32) {
    if k == 0 {
        a
    } else if k == 1 {
        b
    } else if k == 2 {
        c
    } else {
        d
    }
}

/// Pushes node `c` if it was hit (`t` finite) and the stack has room.
fn push(stack: &mut [MaybeUninit<u32>; STACK], sp: &mut usize, t: f32, c: u32) {
    if t < f32::INFINITY && *sp < STACK {
        elem_mut(stack, *sp as u32).write(c);
        *sp += 1;
    }
}

/// `(a, b)` ordered by distance.
fn order2(a: (f32, u32), b: (f32, u32)) -> ((f32, u32), (f32, u32)) {
    if b.0 < a.0 {
        (b, a)
    } else {
        (a, b)
    }
}

/// Intersects a wide leaf's primitives (`order[first..first + count]`, or primitive `first`
/// itself for a leaf of one), updating `limit` and `best`.
fn leaf(s: &Scene, r: &TriRay, word: u32, limit: &mut f32, best: &mut Hit) {
    let (first, count) = wide::leaf_range(word);
    let mut k = 0;
    while k < count {
        let prim = if count == 1 { first } else { *at(s.order, first + k) };
        test_leaf(s, r, prim, limit, best);
        k += 1;
    }
}

/// Where a flattened scene's node buffer holds the children's pairs: after the Karras
/// tree's `2n - 1` nodes and a node of padding, so that every pair (64 bytes) starts on a
/// 64-byte boundary.
pub fn pairs_at(n: u32) -> u32 {
    2 * n
}

/// Nodes a flattened scene's binary walk reads for `n` primitives: the tree's and, from two
/// primitives on, the padding and a pair per internal node ([`write_pairs`]).
pub fn traced_nodes(n: u32) -> u32 {
    if n < 2 {
        n
    } else {
        4 * n - 2
    }
}

/// Writes internal node `i`'s pair (`i < n - 1`, of the `n`-primitive tree in the node
/// buffer `words`): its two children, each as a node holding the child's box, in `a` the
/// child's index and in `b` a leaf child's primitive ([`INVALID`] for an internal child), at
/// nodes `pairs_at(n) + 2 i` and `+ 1`. The walk then reads one pair a step (one 64-byte load)
/// where the tree alone needs the node's links and then each child's box (H200, bunny
/// diffuse bounces 2.71 -> 2.80 Grays/s, the thesis frame's trace 53.4 -> 51.3 ms:
/// bench/NOTES.md, session 41). A copy made after the boxes are final (`pairs_write` after
/// treelets or H-PLOC; the CPU executor's `bvh::pairs`), so the backends' pairs are equal
/// whenever their trees are; a Karras tree's fit writes them itself (`refit::fit`, `PAIRS`).
pub fn write_pairs(i: u32, n: u32, words: &mut [UVec4]) {
    if n < 2 || i >= n - 1 {
        return;
    }
    // The node buffer as 16-byte words, so that a node moves in two vector loads or stores:
    // node `k` is words `2 k` (`min`, `a`) and `2 k + 1` (`max`, `b`).
    let (a, b) = (at(words, 2 * i).w, at(words, 2 * i + 1).w);
    let first_leaf = n - 1;
    let entry = |words: &[UVec4], c: u32| {
        let (lo, hi) = (*at(words, 2 * c), *at(words, 2 * c + 1));
        let prim = if c >= first_leaf { lo.w } else { INVALID };
        (UVec4::new(lo.x, lo.y, lo.z, c), UVec4::new(hi.x, hi.y, hi.z, prim))
    };
    let ((a0, a1), (b0, b1)) = (entry(words, a), entry(words, b));
    let at_pair = 2 * (pairs_at(n) + 2 * i);
    *at_mut(words, at_pair) = a0;
    *at_mut(words, at_pair + 1) = a1;
    *at_mut(words, at_pair + 2) = b0;
    *at_mut(words, at_pair + 3) = b1;
}

/// Stack traversal of the binary tree through its pairs ([`write_pairs`]; with
/// [`VARIANT_NO_PAIRS`] each node's links, then its children): a step ([`pair_step`]) reads
/// the node's pair and tests both children's boxes; a hit leaf's primitive is tested at once,
/// hit internal children are visited nearest first (the far one pushed).
fn walk<const ANY: bool>(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
    let mut best = Hit::MISS;
    let n = s.n_prims;
    if n == 0 || !usable(origin, dir, t_max) {
        return best;
    }
    let r = TriRay::new(origin, dir);
    let mut limit = t_max;
    if n == 1 {
        one_leaf(s, &r, &mut limit, &mut best);
        return found(best, limit);
    }
    let mut stack = [MaybeUninit::<u32>::uninit(); STACK];
    let mut sp = 0usize;
    let mut node = 0u32;
    while pair_step::<ANY>(s, &r, &mut limit, &mut best, &mut stack, &mut sp, &mut node) {}
    found(best, limit)
}

/// The walk of a tree of one primitive, a leaf at the root: its box, then its primitive. (A
/// larger tree's walk does not test the root's box: its first step tests its children's,
/// which a ray missing it misses too.)
fn one_leaf(s: &Scene, r: &TriRay, limit: &mut f32, best: &mut Hit) {
    let root = node_of(s.nodes, 0);
    if slab(s, r, &root, *limit) != f32::INFINITY {
        test_leaf(s, r, root.a, limit, best);
    }
}

/// [`walk`] of closest hits stepped: started ([`Flat::start`]) and stepped ([`Flat::step`],
/// a pair a step) until it ends, so that a kernel can go on with a lane whose walk has ended
/// while the others walk (`path::stepped_pixels`). The same steps as [`walk`], in the same
/// order: the same hits.
pub struct Flat {
    r: TriRay,
    limit: f32,
    /// The closest hit so far ([`Hit::MISS`] for none; its distance is `limit`).
    best: Hit,
    stack: [MaybeUninit<u32>; STACK],
    sp: usize,
    /// The node the next step visits.
    node: u32,
}

impl Flat {
    pub fn new() -> Flat {
        Flat {
            r: TriRay::new(Vec3::ZERO, Vec3::X),
            limit: 0.0,
            best: Hit::MISS,
            stack: [MaybeUninit::<u32>::uninit(); STACK],
            sp: 0,
            node: 0,
        }
    }

    /// Starts the walk of `origin + t dir`, `t` in `(0, t_max)`; false if it has ended
    /// already (a ray that can hit nothing, a scene of one primitive).
    pub fn start(&mut self, s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        self.best = Hit::MISS;
        let n = s.n_prims;
        if n == 0 || !usable(origin, dir, t_max) {
            return false;
        }
        self.r = TriRay::new(origin, dir);
        self.limit = t_max;
        if n == 1 {
            one_leaf(s, &self.r, &mut self.limit, &mut self.best);
            return false;
        }
        self.sp = 0;
        self.node = 0;
        true
    }

    /// The closest hit found ([`Hit::MISS`] for none).
    pub fn hit(&self) -> Hit {
        found(self.best, self.limit)
    }

    /// Ends the walk with `h` as its hit (a brute-force search's).
    pub fn set_hit(&mut self, h: Hit) {
        self.best = h;
        self.limit = h.t;
    }

    /// Visits the next pair; false once the walk has ended.
    pub fn step(&mut self, s: &Scene) -> bool {
        pair_step::<false>(
            s,
            &self.r,
            &mut self.limit,
            &mut self.best,
            &mut self.stack,
            &mut self.sp,
            &mut self.node,
        )
    }
}

impl Default for Flat {
    fn default() -> Flat {
        Flat::new()
    }
}

/// One step of [`walk`] (of a tree of at least two primitives): visits pair `node`; false
/// once the walk has ended (the stack empty, or an any-hit walk's first hit), else `node` is
/// the next.
#[allow(clippy::too_many_arguments)]
fn pair_step<const ANY: bool>(
    s: &Scene,
    r: &TriRay,
    limit: &mut f32,
    best: &mut Hit,
    stack: &mut [MaybeUninit<u32>; STACK],
    sp: &mut usize,
    node: &mut u32,
) -> bool {
    let first_leaf = s.n_prims - 1;
    let (ea, eb) = if s.features & VARIANT_NO_PAIRS != 0 {
        let inner = node_of(s.nodes, *node);
        (
            child_entry(s.nodes, inner.a, first_leaf),
            child_entry(s.nodes, inner.b, first_leaf),
        )
    } else {
        let pairs = pairs_at(s.n_prims);
        (
            node_of(s.nodes, pairs + 2 * *node),
            node_of(s.nodes, pairs + 2 * *node + 1),
        )
    };
    // Both boxes against the limit as the step found it; then the leaves hit, `a`'s
    // first, through one call site, so that lanes with a leaf on either side test it
    // together (two call sites, one per child, ran one after the other whenever a warp
    // held both kinds). A box hit at the limit `l` is hit at any `l' <= l` exactly when
    // its entry is at most `l'` (`intersect::slab`), so `b` is kept, and its leaf
    // tested, as if its box had been tested after `a`'s leaf: the same visits in the
    // same order, the same hits.
    let (ta, tb) = (slab(s, r, &ea, *limit), slab(s, r, &eb, *limit));
    let (a_leaf, b_leaf) = (ea.a >= first_leaf, eb.a >= first_leaf);
    let (a_hit, b_hit) = (a_leaf && ta != f32::INFINITY, b_leaf && tb != f32::INFINITY);
    if a_hit || b_hit {
        test_leaf(s, r, if a_hit { ea.b } else { eb.b }, limit, best);
        if ANY && best.prim != INVALID {
            return false;
        }
        if a_hit && b_hit && tb <= *limit {
            test_leaf(s, r, eb.b, limit, best);
            if ANY && best.prim != INVALID {
                return false;
            }
        }
    }
    let (a, ta) = internal(ea.a, a_leaf, ta, f32::INFINITY);
    let (b, tb) = internal(eb.a, b_leaf, tb, *limit);
    let (near, far) = if tb < ta { (b, a) } else { (a, b) };
    if near != INVALID {
        if far != INVALID && *sp < STACK {
            elem_mut(stack, *sp as u32).write(far);
            *sp += 1;
        }
        *node = near;
        true
    } else if *sp > 0 {
        *sp -= 1;
        // SAFETY: entry `sp` was written by its push.
        *node = unsafe { elem(stack, *sp as u32).assume_init() };
        true
    } else {
        false
    }
}

/// Child `c`'s entry as its parent's pair holds it ([`write_pairs`]), read from the tree
/// itself (with [`VARIANT_NO_PAIRS`]).
fn child_entry(nodes: &[UVec4], c: u32, first_leaf: u32) -> Node {
    let child = node_of(nodes, c);
    Node {
        a: c,
        b: if c >= first_leaf { child.a } else { INVALID },
        ..child
    }
}

/// A pair's child `c` (a pair's entry `a`, see [`write_pairs`]) to descend into, with its
/// box's entry distance `t` (from a test at a limit of at least `limit`): `(INVALID,
/// INFINITY)` for a leaf, a box missed, or one entered past `limit` (which a leaf tested
/// since may have lowered).
fn internal(c: u32, leaf: bool, t: f32, limit: f32) -> (u32, f32) {
    if leaf || t == f32::INFINITY || t > limit {
        (INVALID, f32::INFINITY)
    } else {
        (c, t)
    }
}

/// Intersects a leaf's primitive `prim`, updating `limit` and `best` where it is hit closer.
/// `best.t` is left as it is: a walk's hit lies at its limit ([`found`]), so the walk's steps
/// carry one value fewer (H200, same images: the closed box 76.1 -> 75.8 ms, the herd's
/// real-time frame 6.69 -> 6.62; bench/NOTES.md, session 58).
fn test_leaf(s: &Scene, r: &TriRay, prim: u32, limit: &mut f32, best: &mut Hit) {
    let (t, u, v) = primitive(s, r, prim, *limit);
    if t < *limit {
        *limit = t;
        best.prim = prim;
        best.u = u;
        best.v = v;
    }
}

/// The hit of a walk whose closest hit so far is `best` and whose limit is `limit`: the hit's
/// distance ([`test_leaf`] writes the rest), or [`Hit::MISS`].
fn found(best: Hit, limit: f32) -> Hit {
    if best.prim == INVALID {
        Hit::MISS
    } else {
        Hit { t: limit, ..best }
    }
}

/// Closest hit in `(0, t_max)` of an instanced scene ([`FEATURE_INSTANCES`]) and the
/// instance hit ([`INVALID`] for a miss): `Hit::prim` is the scene's primitive id.
pub fn closest_instance(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> (Hit, u32) {
    walk_levels::<false>(s, origin, dir, t_max)
}

/// Stack traversal of the two levels ([`FEATURE_INSTANCES`]): [`Levels`] stepped to its end.
fn walk_levels<const ANY: bool>(s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> (Hit, u32) {
    let mut w = Levels::new();
    if w.start(s, origin, dir, t_max) {
        while w.step::<ANY>(s) {}
    }
    (w.best, w.best_instance)
}

/// A walk of the two levels between its steps: [`walk`]'s loop, where a hit leaf of the top
/// level is an instance to enter rather than a primitive to intersect. Its box is pushed or
/// taken like an internal node's; taking it moves the ray to the mesh's model space and makes
/// the mesh's root the next node, and the stack's depth there marks where the instance ends:
/// popping back to it restores the world ray (what the top level's boxes read of it). One
/// stack, one box test and one primitive test for both levels. A walk is started
/// ([`Levels::start`]) and stepped ([`Levels::step`]) until it ends, so that a kernel can
/// start a lane's next ray as soon as its walk ends (`path::resolve_tiles`).
pub struct Levels {
    /// The world ray, and what the top level's boxes need of it besides `origin`: its
    /// direction and shear serve primitive tests only, which the top level has none of
    /// (keeping them in `r`, four registers more, made the real-time two-level frames 1.3-2.1%
    /// slower on the H100).
    origin: Vec3,
    dir: Vec3,
    world_inv: Vec3,
    /// The ray of the level walked.
    r: TriRay,
    limit: f32,
    /// The hit so far ([`Hit::MISS`] for none; any-hit walks end at the first) and its
    /// instance.
    pub best: Hit,
    pub best_instance: u32,
    stack: [MaybeUninit<u32>; STACK],
    sp: usize,
    /// The instance being walked ([`INVALID`]: the top level), its mesh and the stack's depth
    /// where it was entered.
    current: u32,
    mesh: MeshRef,
    base: usize,
    /// The node the next step visits.
    node: u32,
}

impl Levels {
    pub fn new() -> Levels {
        Levels {
            origin: Vec3::ZERO,
            dir: Vec3::ZERO,
            world_inv: Vec3::ZERO,
            r: TriRay::new(Vec3::ZERO, Vec3::X),
            limit: 0.0,
            best: Hit::MISS,
            best_instance: INVALID,
            stack: [MaybeUninit::<u32>::uninit(); STACK],
            sp: 0,
            current: INVALID,
            mesh: MeshRef::default(),
            base: 0,
            node: 0,
        }
    }

    /// Starts the walk of `origin + t dir`, `t` in `(0, t_max)`; false if it has ended
    /// already (a ray that can hit nothing, or misses the top level's root box). The stack's
    /// entries are left as they are: each is read only after its push.
    pub fn start(&mut self, s: &Scene, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        self.best = Hit::MISS;
        self.best_instance = INVALID;
        if s.n_instances == 0 || !usable(origin, dir, t_max) {
            return false;
        }
        self.origin = origin;
        self.dir = dir;
        self.r = TriRay::new(origin, dir);
        self.world_inv = self.r.inv_dir;
        self.limit = t_max;
        self.sp = 0;
        self.current = INVALID;
        self.base = 0;
        // Top-level node 0, the root (for one instance, its leaf).
        self.node = 0;
        slab(s, &self.r, &node_of(s.nodes, s.top), t_max) != f32::INFINITY
    }

    /// Visits the next node; false once the walk has ended (an any-hit walk, `ANY`, at its
    /// first hit).
    pub fn step<const ANY: bool>(&mut self, s: &Scene) -> bool {
        let top_leaves = s.n_instances - 1;
        let mut next = INVALID;
        if self.current == INVALID && self.node >= top_leaves {
            // Enter the instance.
            self.current = node_of(s.nodes, s.top + self.node).a;
            let instance = at(s.instances, self.current);
            self.mesh = instance.mesh();
            self.base = self.sp;
            let (o, d) = instance.ray_to_model(self.origin, self.dir);
            self.r = TriRay::new(o, d);
            if self.mesh.prims() == 1 {
                let prim = self.mesh.global(0, s.n_tris);
                let (t, u, v) = primitive_of(s, &self.r, prim, self.mesh.object, self.limit);
                if t < self.limit {
                    self.limit = t;
                    self.best = Hit { t, prim, u, v };
                    self.best_instance = self.current;
                }
            } else if self.mesh.prims() > 1 {
                next = 0;
            }
        } else {
            let top = self.current == INVALID;
            let (first_leaf, offset) = if top {
                (top_leaves, s.top)
            } else {
                (self.mesh.prims() - 1, self.mesh.nodes)
            };
            let inner = node_of(s.nodes, offset + self.node);
            let at_level = Level {
                top,
                offset,
                first_leaf,
                mesh: &self.mesh,
                instance: self.current,
            };
            let (a, ta) = at_level.visit(
                s,
                &self.r,
                inner.a,
                &mut self.limit,
                &mut self.best,
                &mut self.best_instance,
            );
            if ANY && self.best.prim != INVALID {
                return false;
            }
            let (b, tb) = at_level.visit(
                s,
                &self.r,
                inner.b,
                &mut self.limit,
                &mut self.best,
                &mut self.best_instance,
            );
            let (near, far) = if tb < ta { (b, a) } else { (a, b) };
            if near != INVALID {
                if far != INVALID && self.sp < STACK {
                    elem_mut(&mut self.stack, self.sp as u32).write(far);
                    self.sp += 1;
                }
                next = near;
            }
        }
        if ANY && self.best.prim != INVALID {
            return false;
        }
        if next != INVALID {
            self.node = next;
            return true;
        }
        if self.current != INVALID && self.sp == self.base {
            // The instance is done: back to the top level, whose boxes read the ray's origin
            // and reciprocals only. (Computing the reciprocals again here instead of keeping
            // them was 2% slower on the H100.)
            self.current = INVALID;
            self.r.origin = self.origin;
            self.r.inv_dir = self.world_inv;
        }
        if self.sp == 0 {
            return false;
        }
        self.sp -= 1;
        // SAFETY: entry `sp` was written by its push.
        self.node = unsafe { elem(&self.stack, self.sp as u32).assume_init() };
        true
    }
}

impl Default for Levels {
    fn default() -> Levels {
        Levels::new()
    }
}

/// Where [`walk_levels`] is: the top level, or an instance's mesh.
struct Level<'m> {
    top: bool,
    /// The level's first node in `Scene::nodes`.
    offset: u32,
    first_leaf: u32,
    mesh: &'m MeshRef,
    instance: u32,
}

impl Level<'_> {
    /// Child `child` of a node at this level: a hit leaf of a mesh is intersected at once, a
    /// hit internal node or instance is returned with its entry distance.
    fn visit(
        &self,
        s: &Scene,
        r: &TriRay,
        child: u32,
        limit: &mut f32,
        best: &mut Hit,
        best_instance: &mut u32,
    ) -> (u32, f32) {
        let c = node_of(s.nodes, self.offset + child);
        let t_box = slab(s, r, &c, *limit);
        if t_box == f32::INFINITY {
            return (INVALID, f32::INFINITY);
        }
        if self.top || child < self.first_leaf {
            return (child, t_box);
        }
        let prim = self.mesh.global(c.a, s.n_tris);
        let (t, u, v) = primitive_of(s, r, prim, self.mesh.object, *limit);
        if t < *limit {
            *limit = t;
            *best = Hit { t, prim, u, v };
            *best_instance = self.instance;
        }
        (INVALID, f32::INFINITY)
    }
}

/// Entry distance of the ray into node `c`'s box (see [`intersect::slab`]).
fn slab(s: &Scene, r: &TriRay, c: &Node, limit: f32) -> f32 {
    box_entry(s, r, Vec3::from(c.min), Vec3::from(c.max), limit)
}

/// Entry distance of the ray into the box `[lo, hi]`, `INFINITY` for a miss.
fn box_entry(s: &Scene, r: &TriRay, lo: Vec3, hi: Vec3, limit: f32) -> f32 {
    if s.features & VARIANT_PLAIN_SLAB != 0 {
        intersect::slab_plain(r.origin, r.inv_dir, lo, hi, limit)
    } else {
        intersect::slab(r.origin, r.inv_dir, lo, hi, limit)
    }
}

/// The hit point of the hit `(t, b1, b2)` of `origin + t dir` on primitive `prim` of a
/// flattened scene, the unit geometric normal there, and the primitive's scale for
/// [`intersect::offset_origin`].
pub fn surface(s: &Scene, prim: u32, origin: Vec3, dir: Vec3, h: &Hit) -> (Vec3, Vec3, f32) {
    if s.is_triangle(prim) {
        triangle_surface(&triangle_of(s.tris, prim), h)
    } else {
        sphere_surface(at(s.spheres, prim - s.n_tris), origin, dir, h)
    }
}

/// Primitive `p.prim` as a world-space triangle: as stored, or taken from its object's model
/// space by the object's transform (the transform stage's arithmetic: the same bits a
/// flattened scene holds).
pub fn triangle_at(s: &Scene, objects: &[Object], p: Placed) -> Triangle {
    let t = &triangle_of(s.tris, p.prim);
    // The feature test first: without instances (a specialisation constant) the kernel has
    // no code for model-space primitives.
    if s.features & FEATURE_INSTANCES != 0 && p.model {
        transform::world_triangle(at(objects, p.object), t)
    } else {
        *t
    }
}

/// Primitive `p.prim` (a sphere) in world space (see [`triangle_at`]).
pub fn sphere_at(s: &Scene, objects: &[Object], p: Placed) -> Sphere {
    let sphere = at(s.spheres, p.prim - s.n_tris);
    if s.features & FEATURE_INSTANCES != 0 && p.model {
        transform::world_sphere(at(objects, p.object), sphere)
    } else {
        *sphere
    }
}

/// [`surface`] of primitive `p.prim` as `p` places it (`objects`: the scene's objects, read
/// for a primitive in model space).
pub fn surface_at(s: &Scene, objects: &[Object], p: Placed, origin: Vec3, dir: Vec3, h: &Hit) -> (Vec3, Vec3, f32) {
    // A world-space primitive is read where it lies (a flattened scene's kernel has no other
    // code here: the feature is a specialisation constant).
    if s.features & FEATURE_INSTANCES == 0 || !p.model {
        surface(s, p.prim, origin, dir, h)
    } else if s.is_triangle(p.prim) {
        triangle_surface(&triangle_at(s, objects, p), h)
    } else {
        sphere_surface(&sphere_at(s, objects, p), origin, dir, h)
    }
}

/// [`surface`] on world-space triangle `t`.
fn triangle_surface(t: &Triangle, h: &Hit) -> (Vec3, Vec3, f32) {
    (
        intersect::triangle_point(t, h.u, h.v),
        intersect::triangle_normal(t).normalize(),
        intersect::triangle_scale(t),
    )
}

/// [`surface`] on world-space sphere `sphere`.
fn sphere_surface(sphere: &Sphere, origin: Vec3, dir: Vec3, h: &Hit) -> (Vec3, Vec3, f32) {
    let sp = sphere.center_radius;
    let c = xyz(sp);
    let n = (origin + h.t * dir - c).normalize();
    // Re-projected onto the surface: the hit point's error no longer grows with t.
    (c + n * sp[3].abs(), n, intersect::sphere_scale(sphere))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_and_triangles_read_as_words_are_the_structs_bit_for_bit() {
        let nodes = [
            Node {
                min: [-1.5, 0.0, f32::MIN_POSITIVE],
                a: 7,
                max: [2.0, -0.0, f32::INFINITY],
                b: INVALID,
            },
            Node {
                min: [f32::NAN, 1e-30, -3.25],
                a: 0,
                max: [1e30, 4.0, 5.5],
                b: 12,
            },
        ];
        let words: &[UVec4] = bytemuck::cast_slice(&nodes);
        for (i, n) in nodes.iter().enumerate() {
            assert_eq!(bytemuck::bytes_of(&node_of(words, i as u32)), bytemuck::bytes_of(n));
        }
        let tris = [
            Triangle {
                v0: [0.0, 1.0, 2.0, 0.0],
                v1: [-0.0, f32::NAN, 3.0, 1.0],
                v2: [1e-40, -1e38, 0.5, 2.0],
            },
            Triangle {
                v0: [9.0, 8.0, 7.0, 6.0],
                v1: [5.0, 4.0, 3.0, 2.0],
                v2: [1.0, 0.0, -1.0, -2.0],
            },
        ];
        let words: &[UVec4] = bytemuck::cast_slice(&tris);
        for (i, t) in tris.iter().enumerate() {
            assert_eq!(bytemuck::bytes_of(&triangle_of(words, i as u32)), bytemuck::bytes_of(t));
        }
    }
}
