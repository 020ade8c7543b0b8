//! The compute module's entry points. Each is a few lines that call into `shared`: per-item
//! steps with `global_invocation_id.x`, cooperative kernels as phases between barriers.
//! Bindings follow the table in `shared::types`.

use shared::bounds::{self, BoundsState};
use shared::denoise::{self, DenoisePush};
use shared::envmap::EnvEntry;
use shared::instance::Instance;
use shared::merge_sort::{self, MergeState, RunState};
use shared::path;
use shared::ploc::{self, PlocState};
use shared::radix_sort::{self as sort, DigitCounts, ScatterState, SortKey};
use shared::refit::{FitState, RefitState};
use shared::scan;
use shared::texture::TextureInfo;
use shared::types::{
    flat_group, flat_index, BuildParams, Frame, Hit, Material, Object, OrderedBounds, PunctualLight, Ray, RenderPush,
    Sphere, Triangle, VertexAttrs, FEATURES_ALL, SORT_ITEMS,
};
use shared::wide;

// The default of `path_trace`'s and `cast_rays`' specialisation constant: every feature.
const _: () = assert!(FEATURES_ALL == 130111);
use shared::sync::{at, at_mut};
use shared::{display, karras, morton, refit, transform as xform};
use spirv_std::arch::all_memory_barrier_with_group_sync as all_barrier;
use spirv_std::arch::workgroup_memory_barrier_with_group_sync as barrier;
use spirv_std::glam::{UVec3, UVec4};
use spirv_std::spirv;

#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn bounds_reduce(
    #[spirv(local_invocation_id)] lid: UVec3,
    #[spirv(workgroup_id)] gid: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[Triangle],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] out: &mut OrderedBounds,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] summaries: &mut [[f32; 4]],
    #[spirv(workgroup)] st: &mut BoundsState,
) {
    bounds::clear(lid.x, st);
    barrier();
    bounds::accumulate(lid.x, flat_group(gid.x, gid.y), st, p, tris, spheres, summaries);
    barrier();
    bounds::flush(lid.x, st, out);
}

/// A refit entry point: `ORDERED` visit counters or relaxed ones (lavapipe only, see
/// `shared::refit`), with or without treelet restructuring (see `shared::treelet`).
macro_rules! refit_kernel {
    ($name:ident, $ordered:literal, $treelets:literal) => {
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $name(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[Triangle],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_words: &mut [u64],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &mut [u32],
            #[spirv(workgroup)] st: &mut RefitState,
        ) {
            refit::clear(lid.x, st);
            barrier();
            let group = flat_group(gid.x, gid.y);
            let prims = refit::Prims { order, tris, spheres };
            refit::refit::<$ordered, $treelets, true>(lid.x, group, st, p, prims, parents, visits, node_words);
        }
    };
}

refit_kernel!(refit_treelets, true, true);
refit_kernel!(refit_treelets_relaxed, false, true);

/// The counter refit of a tree restructured before (`shared::refit::restructured`):
/// specialisation constant 0 its variant, `ORDERED_COUNTERS` (not on lavapipe) plus
/// `RESTRUCTURE` for a further round of treelets.
#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn refit_restructured(
    #[spirv(local_invocation_id)] lid: UVec3,
    #[spirv(workgroup_id)] gid: UVec3,
    #[spirv(spec_constant(id = 0, default = 3))] variant: u32,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[Triangle],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_words: &mut [u64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &mut [u32],
    #[spirv(workgroup)] st: &mut RefitState,
) {
    let prims = refit::Prims { order, tris, spheres };
    let group = flat_group(gid.x, gid.y);
    refit::restructured(variant, lid.x, group, st, p, prims, parents, visits, node_words);
}

