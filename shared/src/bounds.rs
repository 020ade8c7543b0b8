//! Scene bounds of the primitive centroids: a multi-workgroup reduction. Each workgroup
//! reduces its primitives ([`items_per_lane`] a lane) into workgroup memory, then merges it into the global [`OrderedBounds`]
//! with six device atomics. Min and max are exact, so the result does not depend on order.
//!
//! The same pass stores each primitive's [`prim_summary`] (centroid and largest side) for the
//! Morton stage, which then reads 16 bytes per primitive instead of the primitive. A frame
//! that transforms its primitives and builds reduces in the transform stage
//! ([`accumulate_transformed`]), a top level in the pass that makes its instances' boxes
//! ([`accumulate_instances`]).
//!
//! Phases: [`clear`] | barrier | [`accumulate`] | barrier | [`flush`]. The bounds buffer holds
//! two [`OrderedBounds`]: the reduction's, which starts as [`OrderedBounds::EMPTY`], and the
//! last build's. A later kernel of the build (after the Morton stage has read them) runs
//! [`publish`], which copies the first into the second and empties the first for the next
//! build, so that no build starts with a fill (the host empties it once when it allocates it).
use crate::instance::{instance_box, world_triangle, Instance};
use crate::sync::{self, at, at_mut};
use crate::transform::transformed;
use crate::types::{
    f32_to_ordered, items_per_lane, prim_summary, tri_summary, BuildParams, Object, OrderedBounds, Sphere, Triangle,
    WORKGROUP,
};
use spirv_std::glam::{UVec4, Vec3};

/// Workgroup memory of the bounds reduction.
pub struct BoundsState {
    pub b: OrderedBounds,
}

/// Stores the [`prim_summary`] of lane's primitives, `$summary` giving primitive `$i`'s, and
/// folds their doubled centroids into the workgroup's bounds: `items_per_lane` primitives,
/// every `WORKGROUP`-th of the group's, in order (the first's is where the fold starts). A
/// macro, not a function taking a closure: a closure holding a kernel's buffers became a
/// function-scope variable of storage-buffer pointers, whose pipeline crashed both lavapipe's
/// and NVIDIA's compilers.
macro_rules! reduce {
    ($lane:expr, $group:expr, $st:expr, $p:expr, $summaries:expr, |$i:ident| $summary:expr) => {{
        let items = items_per_lane($p.n);
        let first = $group * items * WORKGROUP + $lane;
        if first < $p.n {
            let (mut lo, mut hi) = (Vec3::ZERO, Vec3::ZERO);
            for k in 0..items {
                let $i = first + k * WORKGROUP;
                if $i < $p.n {
                    let s = $summary;
                    *at_mut($summaries, $i) = s;
                    let c = Vec3::new(s[0], s[1], s[2]);
                    (lo, hi) = if k == 0 { (c, c) } else { (lo.min(c), hi.max(c)) };
                }
            }
            fold($st, lo, hi);
        }
    }};
}

pub fn clear(lane: u32, st: &mut BoundsState) {
    if lane < 4 {
        st.b.min[lane as usize] = u32::MAX;
        st.b.max[lane as usize] = 0;
    }
}

/// Folds the lane's centroids into the workgroup's bounds and stores each primitive's
/// [`prim_summary`] in `summaries` for the Morton stage.
pub fn accumulate(
    lane: u32,
    group: u32,
    st: &mut BoundsState,
    p: &BuildParams,
    tris: &[Triangle],
    spheres: &[Sphere],
    summaries: &mut [[f32; 4]],
) {
    reduce!(lane, group, st, p, summaries, |i| prim_summary(
        i, p.n_tris, tris, spheres
    ));
}

