//! Every type that crosses between host and GPU: `#[repr(C)]`, `Pod`, size asserted.
//!
//! Buffer bindings of the BVH build (descriptor set 0), shared by all build kernels:
//!
//! | binding | contents                                   |
//! |---------|--------------------------------------------|
//! | 0       | `[Triangle]` world-space triangles          |
//! | 1       | `[Sphere]` world-space spheres              |
//! | 2       | `OrderedBounds` scene bounds of centroids   |
//! | 3, 4    | sort input keys, values                     |
//! | 5, 6    | sort output keys, values                    |
//! | 7       | radix sort: per-tile digit counts          |
//! | 8       | `[Node]` the BVH (internal nodes, then leaves) |
//! | 9       | parent of every node                        |
//! | 10      | refit visit counter of every internal node  |
//! | 11      | radix sort: per-super-tile digit sums, every pass |
use bytemuck::{Pod, Zeroable};
use core::mem::size_of;
use spirv_std::glam::Vec3;

/// Invocations per workgroup of every build kernel.
pub const WORKGROUP: u32 = 256;
/// Keys handled by one invocation of the radix sort; a tile is `WORKGROUP * ITEMS` keys.
pub const ITEMS: u32 = 8;
/// Keys per workgroup ("tile") in the bounds, histogram and scatter kernels.
pub const TILE: u32 = WORKGROUP * ITEMS;
/// Marks "no node" (the root's parent) and a leaf's `right` field.
pub const INVALID: u32 = u32::MAX;

/// A triangle in world space; the `w` components are unused.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Triangle {
    pub v0: [f32; 4],
    pub v1: [f32; 4],
    pub v2: [f32; 4],
}

/// A sphere: centre `xyz`, radius `w`.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Sphere {
    pub center_radius: [f32; 4],
}

/// A BVH node (32 bytes). Nodes `0..n-1` are internal, `n-1..2n-1` are leaves; the root is
/// node 0 (for `n == 1` that is the only leaf).
///
/// Internal node: `a` and `b` are the child node indices. Leaf: `a` is the primitive index
/// (triangles first, then spheres) and `b` is [`INVALID`].
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    pub min: [f32; 3],
    pub a: u32,
    pub max: [f32; 3],
    pub b: u32,
}

impl Node {
    pub fn is_leaf(&self) -> bool {
        self.b == INVALID
    }
}

/// Scene bounds of the (doubled) primitive centroids, each component stored as an
/// order-preserving `u32` (see [`f32_to_ordered`]) so that atomic min/max can reduce it.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct OrderedBounds {
    pub min: [u32; 4],
    pub max: [u32; 4],
}

impl OrderedBounds {
    /// The identity of the reduction: min = +largest, max = -largest.
    pub const EMPTY: OrderedBounds = OrderedBounds {
        min: [u32::MAX; 4],
        max: [0; 4],
    };

    pub fn min(&self) -> Vec3 {
        Vec3::new(
            ordered_to_f32(self.min[0]),
            ordered_to_f32(self.min[1]),
            ordered_to_f32(self.min[2]),
        )
    }
    pub fn max(&self) -> Vec3 {
        Vec3::new(
            ordered_to_f32(self.max[0]),
            ordered_to_f32(self.max[1]),
            ordered_to_f32(self.max[2]),
        )
    }
}

/// Push constants of every build kernel.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct BuildParams {
    /// Number of triangles; primitive `i` is a triangle when `i < n_tris`, else a sphere.
    pub n_tris: u32,
    /// Number of primitives (triangles + spheres).
    pub n: u32,
    /// Radix sort: bit offset of the digit this pass sorts by.
    pub shift: u32,
    /// Radix sort: number of tiles, `ceil(n / TILE)`.
    pub tiles: u32,
}