/// The box fit (`shared::refit::fit`): `fit`, and `fit_wide`, deciding the wide collapse on the way (`shared::wide`);
/// constant 0 a sum of `refit::FIT_ORDERED` (not on lavapipe) and, for `fit`, `refit::FIT_PAIRS`. Unformatted: as
/// rustfmt lays it out, the sort kernels below compile 30% slower at 1M keys (H200; bench/NOTES.md, session 60).
#[rustfmt::skip]
macro_rules! fit_kernel {
    ($name:ident, $wide:literal) => {
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $name(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(spec_constant(id = 0, default = 1))] ordered: u32,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[Triangle],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_words: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_quads: &mut [spirv_std::glam::UVec4],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 13)] scratch: &mut [u32],
            #[spirv(workgroup)] st: &mut FitState,
        ) {
            let group = flat_group(gid.x, gid.y);
            let leaf = refit::fit_leaf(lid.x, group, p, refit::Prims { order, tris, spheres });
            refit::fit_clear(lid.x, st);
            barrier();
            refit::fit_links(lid.x, group, st, p, visits, node_words);
            barrier();
            let nodes = &mut refit::FitNodes::bound(node_words, node_quads);
            let (lane, pairs) = (lid.x, !$wide && ordered & refit::FIT_PAIRS != 0);
            match (ordered & refit::FIT_ORDERED != 0, pairs) {
                (true, true) => refit::fit::<true, $wide, true>(lane, group, st, p, leaf, parents, visits, nodes, scratch),
                (true, false) => refit::fit::<true, $wide, false>(lane, group, st, p, leaf, parents, visits, nodes, scratch),
                (false, true) => refit::fit::<false, $wide, true>(lane, group, st, p, leaf, parents, visits, nodes, scratch),
                (false, false) => refit::fit::<false, $wide, false>(lane, group, st, p, leaf, parents, visits, nodes, scratch),
            }
        }
    };
}
fit_kernel!(fit, false);
fit_kernel!(fit_wide, true);

/// Before a refit of a kept tree: every internal node's box emptied
/// (`shared::refit::empty_box`), for `fit` to fit again.
#[spirv(compute(threads(256)))]
pub fn empty_boxes(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_words: &mut [u32],
) {
    refit::empty_box(flat_index(id.x, id.y), p, node_words);
}

/// The buffers of a radix sort pass.
struct SortIo<'a, K> {
    keys_in: &'a [K],
    vals_in: &'a [u32],
    keys_out: &'a mut [K],
    vals_out: &'a mut [u32],
    counts: &'a mut [u32],
    totals: &'a mut [u32],
}

/// A radix sort pass, lanes owning `I` keys (see `shared::radix_sort`).
fn scatter<K: SortKey, const I: u32>(lane: u32, p: &BuildParams, io: SortIo<K>, st: &mut ScatterState) {
    sort::scatter_claim(lane, st, p, io.totals);
    barrier();
    let owned = sort::scatter_count::<K, I>(lane, st, p, io.keys_in, io.vals_in, io.totals);
    barrier();
    sort::scatter_sums(lane, st);
    barrier();
    scan::rake(lane, &mut st.scan);
    barrier();
    scan::rake_totals(lane, &mut st.scan);
    barrier();
    sort::scatter_offsets(lane, st, p, io.counts);
    barrier();
    while sort::looking_back(st) {
        sort::lookback_load(lane, st, p, io.counts);
        barrier();
        sort::lookback_sum(lane, st, p, io.counts);
        barrier();
    }
    let staged = sort::scatter_rank::<K, I>(lane, st, p, owned);
    barrier();
    sort::scatter_stage_keys(st, &staged, 0);
    barrier();
    let lo = sort::scatter_staged::<I>(lane, st);
    if K::WORDS == 2 {
        barrier();
        sort::scatter_stage_keys(st, &staged, 1);
        barrier();
    }
    let at = sort::scatter_write_keys::<K, I>(lane, st, p, &lo, io.keys_out);
    barrier();
    sort::scatter_stage_vals(st, &staged);
    barrier();
    sort::scatter_write_vals(lane, st, &at, io.vals_out);
}

