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
    f32_to_ordered, items_per_lane, prim_summary, transform_items, tri_summary, BuildParams, Object, OrderedBounds,
    Sphere, Triangle, WORKGROUP,
};
use spirv_std::glam::{UVec4, Vec3};

/// Workgroup memory of the bounds reduction.
pub struct BoundsState {
    pub b: OrderedBounds,
}

/// Stores the [`prim_summary`] of lane's primitives, `$summary` giving primitive `$i`'s, and
/// folds their doubled centroids into the workgroup's bounds: `items_per_lane` primitives
/// (or `$items`), every `WORKGROUP`-th of the group's, in order (the first's is where the
/// fold starts). A macro, not a function taking a closure: a closure holding a kernel's
/// buffers became a function-scope variable of storage-buffer pointers, whose pipeline
/// crashed both lavapipe's and NVIDIA's compilers.
macro_rules! reduce {
    ($lane:expr, $group:expr, $st:expr, $p:expr, $summaries:expr, |$i:ident| $summary:expr) => {{
        reduce!($lane, $group, $st, $p, $summaries, items_per_lane($p.n), |$i| $summary)
    }};
    ($lane:expr, $group:expr, $st:expr, $p:expr, $summaries:expr, $items:expr, |$i:ident| $summary:expr) => {{
        let items = $items;
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
    reduce!(lane, group, st, p, summaries, transform_items(p.n), |i| {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::transform;
    use crate::types::{item_groups, transform_groups};

    /// One build's bounds reduction on the CPU, workgroup by workgroup and lane by lane, as
    /// the GPU runs it: `accumulate` over lane `l` of group `g < groups` in `phase(l, g, st)`.
    fn reduced(groups: u32, mut phase: impl FnMut(u32, u32, &mut BoundsState)) -> OrderedBounds {
        let mut out = OrderedBounds::EMPTY;
        for g in 0..groups {
            let mut st = BoundsState {
                b: OrderedBounds::EMPTY,
            };
            (0..WORKGROUP).for_each(|l| clear(l, &mut st));
            (0..WORKGROUP).for_each(|l| phase(l, g, &mut st));
            (0..WORKGROUP).for_each(|l| flush(l, &st, &mut out));
        }
        out
    }

    #[test]
    fn the_transform_stage_reduces_the_bounds_of_the_primitives_it_writes() {
        // Several primitives a lane and several workgroups (`items_per_lane` from 131,072),
        // triangles and spheres, objects turned, scaled, moved and one waving: the fused
        // stage must give the bits of the transform followed by the build's own reduction,
        // which the CPU executor runs.
        let (n_tris, n_spheres) = (200_000u32, 3_001u32);
        let n = n_tris + n_spheres;
        assert!(items_per_lane(n) > transform_items(n) && transform_items(n) > 1 && item_groups(n) > 1);
        let mut seed = 0x2545_f491u32;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32 * 20.0 - 10.0
        };
        let vertex = |next: &mut dyn FnMut() -> f32| [next(), next(), next(), 0.0];
        let model_tris: Vec<Triangle> = (0..n_tris)
            .map(|_| Triangle {
                v0: vertex(&mut next),
                v1: vertex(&mut next),
                v2: vertex(&mut next),
            })
            .collect();
        let model_spheres: Vec<Sphere> = (0..n_spheres)
            .map(|_| Sphere {
                center_radius: [next(), next(), next(), next().abs() * 0.1],
            })
            .collect();
        let objects = [
            Object {
                rows: [[0.0, -2.0, 0.0, 3.5], [1.5, 0.0, 0.0, -1.25], [0.0, 0.0, 0.5, 100.0]],
                radius_scale: 2.0,
                ..Default::default()
            },
            Object {
                rows: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
                wave: [0.25, 0.5, 0.125, 0.3],
                radius_scale: 1.0,
                ..Default::default()
            },
        ];
        let prim_object: Vec<u32> = (0..n).map(|i| (i * 7 / 5) % 2).collect();
        let p = BuildParams {
            n_tris,
            n,
            shift: 0,
            passes: 0,
        };

        // Apart: the transform stage, then the build's reduction over what it wrote.
        let mut words = vec![UVec4::ZERO; 3 * n_tris as usize];
        let mut spheres = vec![Sphere::default(); n_spheres as usize];
        (0..n).for_each(|i| {
            transform(
                i,
                &p,
                &objects,
                &prim_object,
                &model_tris,
                &model_spheres,
                &mut words,
                &mut spheres,
            )
        });
        let tris: Vec<Triangle> = words
            .chunks(3)
            .map(|w| {
                let v = |w: UVec4| [w.x, w.y, w.z, w.w].map(f32::from_bits);
                Triangle {
                    v0: v(w[0]),
                    v1: v(w[1]),
                    v2: v(w[2]),
                }
            })
            .collect();
        let mut summaries = vec![[0f32; 4]; n as usize];
        let apart = reduced(item_groups(n), |l, g, st| {
            accumulate(l, g, st, &p, &tris, &spheres, &mut summaries)
        });

        // Fused.
        let mut fused_words = vec![UVec4::ZERO; 3 * n_tris as usize];
        let mut fused_spheres = vec![Sphere::default(); n_spheres as usize];
        let mut fused_summaries = vec![[0f32; 4]; n as usize];
        let fused = reduced(transform_groups(n), |l, g, st| {
            accumulate_transformed(
                l,
                g,
                st,
                &p,
                &objects,
                &prim_object,
                &model_tris,
                &model_spheres,
                &mut fused_words,
                &mut fused_spheres,
                &mut fused_summaries,
            )
        });

        assert_ne!(apart, OrderedBounds::EMPTY);
        assert_eq!(fused, apart, "the bounds");
        assert!(fused_words == words, "the world triangles differ");
        assert!(fused_spheres == spheres, "the world spheres differ");
        let bits = |s: &[[f32; 4]]| s.iter().flat_map(|v| v.map(f32::to_bits)).collect::<Vec<_>>();
        assert!(bits(&fused_summaries) == bits(&summaries), "the summaries differ");
        // The wave moved the second object's vertices off the model's.
        let waving_tri = (0..n_tris).find(|&i| prim_object[i as usize] == 1).unwrap() as usize;
        assert_ne!(tris[waving_tri].v0[1], model_tris[waving_tri].v0[1]);
    }
}
