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
//! | 7       | radix sort: look-back status tables, every pass |
//! | 8       | `[Node]` the BVH (internal nodes, then leaves) |
//! | 9       | parent of every node                        |
//! | 10      | refit: visit counters (treelet builds); far end of every internal node's leaf range |
//! | 11      | radix sort: digit totals and tile counter, every pass |
//! | 12      | `[WideNode]` the wide BVH (`crate::wide`)   |
//! | 13      | the wide collapse's scratch (a word per `wide::slots`) |
use bytemuck::{Pod, Zeroable};
use core::mem::size_of;
use spirv_std::glam::Vec3;

/// Invocations per workgroup of every build kernel.
pub const WORKGROUP: u32 = 256;
/// Most primitives a lane takes in the kernels that reduce over a workgroup's primitives (see
/// [`items_per_lane`]).
pub const ITEMS: u32 = 8;
/// Most keys a lane owns in the radix sort's scatter kernel (`BuildParams::items` of them:
/// see `radix_sort::items`).
pub const SORT_ITEMS: u32 = 16;
/// Most keys per workgroup ("tile") in the scatter kernel.
pub const TILE: u32 = WORKGROUP * SORT_ITEMS;

/// Primitives per lane of the kernels that reduce over a workgroup's primitives (bounds,
/// the Morton stage's digit counts): one while that gives at most `SPREAD` workgroups (a
/// small input keeps the GPU's SMs busy, each lane waiting for one primitive), up to
/// `ITEMS` (a large one merges fewer workgroups' results: 256 primitives a workgroup
/// took the H100's Morton stage from 20 to 49 us at 1M, a tile a workgroup the bunny's
/// from 7 to 10).
pub fn items_per_lane(n: u32) -> u32 {
    (n / (WORKGROUP * SPREAD)).clamp(1, ITEMS)
}
const SPREAD: u32 = 256;

/// Workgroups of the kernels that take [`items_per_lane`] primitives a lane.
pub fn item_groups(n: u32) -> u32 {
    n.div_ceil(WORKGROUP * items_per_lane(n))
}

/// Primitives per lane of the transform stage of a frame that builds (`transform_bounds`):
/// [`items_per_lane`], at most [`TRANSFORM_ITEMS`]. Its lanes wait on each primitive's
/// loads in turn, and a workgroup more costs it only its six bounds atomics. The other
/// reductions keep `items_per_lane`: the Morton stage's digit counts cost more a workgroup,
/// and the bounds pass of a build without a transform reads the primitives alone, at its
/// bandwidth with eight a lane (two measured slower at 16M). H200, `bench
/// realtime --instancing off`, rebuild p50 at 8 / 4 / 2 / 1 a lane: sixteen bunnies (1.1M)
/// 0.433 / 0.428 / 0.424 / 0.426 ms, the herd (10M) 2.905 / 2.896 / 2.889 / 2.942
/// (bench/NOTES.md, session 59).
pub fn transform_items(n: u32) -> u32 {
    items_per_lane(n).min(TRANSFORM_ITEMS)
}
pub const TRANSFORM_ITEMS: u32 = 2;

/// Workgroups of the transform stage of a frame that builds ([`transform_items`]).
pub fn transform_groups(n: u32) -> u32 {
    n.div_ceil(WORKGROUP * transform_items(n))
}

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
    /// Radix sort: number of digit passes (see [`crate::radix_sort::passes`]).
    pub passes: u32,
}