/// A radix sort pass's entry point, lanes owning `$items` keys of type `$k`.
macro_rules! scatter_kernel {
    ($(#[$doc:meta])* $name:ident, $k:ty, $items:expr) => {
        $(#[$doc])*
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $name(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys_in: &[$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] vals_in: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] keys_out: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] vals_out: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] counts: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] totals: &mut [u32],
            #[spirv(workgroup)] st: &mut ScatterState,
        ) {
            let io = SortIo { keys_in, vals_in, keys_out, vals_out, counts, totals };
            scatter::<$k, { $items }>(lid.x, p, io, st);
        }
    };
}

/// The kernels that depend on the Morton key width, for `u32` (30-bit) and `u64` (63-bit).
macro_rules! key_kernels {
    ($k:ty, $code:ident, $code_of:ident, $morton:ident, $morton_counted:ident, $scatter:ident, $scatter_many:ident, $runs:ident, $instance_runs:ident, $merge:ident, $build:ident, $ploc:ident) => {
        /// Morton codes and every sort pass's digit counts (see `shared::radix_sort`).
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $morton_counted(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] b: &OrderedBounds,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] vals: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] summaries: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] totals: &mut [u32],
            #[spirv(workgroup)] st: &mut DigitCounts,
        ) {
            let group = flat_group(gid.x, gid.y);
            sort::digits_clear(lid.x, st);
            barrier();
            sort::count_codes(lid.x, group, st, p, b, summaries, keys, vals, morton::$morton);
            barrier();
            sort::digits_store(lid.x, st, p, totals);
        }

        scatter_kernel!(
            /// A radix sort pass (see `shared::radix_sort`) whose lanes own `FEW` keys.
            $scatter,
            $k,
            { sort::FEW }
        );
        scatter_kernel!(
            /// A radix sort pass whose lanes own `SORT_ITEMS` keys (large sorts).
            $scatter_many,
            $k,
            SORT_ITEMS
        );

        /// The merge sort's runs kernel (see `shared::merge_sort`), the build's Morton stage:
        /// workgroup g's codes, its run sorted into bindings 3 and 4, the codes into 5.
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $runs(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] b: &OrderedBounds,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] vals: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] codes: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] summaries: &[[f32; 4]],
            #[spirv(workgroup)] st: &mut RunState<$k>,
        ) {
            let group = flat_group(gid.x, gid.y);
            let key = morton::$code(group * merge_sort::RUN + lid.x, p, b, summaries);
            merge_sort::run_load(lid.x, group, key, st, p, codes);
            barrier();
            merge_sort::run_rank(lid.x, group, st, p, keys, vals);
        }

        /// The runs kernel of a top level's build after the first (`shared::bounds::
        /// instance_summary`): workgroup g's instances' world boxes into binding 0, their
        /// codes from the last build's bounds (`b[1]`), this build's reduced into `b[0]`,
        /// the run sorted as `$runs` sorts it.
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $instance_runs(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] boxes: &mut [Triangle],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] b: &mut [OrderedBounds],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] vals: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] codes: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
            #[spirv(workgroup)] st: &mut RunState<$k>,
            #[spirv(workgroup)] reduced: &mut BoundsState,
        ) {
            bounds::clear(lid.x, reduced);
            barrier();
            let group = flat_group(gid.x, gid.y);
            let i = group * merge_sort::RUN + lid.x;
            let s = bounds::instance_summary(i, reduced, p, instances, objects, boxes);
            let key = morton::$code_of(s, at(b, 1));
            merge_sort::run_load(lid.x, group, key, st, p, codes);
            barrier();
            bounds::flush(lid.x, reduced, at_mut(b, 0));
            merge_sort::run_rank(lid.x, group, st, p, keys, vals);
        }

        /// The merge sort's merge kernel: workgroup g places run g's keys.
        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $merge(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &[$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] vals: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] keys_out: &mut [$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] vals_out: &mut [u32],
            #[spirv(workgroup)] st: &mut MergeState<$k>,
        ) {
            let group = flat_group(gid.x, gid.y);
            let key = merge_sort::merge_key(lid.x, group, p, keys);
            let mut place = lid.x;
            let runs = p.n.div_ceil(merge_sort::RUN);
            let mut first = 0;
            while first < runs {
                merge_sort::merge_load(lid.x, first, st, p, keys);
                barrier();
                place += merge_sort::merge_count(group, first, key, st);
                barrier();
                first += merge_sort::BATCH;
            }
            merge_sort::merge_place(lid.x, group, place, p, key, vals, keys_out, vals_out);
        }

        #[spirv(compute(threads(256)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $build(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &[$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] node_words: &mut [spirv_std::glam::UVec4],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] bounds: &mut [OrderedBounds],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] counts: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] totals: &mut [u32],
        ) {
            let i = flat_index(id.x, id.y);
            if karras::warm(i, p, keys) {
                return;
            }
            karras::build(i, p, keys, node_words, parents, visits);
            // The sort and the Morton stage are done with these: reset for the next build.
            sort::clear_tables(i, p, counts, totals);
            bounds::publish(i, bounds);
        }

        /// The tree and its boxes by H-PLOC (`shared::ploc`), instead of the Karras kernel and
        /// the fit; it resets the sort's tables and publishes the bounds as the Karras kernel
        /// does. Specialisation constant 0 is 1 for the ordered link exchange and device-scope
        /// barriers, 0 for relaxed ones and workgroup barriers (lavapipe).
        #[spirv(compute(threads(32)))]
        #[allow(clippy::too_many_arguments)]
        pub fn $ploc(
            #[spirv(local_invocation_id)] lid: UVec3,
            #[spirv(workgroup_id)] gid: UVec3,
            #[spirv(spec_constant(id = 0, default = 1))] ordered: u32,
            #[spirv(push_constant)] p: &BuildParams,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[Triangle],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] bounds: &mut [OrderedBounds],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] keys: &[$k],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] reps: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] counts: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] words: &mut [u64],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] totals: &mut [u32],
            #[spirv(workgroup)] st: &mut PlocState,
        ) {
            let group = flat_group(gid.x, gid.y);
            let i = group * ploc::GROUP + lid.x;
            sort::clear_tables(i, p, counts, totals);
            bounds::publish(i, bounds);
            let mut b = ploc::Buffers {
                keys,
                order,
                tris,
                spheres,
                words,
                parents,
                visits,
                reps,
            };
            ploc::start(lid.x, group, st, p, &mut b);
            barrier();
            let mut round = 0;
            loop {
                if ordered != 0 {
                    ploc::climb::<$k, true>(lid.x, round, st, p, &mut b);
                } else {
                    ploc::climb::<$k, false>(lid.x, round, st, p, &mut b);
                }
                barrier();
                let mut want = ploc::wanted(lid.x, round, st);
                while want != 0 {
                    let w = want.trailing_zeros();
                    want &= want - 1;
                    ploc::load(lid.x, w, st, p, &b);
                    barrier();
                    loop {
                        ploc::compact_stage(lid.x, st);
                        barrier();
                        ploc::compact_back(lid.x, st);
                        barrier();
                        if st.count <= ploc::target(w, st, p) {
                            break;
                        }
                        ploc::areas(lid.x, st);
                        barrier();
                        ploc::nearest(lid.x, st);
                        barrier();
                        ploc::merge(lid.x, st, &mut b);
                        barrier();
                    }
                    ploc::finish(lid.x, w, st, p, &mut b);
                    // Every lane's stores before the lane's release at its next link.
                    if ordered != 0 {
                        all_barrier();
                    } else {
                        barrier();
                    }
                }
                if !ploc::any_live(round, st) {
                    break;
                }
                round += 1;
                barrier();
            }
        }
    };
}