/// [`accumulate`] in the transform stage of a frame that builds (the `transform_bounds`
/// kernel: the bounds' pass, which read every world primitive back, and a dispatch fewer):
/// lane's primitives moved to world space by [`crate::transform::transformed`], their
/// summaries stored and their centroids folded as [`accumulate`] folds them, in the same
/// order. The CPU executor runs the two apart (the transform, then the build's [`accumulate`]
/// over its output): the same bits, which the GPU = CPU tests of rendered scenes compare.
#[allow(clippy::too_many_arguments)]
pub fn accumulate_transformed(
    lane: u32,
    group: u32,
    st: &mut BoundsState,
    p: &BuildParams,
    objects: &[Object],
    prim_object: &[u32],
    model_tris: &[Triangle],
    model_spheres: &[Sphere],
    tris: &mut [UVec4],
    spheres: &mut [Sphere],
    summaries: &mut [[f32; 4]],
) {
    reduce!(lane, group, st, p, summaries, |i| {
        transformed(i, p, objects, prim_object, model_tris, model_spheres, tris, spheres)
    });
}

/// Folds a lane's bounds into the workgroup's.
fn fold(st: &mut BoundsState, lo: Vec3, hi: Vec3) {
    sync::workgroup_min(&mut st.b.min[0], f32_to_ordered(lo.x));
    sync::workgroup_min(&mut st.b.min[1], f32_to_ordered(lo.y));
    sync::workgroup_min(&mut st.b.min[2], f32_to_ordered(lo.z));
    sync::workgroup_max(&mut st.b.max[0], f32_to_ordered(hi.x));
    sync::workgroup_max(&mut st.b.max[1], f32_to_ordered(hi.y));
    sync::workgroup_max(&mut st.b.max[2], f32_to_ordered(hi.z));
}

/// [`accumulate`] over the top level's inputs: lane's instances' world boxes
/// ([`crate::instance::instance_box`]) written as its primitives first, in the same kernel
/// (the `instance_bounds` kernel: one dispatch fewer in every build of the top level). The
/// CPU executor runs the two apart (`instance_box` for every instance, then [`accumulate`]):
/// the same bits, which the GPU = CPU tests of both levels compare.
#[allow(clippy::too_many_arguments)]
pub fn accumulate_instances(
    lane: u32,
    group: u32,
    st: &mut BoundsState,
    p: &BuildParams,
    instances: &[Instance],
    objects: &[Object],
    boxes: &mut [Triangle],
    spheres: &[Sphere],
    summaries: &mut [[f32; 4]],
) {
    reduce!(lane, group, st, p, summaries, |i| {
        instance_box(i, p.n, instances, objects, boxes);
        prim_summary(i, p.n_tris, boxes, spheres)
    });
}

/// The top level's inputs for a build whose codes take the last build's bounds (the merge
/// sort's runs kernel over instances, `instance_runs_*`: one dispatch and the bounds' pass
/// fewer than [`accumulate_instances`] and the runs kernel): instance `i`'s world box stored
/// as [`instance_box`] stores it, its centroid folded into the workgroup's bounds (this
/// build's, for the next; one primitive a lane) and its [`prim_summary`] returned for its
/// code. Past the last instance: nothing stored or folded, a summary of zeros.
pub fn instance_summary(
    i: u32,
    st: &mut BoundsState,
    p: &BuildParams,
    instances: &[Instance],
    objects: &[Object],
    boxes: &mut [Triangle],
) -> [f32; 4] {
    if i >= p.n {
        return [0.0; 4];
    }
    let t = world_triangle(i, instances, objects);
    *at_mut(boxes, i) = t;
    let s = tri_summary(&t);
    let c = Vec3::new(s[0], s[1], s[2]);
    fold(st, c, c);
    s
}

pub fn flush(lane: u32, st: &BoundsState, out: &mut OrderedBounds) {
    if lane < 3 {
        let k = lane as usize;
        sync::atomic_min(&mut out.min[k], st.b.min[k]);
        sync::atomic_max(&mut out.max[k], st.b.max[k]);
    }
}

/// Invocation 0 of a kernel after the Morton stage: keeps the reduction's bounds as the last
/// build's (`b[1]`) and resets the reduction (`b[0]`) for the next build.
pub fn publish(i: u32, b: &mut [OrderedBounds]) {
    if i == 0 {
        *at_mut(b, 1) = *at(b, 0);
        *at_mut(b, 0) = OrderedBounds::EMPTY;
    }
}