impl BuildParams {
    /// Radix sort: keys per tile (lanes own [`crate::radix_sort::items`] keys each).
    pub fn tile_keys(&self) -> u32 {
        WORKGROUP * crate::radix_sort::items(self.n)
    }
    /// Radix sort: number of tiles.
    pub fn tiles(&self) -> u32 {
        self.n.div_ceil(self.tile_keys().max(1))
    }
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

/// Axis-aligned box of primitive `i` (`i < n_tris + spheres.len()`; unchecked on the GPU,
/// see `sync::at`).
pub fn prim_box(i: u32, n_tris: u32, tris: &[Triangle], spheres: &[Sphere]) -> (Vec3, Vec3) {
    if i < n_tris {
        tri_box(crate::sync::at(tris, i))
    } else {
        sphere_box(crate::sync::at(spheres, i - n_tris))
    }
}

/// A sphere's axis-aligned box.
pub fn sphere_box(s: &Sphere) -> (Vec3, Vec3) {
    let r = Vec3::splat(s.center_radius[3].abs());
    let c = xyz(s.center_radius);
    (c - r, c + r)
}

/// What the Morton stage needs of primitive `i`: twice the centroid of its box and the
/// largest side of that box. The doubled centroid is `min + max` for a triangle and `c + c` for
/// a sphere: one exact-or-rounded addition and no multiplication, so no backend can fuse it
/// differently. The bounds stage gathers the primitive once and stores this (16 bytes, where a
/// triangle is 48), so the Morton stage reads a third of the bytes.
pub fn prim_summary(i: u32, n_tris: u32, tris: &[Triangle], spheres: &[Sphere]) -> [f32; 4] {
    if i < n_tris {
        tri_summary(crate::sync::at(tris, i))
    } else {
        sphere_summary(crate::sync::at(spheres, i - n_tris))
    }
}

/// [`prim_summary`] of a sphere.
pub fn sphere_summary(s: &Sphere) -> [f32; 4] {
    let (lo, hi) = sphere_box(s);
    let c = xyz(s.center_radius);
    summary(c + c, lo, hi)
}

/// A triangle's axis-aligned box.
pub fn tri_box(t: &Triangle) -> (Vec3, Vec3) {
    let (a, b, c) = (xyz(t.v0), xyz(t.v1), xyz(t.v2));
    (a.min(b).min(c), a.max(b).max(c))
}

/// [`prim_summary`] of a triangle.
pub fn tri_summary(t: &Triangle) -> [f32; 4] {
    let (lo, hi) = tri_box(t);
    summary(lo + hi, lo, hi)
}

fn summary(c: Vec3, lo: Vec3, hi: Vec3) -> [f32; 4] {
    let d = hi - lo;
    [c.x, c.y, c.z, d.x.max(d.y).max(d.z)]
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

/// `buf[first + k * stride]` for `k` in `0..4`, indices past `n - 1` clamped to it (`n >= 1`,
/// `n <= buf.len()`; unchecked on the GPU, see `sync::at`).
///
/// rust-gpu 0.11 emits no loop-unroll hints and the GPU compiler does not unroll loops with
/// bounds checks, so a loop that loads and then uses one value per iteration waits a full
/// memory round trip per item. Loading four before using any keeps four in flight.
pub fn load4<T: Copy>(buf: &[T], first: u32, stride: u32, n: u32) -> [T; 4] {
    use crate::sync::at;
    let last = n - 1;
    let a = *at(buf, first.min(last));
    let b = *at(buf, (first + stride).min(last));
    let c = *at(buf, (first + 2 * stride).min(last));
    let d = *at(buf, (first + 3 * stride).min(last));
    [a, b, c, d]
}

// ---------------------------------------------------------------------------------------------
// Rendering (descriptor set 1)
//
// | binding | contents                                                  |
// |---------|-----------------------------------------------------------|
// | 0       | `[Object]` transform and material of every object          |
// | 1       | `[Triangle]` model-space triangles                         |
// | 2       | `[Sphere]` model-space spheres                             |
// | 3       | object of every primitive (triangles, then spheres)        |
// | 4       | `[Material]`                                               |
// | 5       | emissive primitives (next-event estimation's lights)       |
// | 6       | `Frame`: camera and render settings                       |
// | 7       | accumulated radiance per pixel, `[f32; 4]` (w: rays traced) |
// | 8       | display image, RGBA8 per pixel                             |
// | 9, 10   | ray casts: `[Ray]` in, `[Hit]` out                         |
// | 11      | `[VertexAttrs]` every mesh's per-vertex normals and UVs, once a mesh |
// | 12      | `[PunctualLight]` point, spot and directional lights       |
// | 13      | `[EnvEntry]` the environment map's texels and alias table  |
// | 14      | `[TextureInfo]` every texture's place and size in binding 15 |
// | 15      | texels of every texture and mip level, RGBA8 in a `u32`    |
// | 16      | `[Guide]` the denoiser's guides (`crate::denoise`)         |
// | 17      | `[Instance]` the instances of an instanced scene (`crate::instance`) |
// ---------------------------------------------------------------------------------------------

/// Storage buffers of descriptor set 1.
pub const RENDER_BINDINGS: u32 = 18;
/// Render kernels run on 8x8 pixel tiles.
pub const TILE_SIDE: u32 = 8;

/// An object: its model-to-world transform (3x4, row-major), its material, and where its
/// primitives and their vertex attributes are.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Object {
    pub rows: [[f32; 4]; 3],
    /// The cofactor matrix of `rows`' 3x3 part (its inverse transpose times its determinant,
    /// row-major, `w` unused): takes model-space normals to world space, on the side the
    /// transformed triangle's own normal (edge cross product) takes, mirrored or not.
    pub normal_rows: [[f32; 4]; 3],
    /// Factor applied to sphere radii: the largest scale of the transform.
    pub radius_scale: f32,
    pub material: u32,
    /// The object's first primitive: its triangles are `first_prim..` (a sphere: itself).
    pub first_prim: u32,
    /// Index of the [`VertexAttrs`] of the object's first triangle (its mesh's attributes,
    /// shared by every object showing the mesh), or [`INVALID`]: flat, no texture
    /// coordinates.
    pub attrs: u32,
    /// A wave that deforms the object's triangles every frame ([`crate::transform::waved`]):
    /// amplitude (model-space units along y; 0: none), waves per unit along x and along z,
    /// and the phase (in waves) at the frame's moment.
    pub wave: [f32; 4],
}

/// Vertex attributes of one mesh triangle in model space (64 bytes): vertex `k`'s shading
/// normal in `normal_u[k].xyz` (all zero: the mesh has none there; the geometric normal
/// shades) and its texture coordinates `(normal_u[k].w, v[k])`.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct VertexAttrs {
    pub normal_u: [[f32; 4]; 3],
    /// `v` of vertices 0, 1, 2; `w` unused.
    pub v: [f32; 4],
}