key_kernels!(
    u32,
    code30,
    code30_of,
    morton30,
    morton30_counted,
    sort_scatter_u32,
    sort_scatter_many_u32,
    sort_runs_u32,
    instance_runs_u32,
    sort_merge_u32,
    karras_build_u32,
    ploc_u32
);
key_kernels!(
    u64,
    code63,
    code63_of,
    morton63,
    morton63_counted,
    sort_scatter_u64,
    sort_scatter_many_u64,
    sort_runs_u64,
    instance_runs_u64,
    sort_merge_u64,
    karras_build_u64,
    ploc_u64
);

/// The wide collapse's last stage, after `fit_wide`: every root writes its wide node.
#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn wide_write(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] nodes: &[spirv_std::glam::UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] ends: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 13)] scratch: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] out: &mut [spirv_std::glam::UVec4],
) {
    wide::write(flat_index(id.x, id.y), p, nodes, parents, ends, scratch, out);
}

/// After the tree's boxes are final: each internal node's pair, its children as the walk
/// reads them (`shared::traverse::write_pairs`); with specialisation constant 0 set, after a
/// fit that wrote the boxes into the pairs (`shared::refit::FIT_PAIRS`), only the entries of
/// the nodes above its blocks (`shared::refit::pair_entry_above`).
#[spirv(compute(threads(256)))]
pub fn pairs_write(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(spec_constant(id = 0, default = 0))] above: u32,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] words: &mut [spirv_std::glam::UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] parents: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] visits: &[u32],
) {
    let i = flat_index(id.x, id.y);
    if above != 0 {
        refit::pair_entry_above(i, p.n, parents, visits, words);
    } else {
        shared::traverse::write_pairs(i, p.n, words);
    }
}

