//! Scene bounds of the primitive centroids: a multi-workgroup reduction. Each workgroup
//! reduces its tile into workgroup memory, then merges it into the global [`OrderedBounds`]
//! with six device atomics. Min and max are exact, so the result does not depend on order.
//!
//! Phases: [`clear`] | barrier | [`accumulate`] | barrier | [`flush`]. The global bounds start
//! as [`OrderedBounds::EMPTY`] (the host fills them before the dispatch).
use crate::sync;
use crate::types::{
    f32_to_ordered, prim_centroid2, BuildParams, OrderedBounds, Sphere, Triangle, ITEMS, TILE, WORKGROUP,
};

/// Workgroup memory of the bounds reduction.
pub struct BoundsState {
    pub b: OrderedBounds,
}

pub fn clear(lane: u32, st: &mut BoundsState) {
    if lane < 4 {
        st.b.min[lane as usize] = u32::MAX;
        st.b.max[lane as usize] = 0;
    }
}

pub fn accumulate(lane: u32, group: u32, st: &mut BoundsState, p: &BuildParams, tris: &[Triangle], spheres: &[Sphere]) {
    let first = group * TILE + lane;
    if first >= p.n {
        return;
    }
    let mut lo = prim_centroid2(first, p.n_tris, tris, spheres);
    let mut hi = lo;
    // Grid-stride over the tile: lane takes every WORKGROUP-th primitive.
    for k in 1..ITEMS {
        let i = first + k * WORKGROUP;
        if i < p.n {
            let c = prim_centroid2(i, p.n_tris, tris, spheres);
            lo = lo.min(c);
            hi = hi.max(c);
        }
    }
    sync::workgroup_min(&mut st.b.min[0], f32_to_ordered(lo.x));
    sync::workgroup_min(&mut st.b.min[1], f32_to_ordered(lo.y));
    sync::workgroup_min(&mut st.b.min[2], f32_to_ordered(lo.z));
    sync::workgroup_max(&mut st.b.max[0], f32_to_ordered(hi.x));
    sync::workgroup_max(&mut st.b.max[1], f32_to_ordered(hi.y));
    sync::workgroup_max(&mut st.b.max[2], f32_to_ordered(hi.z));
}

pub fn flush(lane: u32, st: &BoundsState, out: &mut OrderedBounds) {
    if lane < 3 {
        let k = lane as usize;
        sync::atomic_min(&mut out.min[k], st.b.min[k]);
        sync::atomic_max(&mut out.max[k], st.b.max[k]);
    }
}