/// How a surface scatters light.
#[repr(u32)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub enum MaterialKind {
    /// Ideal diffuse reflection (Lambert).
    #[default]
    Diffuse = 0,
    /// Mirror reflection, blurred by `roughness`.
    Metal = 1,
    /// Smooth glass: Fresnel reflection and refraction with `ior`.
    Dielectric = 2,
    /// A light that does not scatter.
    Emissive = 3,
    /// glTF's metallic-roughness model: GGX specular over Lambert diffuse, mixed with a GGX
    /// metal by `metallic` (`crate::pbr`).
    Pbr = 4,
}

/// [`Material::textures`] slots.
pub const TEX_BASE_COLOR: usize = 0;
/// Metallic (blue) and roughness (green), multiplying the factors.
pub const TEX_METAL_ROUGH: usize = 1;
/// Tangent-space normal map.
pub const TEX_NORMAL: usize = 2;
pub const TEX_EMISSIVE: usize = 3;

/// A material (112 bytes): `kind` is a [`MaterialKind`]; every kind may also emit `emission`.
/// A zeroed material is black diffuse without textures, so `..Default::default()` fills the
/// rest of any material soundly.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Material {
    /// Reflectance, the base colour (`xyz`); `w` unused.
    pub albedo: [f32; 4],
    /// Emitted radiance (`xyz`); `w` unused.
    pub emission: [f32; 4],
    pub kind: u32,
    /// Metal: blur radius; PBR: perceptual roughness (GGX alpha = roughness^2).
    pub roughness: f32,
    pub ior: f32,
    /// PBR: 0 dielectric, 1 metal.
    pub metallic: f32,
    /// Textures by slot (`TEX_*`): index + 1 into the texture table, 0 for none.
    pub textures: [u32; 4],
    /// Texture coordinate transform (glTF `KHR_texture_transform`) minus the identity, so
    /// that zeros leave coordinates alone: `uv' = uv + (r0 . (u, v, 1), r1 . (u, v, 1))`.
    pub uv_delta: [[f32; 4]; 2],
    /// [`ALPHA_MASK`]: where the coverage (`alpha` times the base colour texture's alpha)
    /// falls below this the surface is a hole (glTF `alphaCutoff`).
    pub alpha_cutoff: f32,
    /// Base colour alpha factor (glTF `baseColorFactor[3]`): the coverage without a texture.
    pub alpha: f32,
    /// Strength of the normal map (glTF `normalTexture.scale`).
    pub normal_scale: f32,
    /// [`ALPHA_OPAQUE`], [`ALPHA_MASK`] or [`ALPHA_BLEND`] (glTF `alphaMode`); rays pass
    /// through holes with [`FEATURE_ALPHA`] (`crate::alpha`).
    pub alpha_mode: u32,
}