#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn transform(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &mut [spirv_std::glam::UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &mut [Sphere],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 1)] model_tris: &[Triangle],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 2)] model_spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
) {
    let i = flat_index(id.x, id.y);
    xform::transform(i, p, objects, prim_object, model_tris, model_spheres, tris, spheres);
}

/// `transform` in a frame that builds: the bounds' reduction on the way, as `bounds_reduce`'s
/// (`shared::bounds::accumulate_transformed`), `items_per_lane` primitives a lane.
#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn transform_bounds(
    #[spirv(local_invocation_id)] lid: UVec3,
    #[spirv(workgroup_id)] gid: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &mut [spirv_std::glam::UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &mut [Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] out: &mut OrderedBounds,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] summaries: &mut [[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 1)] model_tris: &[Triangle],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 2)] model_spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
    #[spirv(workgroup)] st: &mut BoundsState,
) {
    bounds::clear(lid.x, st);
    barrier();
    let group = flat_group(gid.x, gid.y);
    bounds::accumulate_transformed(
        lid.x,
        group,
        st,
        p,
        objects,
        prim_object,
        model_tris,
        model_spheres,
        tris,
        spheres,
        summaries,
    );
    barrier();
    bounds::flush(lid.x, st, out);
}

/// The top level's inputs: each instance's world box (`shared::instance::instance_box`) into
/// set 0's triangles, which the top level's build then reads.
#[spirv(compute(threads(256)))]
pub fn instance_boxes(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] boxes: &mut [Triangle],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
) {
    shared::instance::instance_box(flat_index(id.x, id.y), p.n, instances, objects, boxes);
}

/// The top level's inputs and their bounds in one kernel (`shared::bounds::
/// accumulate_instances`): each instance's world box into set 0's triangles, its summary and
/// the bounds' reduction as `bounds_reduce`'s, for the top level's build (its refits, which
/// keep the bounds, take `instance_boxes`).
#[spirv(compute(threads(256)))]
#[allow(clippy::too_many_arguments)]
pub fn instance_bounds(
    #[spirv(local_invocation_id)] lid: UVec3,
    #[spirv(workgroup_id)] gid: UVec3,
    #[spirv(push_constant)] p: &BuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] boxes: &mut [Triangle],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] out: &mut OrderedBounds,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] summaries: &mut [[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(workgroup)] st: &mut BoundsState,
) {
    bounds::clear(lid.x, st);
    barrier();
    let group = flat_group(gid.x, gid.y);
    bounds::accumulate_instances(lid.x, group, st, p, instances, objects, boxes, spheres, summaries);
    barrier();
    bounds::flush(lid.x, st, out);
}

