//! The CPU executor's BVH build: the very build kernels of `shared` that the GPU runs.
//! Per-item steps run for every index in turn; workgroup kernels run each phase for every lane
//! before the next phase (a barrier), with workgroup memory as a plain struct per group.
use crate::bvh::{BuildOptions, BuildResult, MortonBits, Sort};
use bytemuck::Pod;
use shared::bounds::{self, BoundsState};
use shared::merge_sort::{self, MergeState, RunState};
use shared::radix_sort::{self as sort, DigitCounts, ScatterState, SortKey, RADIX};
use shared::refit::{ORDERED_COUNTERS as ORDERED, RESTRUCTURE as AGAIN};
use shared::scan::{self, BlockScan};
use shared::types::{item_groups, BuildParams, Node, OrderedBounds, Sphere, Triangle, SORT_ITEMS, WORKGROUP};
use shared::wide::{self, WideNode};
use shared::{karras, morton, ploc, refit, traverse};
use std::time::Instant;

const WG: usize = WORKGROUP as usize;

/// Runs `phase` for every lane of a workgroup.
fn lanes(mut phase: impl FnMut(u32)) {
    for lane in 0..WORKGROUP {
        phase(lane);
    }
}

/// Builds the BVH on the CPU; returns every stage's output and each stage's seconds.
pub fn build(tris: &[Triangle], spheres: &[Sphere], opts: BuildOptions) -> (BuildResult, Vec<(&'static str, f64)>) {
    build_coded(tris, spheres, opts, None)
}

/// [`build`] with the Morton codes taken in `code_bounds` where given (the primitives'
/// own bounds are still reduced, published and returned): what the GPU's top level does
/// from its second build on, coding the instances in the last build's bounds
/// (`GpuLbvh::record_instanced`).
pub fn build_coded(
    tris: &[Triangle],
    spheres: &[Sphere],
    opts: BuildOptions,
    code_bounds: Option<&OrderedBounds>,
) -> (BuildResult, Vec<(&'static str, f64)>) {
    match opts.bits {
        MortonBits::B30 => build_keyed::<u32>(tris, spheres, opts, code_bounds, morton::morton30, morton::code30),
        MortonBits::B63 => build_keyed::<u64>(tris, spheres, opts, code_bounds, morton::morton63, morton::code63),
    }
}

type MortonFn<K> = fn(u32, &BuildParams, &OrderedBounds, &[[f32; 4]], &mut [K], &mut [u32]) -> K;
type CodeFn<K> = fn(u32, &BuildParams, &OrderedBounds, &[[f32; 4]]) -> K;

fn build_keyed<K: SortKey + Pod + Default + Into<u64>>(
    tris: &[Triangle],
    spheres: &[Sphere],
    opts: BuildOptions,
    code_bounds: Option<&OrderedBounds>,
    morton_fn: MortonFn<K>,
    code_fn: CodeFn<K>,
) -> (BuildResult, Vec<(&'static str, f64)>) {
    let n = (tris.len() + spheres.len()) as u32;
    let sorting = Sort::of(n, opts.bits);
    let mut p = BuildParams {
        n_tris: tris.len() as u32,
        n,
        shift: 0,
        passes: sorting.passes(opts.bits),
    };
    let tiles = p.tiles();
    let mut times = Vec::new();
    let mut out = BuildResult::default();
    let mut t = Instant::now();
    let mut lap = |name: &'static str, times: &mut Vec<(&'static str, f64)>| {
        times.push((name, t.elapsed().as_secs_f64()));
        t = Instant::now();
    };

    // Bounds: `items_per_lane` primitives a lane.
    let mut b = OrderedBounds::EMPTY;
    // The GPU's scratch that outlives a build: the sort's tables and the bounds pair (see
    // `shared::bounds`), reset by the tree kernel as on the GPU.
    let mut totals = vec![0u32; sort::TOTALS_WORDS as usize];
    let mut counts = vec![0u32; sort::table_words(n) as usize];
    let mut summaries = vec![[0f32; 4]; n as usize];
    for g in 0..item_groups(n) {
        let mut st = BoundsState {
            b: OrderedBounds::EMPTY,
        };
        lanes(|l| bounds::clear(l, &mut st));
        lanes(|l| bounds::accumulate(l, g, &mut st, &p, tris, spheres, &mut summaries));
        lanes(|l| bounds::flush(l, &st, &mut b));
    }
    out.bounds = b;
    let coded = *code_bounds.unwrap_or(&b);
    lap("bounds", &mut times);

    let mut keys = vec![K::default(); n as usize];
    let mut vals = vec![0u32; n as usize];
    let mut visits = vec![0u32; 2 * n as usize];
    if sorting == Sort::Radix {
        // The counting Morton kernel (for the radix passes).
        for g in 0..item_groups(n) {
            let mut st = Box::new(DigitCounts {
                counts: [0; sort::DIGIT_WORDS],
            });
            lanes(|l| sort::digits_clear(l, &mut st));
            lanes(|l| sort::count_codes(l, g, &mut st, &p, &coded, &summaries, &mut keys, &mut vals, morton_fn));
            lanes(|l| sort::digits_store(l, &st, &p, &mut totals));
        }
        out.morton = keys.iter().map(|&k| k.into()).collect();
    } else {
        // The runs kernel: each workgroup's run sorted (into `keys`, `vals`), its codes
        // into `codes`.
        let mut codes = vec![K::default(); n as usize];
        for g in 0..n.div_ceil(merge_sort::RUN) {
            let mut st = Box::new(RunState {
                keys: [K::default(); merge_sort::RUN as usize],
            });
            lanes(|l| {
                let key = code_fn(g * merge_sort::RUN + l, &p, &coded, &summaries);
                merge_sort::run_load(l, g, key, &mut st, &p, &mut codes)
            });
            lanes(|l| merge_sort::run_rank(l, g, &st, &p, &mut keys, &mut vals));
        }
        out.morton = codes.iter().map(|&k| k.into()).collect();
    }
    lap("morton", &mut times);

    // One run is sorted whole by the runs kernel; more are merged, as on the GPU.
    if sorting == Sort::Merge && n > merge_sort::RUN {
        // Workgroup g places run g: the runs staged a batch at a time, each lane's count of
        // the keys before its own summed over the batches.
        let (mut keys_b, mut vals_b) = (vec![K::default(); n as usize], vec![0u32; n as usize]);
        let runs = n.div_ceil(merge_sort::RUN);
        for g in 0..runs {
            let mut st = Box::new(MergeState {
                keys: [K::default(); (merge_sort::BATCH * merge_sort::RUN) as usize],
            });
            let own: Vec<K> = (0..WORKGROUP).map(|l| merge_sort::merge_key(l, g, &p, &keys)).collect();
            let mut place: Vec<u32> = (0..WORKGROUP).collect();
            let mut first = 0;
            while first < runs {
                lanes(|l| merge_sort::merge_load(l, first, &mut st, &p, &keys));
                lanes(|l| place[l as usize] += merge_sort::merge_count(g, first, own[l as usize], &st));
                first += merge_sort::BATCH;
            }
            lanes(|l| {
                let (key, at) = (own[l as usize], place[l as usize]);
                merge_sort::merge_place(l, g, at, &p, key, &vals, &mut keys_b, &mut vals_b)
            });
        }
        (keys, vals) = (keys_b, vals_b);
    } else if sorting == Sort::Radix {
        let mut keys_b = keys.clone();
        let mut vals_b = vals.clone();
        for pass in 0..p.passes {
            p.shift = pass * sort::RADIX_BITS;
            let mut st = Box::new(ScatterState {
                counts: [0; sort::COUNTERS],
                window: [0; 2 * WG],
                digit_total: [0; RADIX as usize],
                own: [0; RADIX as usize],
                digit_before: [0; RADIX as usize],
                end: [0; RADIX as usize],
                base: [0; RADIX as usize],
                tile: 0,
                pending: 0,
                scan: BlockScan {
                    sums: [0; WG],
                    totals: [0; scan::RAKES as usize],
                },
            });
            // Workgroups in turn: each claims the next tile, so its look-back finds every
            // tile before it published.
            for _ in 0..tiles {
                let io = (&keys[..], &vals[..], &mut keys_b[..], &mut vals_b[..]);
                if sort::items(n) == sort::FEW {
                    scatter_tile::<K, { sort::FEW }>(&mut st, &p, io, &mut counts, &mut totals);
                } else {
                    scatter_tile::<K, SORT_ITEMS>(&mut st, &p, io, &mut counts, &mut totals);
                }
            }
            std::mem::swap(&mut keys, &mut keys_b);
            std::mem::swap(&mut vals, &mut vals_b);
        }
    }
    out.sorted_keys = keys.iter().map(|&k| k.into()).collect();
    out.sorted_prims = vals.clone();
    lap("sort", &mut times);

    if opts.builds_ploc() {
        // The tree and its boxes in one kernel, which also resets what the Karras kernel
        // resets (its "refit" stage is empty).
        (0..n).for_each(|i| sort::clear_tables(i, &p, &mut counts, &mut totals));
        let mut pair = [b, OrderedBounds::EMPTY];
        bounds::publish(0, &mut pair);
        let (nodes, parents) = ploc(&p, &keys, &vals, tris, spheres);
        lap("tree", &mut times);
        // Its "refit" stage: the pairs.
        out.pairs = crate::bvh::pairs_if(opts, &nodes);
        lap("refit", &mut times);
        out.nodes = nodes;
        out.parents = parents;
        return (out, times);
    }
    let total_nodes = (2 * n).saturating_sub(1) as usize;
    let mut nodes = vec![Node::default(); total_nodes];
    let mut parents = vec![0u32; total_nodes];
    let words = bytemuck::cast_slice_mut(&mut nodes);
    for i in 0..n {
        karras::build(i, &p, &keys, words, &mut parents, &mut visits);
        sort::clear_tables(i, &p, &mut counts, &mut totals);
    }
    debug_assert!(totals.iter().chain(&counts).all(|&w| w == 0));
    let mut pair = [b, OrderedBounds::EMPTY];
    bounds::publish(0, &mut pair);
    debug_assert_eq!(pair, [OrderedBounds::EMPTY, b]);
    lap("tree", &mut times);

    let prims = refit::Prims {
        order: &vals,
        tris,
        spheres,
    };
    let groups = n.div_ceil(refit::BLOCK);
    // The wide collapse's climb results, decided by the fit (none for a binary build).
    let mut scratch = if opts.wide {
        vec![0u32; wide::slots(n) as usize]
    } else {
        Vec::new()
    };
    let nodes: Vec<Node> = if opts.restructures() {
        // The treelet refit sees the nodes as 64-bit words (`Node` is only 4-aligned: copy, not cast).
        let mut words: Vec<u64> = bytemuck::pod_collect_to_vec(&nodes);
        for g in 0..groups {
            let mut st = refit::RefitState {
                visits: [0; refit::BLOCK as usize],
            };
            lanes(|l| refit::clear(l, &mut st));
            lanes(|l| {
                refit::refit::<true, true, true>(l, g, &mut st, &p, prims, &mut parents, &mut visits, &mut words)
            });
        }
        // Further rounds over the restructured tree, every counter device-scope (each left
        // zero by the round before, as on the GPU).
        for _ in 1..if n > 1 { opts.rounds } else { 1 } {
            debug_assert!(visits[..n as usize - 1].iter().all(|&c| c == 0));
            restructured(ORDERED | AGAIN, &p, prims, &mut parents, &mut visits, &mut words);
        }
        let nodes: Vec<Node> = bytemuck::pod_collect_to_vec(&words);
        out.pairs = crate::bvh::pairs_if(opts, &nodes);
        nodes
    } else {
        let (nodes, pairs) = fit(&p, prims, &parents, &visits, &nodes, &mut scratch, opts);
        out.pairs = pairs;
        nodes
    };
    lap("refit", &mut times);
    if opts.wide && n > 0 {
        out.wide = collapse(&p, &nodes, &parents, &visits, &scratch);
        lap("wide", &mut times);
    }
    out.nodes = nodes;
    out.parents = parents;
    (out, times)
}

/// The build's fit (`shared::refit::fit`) over the Karras tree `nodes` (its leaf ranges'
/// far ends in `visits[n..]`), as the GPU runs it, and the pairs a build with `opts`
/// writes: returns the fitted nodes and their pairs. Where it writes pairs, the fit writes
/// the boxes into them (`FIT_PAIRS`, as the GPU does where one binding holds them) and the
/// `pairs_write` pass then those of the nodes above the blocks
/// (`refit::pair_entry_above`), and the nodes' boxes are copied back from the pairs. With
/// the wide collapse's `scratch` (a word per internal node; empty for a binary build), it
/// decides the collapse's nodes on the way (`fit_wide`).
fn fit(
    p: &BuildParams,
    prims: refit::Prims,
    parents: &[u32],
    visits: &[u32],
    nodes: &[Node],
    scratch: &mut [u32],
    opts: BuildOptions,
) -> (Vec<Node>, Vec<Node>) {
    let pairs = opts.pairs && !opts.wide && scratch.is_empty() && p.n >= 2;
    // The fit sees the nodes as 32-bit words (with room for the pairs after them).
    let mut all = nodes.to_vec();
    if pairs {
        all.resize(traverse::traced_nodes(p.n) as usize, Node::default());
    }
    let mut words: Vec<u32> = bytemuck::pod_collect_to_vec(&all);
    for g in 0..p.n.div_ceil(refit::BLOCK) {
        let mut st = refit::FitState {
            boxes: [0.0; 6 * refit::BLOCK as usize],
            links: [0; refit::BLOCK as usize],
            leaf_links: [0; refit::BLOCK as usize],
        };
        let leaves: Vec<refit::Leaf> = (0..WORKGROUP).map(|l| refit::fit_leaf(l, g, p, prims)).collect();
        lanes(|l| refit::fit_clear(l, &mut st));
        lanes(|l| refit::fit_links(l, g, &mut st, p, visits, &words));
        let leaf = |l: u32| leaves[l as usize];
        let nodes = &mut refit::FitNodes { words: &mut words };
        if pairs {
            lanes(|l| refit::fit::<true, false, true>(l, g, &mut st, p, leaf(l), parents, visits, nodes, scratch));
        } else if scratch.is_empty() {
            lanes(|l| refit::fit::<true, false, false>(l, g, &mut st, p, leaf(l), parents, visits, nodes, scratch));
        } else {
            lanes(|l| refit::fit::<true, true, false>(l, g, &mut st, p, leaf(l), parents, visits, nodes, scratch));
        }
    }
    let mut all: Vec<Node> = bytemuck::pod_collect_to_vec(&words);
    if !pairs {
        let pairs = crate::bvh::pairs_if(opts, &all);
        return (all, pairs);
    }
    let quads: &mut [glam::UVec4] = bytemuck::cast_slice_mut(&mut all);
    (0..p.n - 1).for_each(|x| refit::pair_entry_above(x, p.n, parents, visits, quads));
    let pairs = all.split_off(traverse::pairs_at(p.n) as usize);
    all.truncate(nodes.len());
    crate::bvh::boxes_from_pairs(&mut all, &pairs);
    (all, pairs)
}

/// One dispatch of the `refit_restructured` kernel (`refit::restructured`, `variant` its
/// specialisation constant) over a tree restructured by treelets, as the GPU runs it.
fn restructured(
    variant: u32,
    p: &BuildParams,
    prims: refit::Prims,
    parents: &mut [u32],
    visits: &mut [u32],
    words: &mut [u64],
) {
    for g in 0..p.n.div_ceil(refit::BLOCK) {
        let mut st = refit::RefitState {
            visits: [0; refit::BLOCK as usize],
        };
        lanes(|l| refit::restructured(variant, l, g, &mut st, p, prims, parents, visits, words));
    }
}

/// Refits `earlier` (a binary build of as many primitives) over `tris` and `spheres` as they
/// are now, as `GpuLbvh::record_refit` does: the tree is kept (its sorted order, links and
/// parents). A Karras tree has every internal box emptied (`refit::empty_box`) and the
/// build's fit run again; a tree restructured by treelets or built by H-PLOC
/// (`opts.counter_refit()`) the counter refit without the block's counters. The bounds and codes stay the earlier build's (those
/// the tree was built from). Errors name a mismatch in the primitives' count.
pub fn refit(
    earlier: &BuildResult,
    tris: &[Triangle],
    spheres: &[Sphere],
    opts: BuildOptions,
) -> Result<BuildResult, String> {
    refit_with(earlier, tris, spheres, opts, false)
}

/// [`refit`] of a tree restructured by treelets that restructures it again (one more round,
/// as `GpuLbvh::record_refit` with `again`: the top level's frames after its build).
pub fn refit_round(
    earlier: &BuildResult,
    tris: &[Triangle],
    spheres: &[Sphere],
    opts: BuildOptions,
) -> Result<BuildResult, String> {
    if !opts.restructures() {
        return Err("a refit restructures again only a tree restructured by treelets".into());
    }
    refit_with(earlier, tris, spheres, opts, true)
}

fn refit_with(
    earlier: &BuildResult,
    tris: &[Triangle],
    spheres: &[Sphere],
    opts: BuildOptions,
    again: bool,
) -> Result<BuildResult, String> {
    let n = (tris.len() + spheres.len()) as u32;
    if earlier.sorted_prims.len() != n as usize || earlier.nodes.len() != (2 * n).saturating_sub(1) as usize {
        return Err(format!(
            "a refit of a tree over {} primitives given {n}",
            earlier.sorted_prims.len()
        ));
    }
    if opts.wide {
        return Err("a wide BVH cannot be refit: a binary build".into());
    }
    if n == 0 {
        return Ok(earlier.clone());
    }
    let p = BuildParams {
        n_tris: tris.len() as u32,
        n,
        shift: 0,
        passes: 0,
    };
    let prims = refit::Prims {
        order: &earlier.sorted_prims,
        tris,
        spheres,
    };
    if opts.counter_refit() {
        let mut words: Vec<u64> = bytemuck::pod_collect_to_vec(&earlier.nodes);
        let mut parents = earlier.parents.clone();
        let mut visits = vec![0u32; 2 * n as usize];
        let variant = if again { ORDERED | AGAIN } else { ORDERED };
        restructured(variant, &p, prims, &mut parents, &mut visits, &mut words);
        let nodes: Vec<Node> = bytemuck::pod_collect_to_vec(&words);
        return Ok(BuildResult {
            pairs: crate::bvh::pairs_if(opts, &nodes),
            nodes,
            parents,
            wide: Vec::new(),
            ..earlier.clone()
        });
    }
    // The leaf ranges' far ends, which the GPU's tree kernel left in its visit buffer: the
    // tree kernel again over the kept codes (the same links, checked).
    let mut visits = vec![0u32; 2 * n as usize];
    let mut tree = vec![Node::default(); earlier.nodes.len()];
    let mut parents = vec![0u32; earlier.nodes.len()];
    let ends = |keys: &[u64], tree: &mut [Node], parents: &mut [u32], visits: &mut [u32]| match opts.bits {
        MortonBits::B30 => {
            let keys: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
            let words = bytemuck::cast_slice_mut(tree);
            (0..n).for_each(|i| karras::build(i, &p, &keys, words, parents, visits));
        }
        MortonBits::B63 => {
            let words = bytemuck::cast_slice_mut(tree);
            (0..n).for_each(|i| karras::build(i, &p, keys, words, parents, visits))
        }
    };
    ends(&earlier.sorted_keys, &mut tree, &mut parents, &mut visits);
    let linked = |a: &Node, b: &Node| (a.a, a.b) == (b.a, b.b);
    if !tree
        .iter()
        .zip(&earlier.nodes)
        .take(n as usize - 1)
        .all(|(a, b)| linked(a, b))
    {
        return Err("the earlier build's nodes are not its codes' Karras tree".into());
    }
    let mut words: Vec<u32> = bytemuck::pod_collect_to_vec(&earlier.nodes);
    (0..n).for_each(|i| refit::empty_box(i, &p, &mut words));
    let emptied: Vec<Node> = bytemuck::pod_collect_to_vec(&words);
    let (nodes, pairs) = fit(&p, prims, &earlier.parents, &visits, &emptied, &mut [], opts);
    Ok(BuildResult {
        pairs,
        nodes,
        wide: Vec::new(),
        ..earlier.clone()
    })
}

/// The wide collapse's last pass (`shared::wide::write`), after the fit decided every node
/// (`fit_wide`), as the GPU runs it.
fn collapse(p: &BuildParams, nodes: &[Node], parents: &[u32], ends: &[u32], scratch: &[u32]) -> Vec<WideNode> {
    let slots = wide::slots(p.n);
    let mut out = vec![WideNode::EMPTY; slots as usize];
    let words: &mut [glam::UVec4] = bytemuck::cast_slice_mut(&mut out);
    let nodes: &[glam::UVec4] = bytemuck::cast_slice(nodes);
    for i in 0..slots {
        wide::write(i, p, nodes, parents, ends, scratch, words);
    }
    out
}

/// The H-PLOC tree and its boxes (`shared::ploc`) over the sorted `keys` and primitives
/// `order`, as the GPU builds them: returns the nodes and their parents.
/// One workgroup of a radix sort pass, lanes owning `I` keys, lane by lane between barriers.
fn scatter_tile<K: SortKey, const I: u32>(
    st: &mut ScatterState,
    p: &BuildParams,
    (keys, vals, keys_b, vals_b): (&[K], &[u32], &mut [K], &mut [u32]),
    counts: &mut [u32],
    totals: &mut [u32],
) {
    lanes(|l| sort::scatter_claim(l, st, p, totals));
    let owned: Vec<_> = (0..WORKGROUP)
        .map(|l| sort::scatter_count::<K, I>(l, st, p, keys, vals, totals))
        .collect();
    lanes(|l| sort::scatter_sums(l, st));
    lanes(|l| scan::rake(l, &mut st.scan));
    lanes(|l| scan::rake_totals(l, &mut st.scan));
    lanes(|l| sort::scatter_offsets(l, st, p, counts));
    while sort::looking_back(st) {
        lanes(|l| sort::lookback_load(l, st, p, counts));
        lanes(|l| sort::lookback_sum(l, st, p, counts));
    }
    let staged: Vec<_> = (0..WORKGROUP)
        .zip(owned)
        .map(|(l, o)| sort::scatter_rank::<K, I>(l, st, p, o))
        .collect();
    staged.iter().for_each(|s| sort::scatter_stage_keys(st, s, 0));
    let lo: Vec<_> = (0..WORKGROUP).map(|l| sort::scatter_staged::<I>(l, st)).collect();
    if K::WORDS == 2 {
        staged.iter().for_each(|s| sort::scatter_stage_keys(st, s, 1));
    }
    let at: Vec<_> = (0..WORKGROUP)
        .zip(&lo)
        .map(|(l, lo)| sort::scatter_write_keys::<K, I>(l, st, p, lo, keys_b))
        .collect();
    staged.iter().for_each(|s| sort::scatter_stage_vals(st, s));
    for (l, at) in (0..WORKGROUP).zip(&at) {
        sort::scatter_write_vals(l, st, at, vals_b);
    }
}

fn ploc<K: SortKey>(
    p: &BuildParams,
    keys: &[K],
    order: &[u32],
    tris: &[Triangle],
    spheres: &[Sphere],
) -> (Vec<Node>, Vec<u32>) {
    let n = p.n;
    let total = (2 * n).saturating_sub(1) as usize;
    let mut words = vec![0u64; total * shared::node_words::WORDS as usize];
    let mut parents = vec![shared::types::INVALID; total];
    let mut visits = vec![0u32; 2 * n as usize];
    let mut reps = vec![0u32; n as usize];
    let mut b = ploc::Buffers {
        keys,
        order,
        tris,
        spheres,
        words: &mut words,
        parents: &mut parents,
        visits: &mut visits,
        reps: &mut reps,
    };
    let group = |phase: &mut dyn FnMut(u32)| (0..ploc::GROUP).for_each(phase);
    // Workgroups in turn: a lane that arrives first at a node stops, so any order builds
    // the same tree.
    for g in 0..n.div_ceil(ploc::GROUP) {
        let mut st = Box::new(<ploc::PlocState as bytemuck::Zeroable>::zeroed());
        group(&mut |l| ploc::start(l, g, &mut st, p, &mut b));
        let mut round = 0;
        loop {
            group(&mut |l| ploc::climb::<K, true>(l, round, &mut st, p, &mut b));
            let mut want = 0;
            group(&mut |l| want = ploc::wanted(l, round, &mut st));
            while want != 0 {
                let w = want.trailing_zeros();
                want &= want - 1;
                group(&mut |l| ploc::load(l, w, &mut st, p, &b));
                loop {
                    group(&mut |l| ploc::compact_stage(l, &mut st));
                    group(&mut |l| ploc::compact_back(l, &mut st));
                    if st.count <= ploc::target(w, &st, p) {
                        break;
                    }
                    group(&mut |l| ploc::areas(l, &mut st));
                    group(&mut |l| ploc::nearest(l, &mut st));
                    group(&mut |l| ploc::merge(l, &mut st, &mut b));
                }
                group(&mut |l| ploc::finish(l, w, &mut st, p, &mut b));
            }
            if !ploc::any_live(round, &st) {
                break;
            }
            round += 1;
        }
    }
    // Every link emptied again, as the refits expect their counters.
    debug_assert!(visits[..n.saturating_sub(1) as usize].iter().all(|&w| w == 0));
    (bytemuck::pod_collect_to_vec(&words), parents)
}