/// [`Material::alpha_mode`]: every point of the surface is hit (alpha ignored).
pub const ALPHA_OPAQUE: u32 = 0;
/// A point is hit where its coverage reaches [`Material::alpha_cutoff`], else a hole.
pub const ALPHA_MASK: u32 = 1;
/// A point is hit with probability equal to its coverage (stochastic transparency, which a
/// path tracer's average turns into alpha blending).
pub const ALPHA_BLEND: u32 = 2;

/// [`PunctualLight::kind`]: light from a point, the same in every direction.
pub const LIGHT_POINT: u32 = 0;
/// A point light that shines into a cone (`cos_outer`, `cos_inner` about `direction`).
pub const LIGHT_SPOT: u32 = 1;
/// Light from infinitely far away along `direction`.
pub const LIGHT_DIRECTIONAL: u32 = 2;

/// A light without area (glTF's `KHR_lights_punctual`), in world space (64 bytes). Point and
/// spot lights have a radiant intensity (`intensity`, per steradian: irradiance
/// `intensity / d^2` at distance `d`), directional lights an irradiance (`intensity` on a
/// surface facing them). Next-event estimation reaches them; rays never hit them.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PunctualLight {
    /// Position (`xyz`, point and spot); `w` unused.
    pub position: [f32; 4],
    /// Unit direction the light shines along (`xyz`, spot and directional); `w`: the spot's
    /// `cos_outer` (no light outside that cone).
    pub direction: [f32; 4],
    /// Colour times intensity (`xyz`); `w`: the spot's `cos_inner` (full light inside).
    pub intensity: [f32; 4],
    pub kind: u32,
    pub _pad: [u32; 3],
}

/// Thin-lens camera (pinhole when `lens_radius == 0`): the image plane lies at the focus
/// distance, spanned from `lower_left` by `horizontal` and `vertical`.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Camera {
    pub origin: [f32; 4],
    pub lower_left: [f32; 4],
    pub horizontal: [f32; 4],
    pub vertical: [f32; 4],
    /// Unit vectors of the lens plane (`w` of `u`: lens radius).
    pub u: [f32; 4],
    pub v: [f32; 4],
}

/// Flags of [`Frame::flags`].
pub const FLAG_NEE: u32 = 1;
pub const FLAG_RUSSIAN_ROULETTE: u32 = 2;
/// Trace through the BVH (otherwise test every primitive: the thesis's brute force).
pub const FLAG_BVH: u32 = 4;
/// Display with the thesis's gamma 1/2 instead of the sRGB curve.
pub const FLAG_GAMMA2: u32 = 8;
/// Weight next-event estimation and BSDF sampling by multiple importance sampling.
pub const FLAG_MIS: u32 = 16;
/// The frame is denoised (`crate::denoise`): the host derives `FEATURE_GUIDES` from it.
pub const FLAG_DENOISE: u32 = 32;

/// Camera and settings of a render.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Frame {
    pub camera: Camera,
    /// The camera of the previous frame (the denoiser's motion vectors; `camera` where
    /// there is none).
    pub prev_camera: Camera,
    /// Radiance of rays that leave the scene: `sky_top` straight up, `sky_bottom` down.
    pub sky_top: [f32; 4],
    pub sky_bottom: [f32; 4],
    pub width: u32,
    pub height: u32,
    pub max_depth: u32,
    pub flags: u32,
    pub n_tris: u32,
    pub n_prims: u32,
    pub n_lights: u32,
    pub seed: u32,
    pub exposure: f32,
    /// `FEATURE_*` bits the path tracer needs for this scene. The CPU executor tests them at
    /// run time; the GPU runs `path_trace` specialised to them (specialisation constant 0).
    pub features: u32,
    /// Number of punctual lights (binding 12).
    pub n_punctual: u32,
    /// The environment map (binding 13, with [`FEATURE_ENVMAP`]): its size, its turn about
    /// `+y` (cosine, sine), the factor on its radiance, and the probability with which
    /// next-event estimation samples it rather than the other lights.
    pub env_width: u32,
    pub env_height: u32,
    pub env_rotation: [f32; 2],
    pub env_intensity: f32,
    pub env_prob: f32,
    /// Angle a camera ray's cone opens per pixel (radians): texture level of detail by ray
    /// cones (`crate::texture`).
    pub pixel_spread: f32,
    /// Where the objects' previous-frame transforms start in the objects binding: object
    /// `o` was `objects[prev_objects + o]` (0: nothing moved).
    pub prev_objects: u32,
    /// Instances of an instanced scene (`FEATURE_INSTANCES`; render binding 17), and the
    /// first node of its top level in the node buffer (`traverse::Scene::top`).
    pub n_instances: u32,
    pub top_nodes: u32,
    pub _pad: [u32; 3],
}