/// The compute kernels over the scene (the path tracer's, `cast_rays`): the push constants,
/// every binding the path loop reads and the scene made of them (`$w`), then `$body`; `$p`,
/// `$w`, `$accum` and `$guides` are named by the caller (`_accum`, `_guides` where unused),
/// extra parameters (built-ins, further bindings) come first.
macro_rules! scene_kernel {
    ($(#[$attr:meta])* $name:ident($($(#[$pattr:meta])* $param:ident: $ty:ty),*) |$p:ident, $w:ident, $accum:ident, $guides:ident| $body:block) => {
        $(#[$attr])*
        #[allow(clippy::too_many_arguments)]
        pub fn $name(
            $($(#[$pattr])* $param: $ty,)*
            #[spirv(push_constant)] $p: &RenderPush,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[UVec4],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] nodes: &[UVec4],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] wide: &[UVec4],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 4)] materials: &[Material],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 5)] lights: &[u32],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
            #[spirv(storage_buffer, descriptor_set = 1, binding = 7)] $accum: &mut [[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 11)] attrs: &[VertexAttrs],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 12)] punctual: &[PunctualLight],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 13)] env: &[EnvEntry],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 14)] textures: &[TextureInfo],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 15)] texels: &[u32],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 16)] $guides: &mut [[u32; 4]],
            #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
            #[spirv(spec_constant(id = 0, default = 130111))] features: u32,
        ) {
            let $w = world!(
                tris,
                spheres,
                nodes,
                wide,
                order,
                instances,
                objects,
                prim_object,
                materials,
                lights,
                frame,
                attrs,
                punctual,
                env,
                textures,
                texels,
                features
            );
            $body
        }
    };
}

scene_kernel! {
    /// The path tracer in 8x8 tiles, an invocation a pixel (`path::render_pixel`).
    #[spirv(compute(threads(8, 8)))]
    path_trace(
        #[spirv(global_invocation_id)] id: UVec3,
        #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32]
    ) |p, w, accum, guides| {
        path::render_pixel(id.x, id.y, p, &w, &mut path::Walk, accum, guides, image);
    }
}

scene_kernel! {
    /// `path_trace` persistent (`path::render_tiles`): what every frame runs off lavapipe
    /// (`GpuRenderer::path_kernel`).
    #[spirv(compute(threads(1024)))]
    path_trace_persistent(
        #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32]
    ) |p, w, accum, guides| {
        path::render_tiles(p, &w, &mut path::Walk, accum, guides, image);
    }
}

// The stepped path loop (`path::stepped_pixels`: frames the host marks `VARIANT_STEPPED`), in
// entry points of their own, so that the segment loop's modules hold one loop.

scene_kernel! {
    /// `path_trace` through the stepped loop (`path::stepped_pixel`).
    #[spirv(compute(threads(8, 8)))]
    path_stepped(
        #[spirv(global_invocation_id)] id: UVec3,
        #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32]
    ) |p, w, accum, guides| {
        path::stepped_pixel(id.x, id.y, p, &w, accum, guides, image);
    }
}

scene_kernel! {
    /// `path_trace_persistent` through the stepped loop (`path::stepped_tiles`).
    #[spirv(compute(threads(1024)))]
    path_stepped_persistent(
        #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32]
    ) |p, w, accum, guides| {
        path::stepped_tiles(p, &w, accum, guides, image);
    }
}

// The shadow queue (a scene in two levels with next-event estimation): the path tracer of one
// sample a pixel of a band of rows queues its shadow rays in binding 9 (the ray casts' rays:
// a binding more would pass lavapipe's 32 storage buffers a kernel), `shadow_resolve` casts
// them and adds the samples. Entry points of their own, so that each module holds one path
// loop (one module holding both made NVIDIA's driver crash).

scene_kernel! {
    /// `path_trace` for the shadow queue (`path::queue_pixel`, rows from `p.row_base`).
    #[spirv(compute(threads(8, 8)))]
    path_queue(
        #[spirv(global_invocation_id)] id: UVec3,
        #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] queue: &mut [[f32; 4]]
    ) |p, w, _accum, guides| {
        path::queue_pixel(id.x, p.row_base + id.y, p, &w, guides, queue);
    }
}

scene_kernel! {
    /// `path_trace_persistent` for the shadow queue (`path::queue_tiles`).
    #[spirv(compute(threads(1024)))]
    path_queue_persistent(
        #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] queue: &mut [[f32; 4]]
    ) |p, w, _accum, guides| {
        path::queue_tiles(p, &w, guides, queue);
    }
}

scene_kernel! {
    /// The shadow rays `path_queue` queued, cast, and each pixel's sample added
    /// (`path::resolve_pixel`): an invocation a pixel of the band.
    #[spirv(compute(threads(256)))]
    shadow_resolve(
        #[spirv(global_invocation_id)] id: UVec3,
        #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] queue: &[[f32; 4]]
    ) |p, w, accum, guides| {
        path::resolve_pixel(flat_index(id.x, id.y), p, &w, &mut path::Walk, accum, guides, queue);
    }
}

scene_kernel! {
    /// `shadow_resolve` persistent (`path::resolve_tiles`): a lane starts its next shadow ray
    /// as soon as its walk ends.
    #[spirv(compute(threads(1024)))]
    shadow_resolve_persistent(
        #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] queue: &[[f32; 4]]
    ) |p, w, accum, guides| {
        path::resolve_tiles(p, &w, accum, guides, queue);
    }
}

// The denoiser (`shared::denoise`): its own buffers in set 0 (a set of the build's layout:
// guides, history, filter, output), the frame and display image of set 1.

#[spirv(compute(threads(8, 8)))]
pub fn denoise_temporal(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &DenoisePush,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] guides: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] history: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] filter: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
) {
    if id.x < frame.width {
        denoise::temporal(id.y * frame.width + id.x, p, frame, guides, history, filter);
    }
}

#[spirv(compute(threads(8, 8)))]
pub fn denoise_variance(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &DenoisePush,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] history: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] filter: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
) {
    if id.x < frame.width {
        denoise::variance(id.y * frame.width + id.x, p, frame, history, filter);
    }
}