/// Maps an `f32` to a `u32` with the same order (`-0.0` just below `+0.0`):
///
/// ```text
/// sign 1: s eeeeeeee mmm..  ->  !bits          (more negative -> smaller)
/// sign 0: 0 eeeeeeee mmm..  ->  bits | 1<<31   (above every negative)
/// ```
pub fn f32_to_ordered(f: f32) -> u32 {
    let b = f.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Inverse of [`f32_to_ordered`].
pub fn ordered_to_f32(u: u32) -> f32 {
    if u & 0x8000_0000 != 0 {
        f32::from_bits(u & 0x7FFF_FFFF)
    } else {
        f32::from_bits(!u)
    }
}

pub fn xyz(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Axis-aligned box of primitive `i`.
pub fn prim_box(i: u32, n_tris: u32, tris: &[Triangle], spheres: &[Sphere]) -> (Vec3, Vec3) {
    if i < n_tris {
        let t = tris[i as usize];
        let (a, b, c) = (xyz(t.v0), xyz(t.v1), xyz(t.v2));
        (a.min(b).min(c), a.max(b).max(c))
    } else {
        let s = spheres[(i - n_tris) as usize].center_radius;
        let r = Vec3::splat(s[3].abs());
        (xyz(s) - r, xyz(s) + r)
    }
}

/// Twice the centroid of primitive `i`'s box, `min + max`: one exact-or-rounded addition and no
/// multiplication, so no backend can fuse it differently.
pub fn prim_centroid2(i: u32, n_tris: u32, tris: &[Triangle], spheres: &[Sphere]) -> Vec3 {
    if i < n_tris {
        let (lo, hi) = prim_box(i, n_tris, tris, spheres);
        lo + hi
    } else {
        let c = xyz(spheres[(i - n_tris) as usize].center_radius);
        c + c
    }
}

const _: () = assert!(size_of::<Triangle>() == 48);
const _: () = assert!(size_of::<Sphere>() == 16);
const _: () = assert!(size_of::<Node>() == 32);
const _: () = assert!(size_of::<OrderedBounds>() == 32);
const _: () = assert!(size_of::<BuildParams>() == 16);

/// Workgroups per dispatch row: dispatches larger than this use the y dimension.
pub const GRID_X: u32 = 32768;

/// The dispatch shape `(x, y)` for `groups` workgroups.
pub fn grid(groups: u32) -> (u32, u32) {
    if groups <= GRID_X {
        (groups, 1)
    } else {
        (GRID_X, groups.div_ceil(GRID_X))
    }
}

/// Flat workgroup index of a tile kernel dispatched with [`grid`].
pub fn flat_group(group_x: u32, group_y: u32) -> u32 {
    group_y * GRID_X + group_x
}

/// Flat invocation index of a per-item kernel dispatched with [`grid`].
pub fn flat_index(global_x: u32, global_y: u32) -> u32 {
    global_y * GRID_X * WORKGROUP + global_x
}

/// Loads issued back to back by [`load4`].
pub const GROUP: u32 = 4;
const _: () = assert!(ITEMS.is_multiple_of(GROUP));

/// `buf[first + k * stride]` for `k` in `0..4`, indices past `n - 1` clamped to it (`n >= 1`).
///
/// rust-gpu 0.11 emits no loop-unroll hints and the GPU compiler does not unroll loops with
/// bounds checks, so a loop that loads and then uses one value per iteration waits a full
/// memory round trip per item. Loading four before using any keeps four in flight.
pub fn load4<T: Copy>(buf: &[T], first: u32, stride: u32, n: u32) -> [T; 4] {
    let last = n - 1;
    let a = buf[first.min(last) as usize];
    let b = buf[(first + stride).min(last) as usize];
    let c = buf[(first + 2 * stride).min(last) as usize];
    let d = buf[(first + 3 * stride).min(last) as usize];
    [a, b, c, d]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordered_floats_keep_their_order() {
        let xs = [
            f32::NEG_INFINITY,
            -1e30,
            -1.0,
            -1e-40,
            -0.0,
            0.0,
            1e-40,
            1.0,
            1e30,
            f32::INFINITY,
        ];
        for w in xs.windows(2) {
            assert!(f32_to_ordered(w[0]) < f32_to_ordered(w[1]), "{} !< {}", w[0], w[1]);
        }
        for x in xs {
            assert_eq!(ordered_to_f32(f32_to_ordered(x)).to_bits(), x.to_bits());
        }
    }
}