/// Push constants of the render kernels.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct RenderPush {
    /// Samples per pixel accumulated before this dispatch (the first sample's index).
    pub sample_base: u32,
    /// Samples per pixel this dispatch adds (path tracing) or has in all (display).
    pub samples: u32,
    /// Number of rays (ray casts).
    pub count: u32,
    /// `DISPLAY_*` flags (display pass, and path tracer dispatches that display:
    /// [`DISPLAY_IN_TRACE`]), `CAST_*` flags (ray casts), or the sample groups a persistent
    /// stepped dispatch splits each pixel's samples into (with `VARIANT_GROUPS`;
    /// `crate::path::sample_groups`).
    pub flags: u32,
    /// The shadow queue's passes: the band of rows `row_base..row_base + rows` the dispatch
    /// renders (`crate::path::queue_pixel`, `crate::path::resolve_pixel`).
    pub row_base: u32,
    pub rows: u32,
}

// Features a path-tracing kernel can leave out: the bits of its specialisation constant 0
// (and of the CPU executor's `Scene::features`). A scene needs only some; the host derives
// which (`host/src/features.rs`) and the driver folds the branches of the others away.

/// Triangles are intersected.
pub const FEATURE_TRIANGLES: u32 = 1;
/// Spheres are intersected.
pub const FEATURE_SPHERES: u32 = 1 << 1;
/// Next-event estimation (with MIS when the frame asks) toward emissive primitives.
pub const FEATURE_NEE: u32 = 1 << 2;
/// Metal surfaces scatter (else they absorb).
pub const FEATURE_METAL: u32 = 1 << 3;
/// Dielectric surfaces scatter (else they absorb).
pub const FEATURE_DIELECTRIC: u32 = 1 << 4;
/// Camera rays start on a lens disk (else at the pinhole).
pub const FEATURE_THIN_LENS: u32 = 1 << 5;
/// Shading normals interpolated from vertex normals (else the geometric normal shades).
pub const FEATURE_SHADING_NORMALS: u32 = 1 << 10;
/// Texture coordinates interpolated and material textures sampled.
pub const FEATURE_TEXTURES: u32 = 1 << 11;
/// Tangent-space normal maps perturb the shading normal.
pub const FEATURE_NORMAL_MAPS: u32 = 1 << 12;
/// The metallic-roughness GGX material scatters (else it absorbs).
pub const FEATURE_PBR: u32 = 1 << 13;
/// An HDR environment map lights the scene (else the sky gradient).
pub const FEATURE_ENVMAP: u32 = 1 << 14;
/// Next-event estimation toward punctual lights (point, spot, directional).
pub const FEATURE_PUNCTUAL: u32 = 1 << 15;
/// Alpha-masked and blended triangles: ray queries skip the points they do not cover.
pub const FEATURE_ALPHA: u32 = 1 << 16;
/// The path tracer leaves the denoiser's guides (`crate::denoise::Guide`, binding 16). Not
/// in [`FEATURES_ALL`]: only a denoised frame asks for it.
pub const FEATURE_GUIDES: u32 = 1 << 17;
/// Two levels (`crate::instance`): a top-level BVH over instances of meshes, each with its
/// own BVH in model space (`traverse::Scene::top`). A layout the host sets where the scene
/// is instanced, as [`VARIANT_WIDE_BVH`] is; not in [`FEATURES_ALL`].
pub const FEATURE_INSTANCES: u32 = 1 << 18;
/// Every feature: the kernel that runs any scene. Bits 6-9, 19 and 20 are the `VARIANT_*` bits.
pub const FEATURES_ALL: u32 = ((1 << 6) - 1)
    | FEATURE_SHADING_NORMALS
    | FEATURE_TEXTURES
    | FEATURE_NORMAL_MAPS
    | FEATURE_PBR
    | FEATURE_ENVMAP
    | FEATURE_PUNCTUAL
    | FEATURE_ALPHA;

// Intersection variants, bits of the same specialisation constant: less robust tests that
// only `raytrace bench accuracy` sets (what the robust defaults of DESIGN.md section 3
// cost), and the device workaround the host sets.