#[spirv(compute(threads(8, 8)))]
#[allow(clippy::too_many_arguments)]
pub fn denoise_atrous(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &DenoisePush,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] guides: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] history: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] filter: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] output: &mut [[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32],
) {
    if id.x < frame.width {
        let i = id.y * frame.width + id.x;
        denoise::atrous(i, p, frame, guides, history, filter, output, image);
    }
}

#[spirv(compute(threads(256)))]
pub fn display_image(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &RenderPush,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 7)] accum: &[[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32],
) {
    display::display(flat_index(id.x, id.y), p, frame, accum, image);
}

scene_kernel! {
    /// Closest hits of a batch of rays (tests and benchmarks of the traversal).
    #[spirv(compute(threads(256)))]
    cast_rays(
        #[spirv(global_invocation_id)] id: UVec3,
        #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] rays: &[Ray],
        #[spirv(storage_buffer, descriptor_set = 1, binding = 10)] hits: &mut [Hit]
    ) |p, w, _accum, _guides| {
        path::cast(flat_index(id.x, id.y), p, &w, &mut path::Walk, rays, hits);
    }
}

/// `io[3] = fma(io[0], io[1], io[2])`: whether the device's `fma` rounds once
/// (`Kernels::probe_fma`).
#[spirv(compute(threads(1)))]
pub fn fma_probe(#[spirv(storage_buffer, descriptor_set = 0, binding = 0)] io: &mut [f32]) {
    io[3] = shared::math::fma(io[0], io[1], io[2]);
}

/// Adds a persistent path tracer's sample groups' sums to the accumulation
/// (`path::add_groups`): `p.flags` groups of `p.count` pixels.
#[spirv(compute(threads(256)))]
pub fn accum_groups(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &RenderPush,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 7)] accum: &mut [[f32; 4]],
) {
    path::add_groups(flat_index(id.x, id.y), p.count, p.flags, accum);
}