/// Triangles by Moller & Trumbore (1997) instead of the watertight test.
pub const VARIANT_MOLLER_TRUMBORE: u32 = 1 << 6;
/// Boxes by the plain slab test (no NaN handling, no widening) instead of the robust one.
pub const VARIANT_PLAIN_SLAB: u32 = 1 << 7;

/// Trace through the 4-wide BVH (`crate::wide`) instead of the binary one: set by the host
/// where the build collapsed it (`--bvh wide`).
pub const VARIANT_WIDE_BVH: u32 = 1 << 9;

/// The node buffer holds the binary tree without its pairs (`traverse::write_pairs`): set by
/// the host where the builds write none (`BuildOptions::pairs`, `--pairs`: large scenes at a
/// few samples a frame) or a device's storage-buffer binding cannot hold both (lavapipe's
/// 134 MB: a flattened scene of more than about a million primitives). The walk then reads each node's
/// links and then its children, visiting them in the same order: the same hits.
pub const VARIANT_NO_PAIRS: u32 = 1 << 19;

/// The path loop steps each lane's walk itself (`path::stepped_pixels`) instead of tracing a
/// segment at a time: set by the host for frames of more than one segment a path, flattened
/// and through the binary BVH, without next-event estimation (`render::tracer_features`),
/// which the GPU renderer then traces with the stepped loop's kernels (off lavapipe unless
/// asked: `GpuRenderer::set_stepped`; the kernels themselves do not read the bit).
pub const VARIANT_STEPPED: u32 = 1 << 20;

/// The persistent stepped loop's items are groups of a pixel's samples
/// (`path::sample_groups`: the count in [`RenderPush::flags`]), each group's sums written past
/// the image for `path::add_groups`: set by the host for a dispatch of more than one group.
/// Frames of one group (real time) run the kernel without it.
pub const VARIANT_GROUPS: u32 = 1 << 21;

/// Exact products without a fused multiply-add (`math::two_product_split`): set by the host
/// where the device's `Fma` rounds twice (Vulkan allows it; llvmpipe's does), so the sphere
/// test keeps its precision there.
pub const VARIANT_SPLIT_PRODUCTS: u32 = 1 << 8;

/// Ray casts ([`RenderPush::flags`]): ray `2 i` is cast, then a ray leaves its hit point
/// along the direction of ray `2 i + 1` (its `w`: largest distance) as a path does; hits
/// `2 i` and `2 i + 1` are theirs.
pub const CAST_SPAWN: u32 = 1;
/// Ray casts: any-hit queries (shadow rays); a hit is `t = 0`, primitive 0.
pub const CAST_ANY: u32 = 2;
/// Ray casts: closest hits whose `prim` names the object hit instead (through an instance,
/// the instance's object): what picking asks.
pub const CAST_OBJECT: u32 = 4;

/// Display pass: pack pixels as B, G, R, A bytes (for BGRA swapchain images).
pub const DISPLAY_BGRA: u32 = 1;
/// A path tracer dispatch (without `VARIANT_GROUPS`) that traces all of a frame's samples from
/// none: each pixel's sums are written to the accumulation, not added (it needs no clearing
/// first), and its display code to the display image (`crate::display::pixel`, with the
/// push's `samples` and [`DISPLAY_BGRA`]), so that the frame needs no display pass.
pub const DISPLAY_IN_TRACE: u32 = 2;

/// A ray: origin `xyz` (`w`: smallest distance), direction `xyz` (`w`: largest distance).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Ray {
    pub origin: [f32; 4],
    pub dir: [f32; 4],
}

/// The closest hit of a ray: distance ([`f32::INFINITY`] for a miss), primitive ([`INVALID`]
/// for a miss) and barycentric coordinates of the hit (triangles).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

impl Hit {
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        prim: INVALID,
        u: 0.0,
        v: 0.0,
    };
}

const _: () = assert!(size_of::<Object>() == 128);
const _: () = assert!(size_of::<VertexAttrs>() == 64);
const _: () = assert!(size_of::<PunctualLight>() == 64);
const _: () = assert!(size_of::<Material>() == 112);
const _: () = assert!(size_of::<Camera>() == 96);
const _: () = assert!(size_of::<Frame>() == 320);
const _: () = assert!(size_of::<RenderPush>() == 24);
const _: () = assert!(size_of::<Ray>() == 32);
const _: () = assert!(size_of::<Hit>() == 16);

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
