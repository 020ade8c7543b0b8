//! The real-time denoiser: spatiotemporal variance-guided filtering (Schied et al., HPG 2017,
//! "Spatiotemporal Variance-Guided Filtering: Real-Time Reconstruction for Path-Traced
//! Global Illumination").
//!
//! The path tracer (with `FEATURE_GUIDES`) leaves a [`Guide`] per pixel: the frame's radiance
//! split into what the first hit emits and what it reflects, and that hit's albedo, shading
//! normal, distance, object and place in the previous frame (motion). Three per-pixel passes
//! follow, each a step over every pixel before the next:
//!
//! 1. [`temporal`]: the reflected radiance divided by the albedo (demodulation: texture
//!    detail is not blurred) is blended into the history reprojected from the previous frame
//!    (bilinear, taps whose object, distance and normal disagree rejected), with the first
//!    two moments of its luminance. The blend weight is `max(1 / n, ALPHA)` for a history of
//!    `n` frames, or `1 / n` while nothing moves (`DENOISE_STILL`: the history is then the
//!    plain mean of every frame, as the accumulation image is).
//! 2. [`variance`]: the luminance variance of the temporal estimate, `(m2 - m1^2) w2` where
//!    `w2` is the sum of the squared blend weights (the variance of a weighted mean of
//!    independent frames); from a 7x7 neighbourhood where the history is shorter than 4
//!    frames. It also writes the pixel's tangent [`Plane`] for the next pass.
//! 3. [`atrous`], five times: the edge-avoiding a-trous wavelet filter (Dammertz et al.
//!    2010) at steps 1, 2, 4, 8, 16 with a 3x3 kernel ([`RADIUS`]; SVGF's 5x5 B3 spline
//!    measured the same error in 1.5 times the time on the H100), each tap weighted by its
//!    object (another object never blends in), normal (`max(0, n.n')^128`), distance from
//!    the centre's tangent plane (predicted linearly, relative to the tap's footprint) and
//!    luminance (relative to the centre's standard deviation, prefiltered on the first
//!    level); variances carried as `sum w^2 var / (sum w)^2`. The first level's output
//!    becomes the history (SVGF's feedback) while the image moves. The last level also
//!    finishes the pixel: remodulation by the albedo, the first hit's emission added back,
//!    and the display encoding.
//!
//! Per-pixel data lives in planes of 16-byte words (word `k` of pixel `i` at `k * n + i`),
//! the layout a warp reads fastest: side by side as 64-byte structures, the temporal pass
//! took 0.40 ms at 1080p on the H100 instead of 0.14 (bench/NOTES.md, session 21).
//!
//! Pixels whose first sample left the scene are passed through the spatial filter. Non-finite
//! radiance never enters the history or the filter (it counts as black).
use crate::display;
use crate::math::{exp, finite3, floor, inverse_sqrt, pack_half2, sqrt, unpack_half2};
use crate::sync::{at, at_mut};
use crate::types::{xyz, Camera, Frame, Object, INVALID};
use bytemuck::{Pod, Zeroable};
use spirv_std::glam::Vec3;

/// What the path tracer leaves per pixel for the denoiser (64 bytes, stored as four planes:
/// [`Guide::store`]). Sums run over the frame's samples; the geometry is the first sample's
/// first hit.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Guide {
    /// Radiance reflected toward the camera (everything but the first hit's emission).
    pub color: [f32; 3],
    /// Where the first hit was in the previous frame, in its pixel coordinates (pixel
    /// `(i, j)` covers `[i, i + 1) x [j, j + 1)`).
    pub prev_x: f32,
    /// Radiance the first hit emits (or the sky, for a sample that left the scene).
    pub emission: [f32; 3],
    pub prev_y: f32,
    /// Reflectance at the first hit (the demodulation albedo).
    pub albedo: [f32; 3],
    /// Object of the first hit, [`INVALID`] where the first sample left the scene.
    pub object: u32,
    /// Unit shading normal toward the camera, octahedral ([`oct_encode`]).
    pub normal: u32,
    /// Distance from the camera to the first hit.
    pub depth: f32,
    /// Distance from the previous frame's camera to the first hit where it was then.
    pub prev_depth: f32,
    pub _pad: u32,
}

/// Planes of 16-byte words of the guides of an image (see [`Guide::store`]).
pub const GUIDE_PLANES: u32 = 4;

impl Guide {
    /// Stores the guide of pixel `i` of an `n`-pixel image into `planes`: its 16-byte word
    /// `k` at `k * n + i`. Planes rather than 64-byte guides side by side let a warp's lanes
    /// read and write a word of neighbouring pixels together.
    pub fn store(&self, planes: &mut [[u32; 4]], n: u32, i: u32) {
        let b = |v: f32| v.to_bits();
        let (c, e, a) = (self.color, self.emission, self.albedo);
        *at_mut(planes, i) = [b(c[0]), b(c[1]), b(c[2]), b(self.prev_x)];
        *at_mut(planes, n + i) = [b(e[0]), b(e[1]), b(e[2]), b(self.prev_y)];
        *at_mut(planes, 2 * n + i) = [b(a[0]), b(a[1]), b(a[2]), self.object];
        *at_mut(planes, 3 * n + i) = [self.normal, b(self.depth), b(self.prev_depth), 0];
    }

    /// The guide [`Self::store`] stored (a plane whose fields go unused is not read).
    pub fn load(planes: &[[u32; 4]], n: u32, i: u32) -> Guide {
        let f = f32::from_bits;
        let (c, e) = (*at(planes, i), *at(planes, n + i));
        let (a, g) = (*at(planes, 2 * n + i), *at(planes, 3 * n + i));
        Guide {
            color: [f(c[0]), f(c[1]), f(c[2])],
            prev_x: f(c[3]),
            emission: [f(e[0]), f(e[1]), f(e[2])],
            prev_y: f(e[3]),
            albedo: [f(a[0]), f(a[1]), f(a[2])],
            object: a[3],
            normal: g[0],
            depth: f(g[1]),
            prev_depth: f(g[2]),
            _pad: 0,
        }
    }

    /// Adds the sums of `more` (later samples of the same frame) to the guide of pixel `i`.
    pub fn add_sums(more: &Guide, planes: &mut [[u32; 4]], n: u32, i: u32) {
        let add = |w: &mut [u32; 4], v: [f32; 3]| {
            let mut k = 0;
            while k < 3 {
                w[k] = (f32::from_bits(w[k]) + v[k]).to_bits();
                k += 1;
            }
        };
        add(at_mut(planes, i), more.color);
        add(at_mut(planes, n + i), more.emission);
    }

    /// A pixel the denoiser passes through (its first sample left the scene).
    pub const NONE: Guide = Guide {
        color: [0.0; 3],
        prev_x: 0.0,
        emission: [0.0; 3],
        prev_y: 0.0,
        albedo: [1.0; 3],
        object: INVALID,
        normal: 0,
        depth: f32::INFINITY,
        prev_depth: f32::INFINITY,
        _pad: 0,
    };
}

/// The denoiser's state of a pixel, kept from one frame to the next (48 bytes, three planes
/// of the history buffer: [`History::store`]). Its surface (normal, object, distance) is kept
/// with the filter's (see [`filter_entries`]).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct History {
    /// Demodulated radiance (the estimate the filter starts from; the first level of the
    /// a-trous filter writes its output back here).
    pub illum: [f32; 3],
    pub _pad0: f32,
    pub emission: [f32; 3],
    pub _pad1: f32,
    /// First and second moments of the per-frame luminance.
    pub m1: f32,
    pub m2: f32,
    /// Sum of the squared weights of the frames in the history: its variance is the
    /// per-frame variance times this.
    pub w2: f32,
    /// Frames the history spans (its blend weight is at least `1 / len`).
    pub len: f32,
}

/// Planes of 16-byte words of one frame's histories.
pub const HISTORY_PLANES: u32 = 3;

impl History {
    /// Stores the history of pixel `i` of an `n`-pixel image into the frame's half of the
    /// history buffer that starts at `base`: its 16-byte word `k` at `base + k * n + i`.
    pub fn store(&self, history: &mut [[u32; 4]], base: u32, n: u32, i: u32) {
        let b = |v: f32| v.to_bits();
        let (c, e) = (self.illum, self.emission);
        *at_mut(history, base + i) = [b(c[0]), b(c[1]), b(c[2]), 0];
        *at_mut(history, base + n + i) = [b(e[0]), b(e[1]), b(e[2]), 0];
        *at_mut(history, base + 2 * n + i) = [b(self.m1), b(self.m2), b(self.w2), b(self.len)];
    }

    /// The history [`Self::store`] stored (a plane whose fields go unused is not read).
    pub fn load(history: &[[u32; 4]], base: u32, n: u32, i: u32) -> History {
        let f = f32::from_bits;
        let (c, e, m) = (
            *at(history, base + i),
            *at(history, base + n + i),
            *at(history, base + 2 * n + i),
        );
        History {
            illum: [f(c[0]), f(c[1]), f(c[2])],
            _pad0: 0.0,
            emission: [f(e[0]), f(e[1]), f(e[2])],
            _pad1: 0.0,
            m1: f(m[0]),
            m2: f(m[1]),
            w2: f(m[2]),
            len: f(m[3]),
        }
    }
}

/// Entries (16 bytes) of the history buffer for `n` pixels: this frame's and the previous
/// frame's [`History`] planes.
pub const fn history_entries(n: u32) -> u32 {
    2 * HISTORY_PLANES * n
}

/// Push constants of the denoiser's passes (16 bytes, the size of every kernel's).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct DenoisePush {
    /// Samples per pixel the frame traced (the guides' sums divide by it).
    pub samples: u32,
    /// The a-trous level (step `2^level`).
    pub level: u32,
    /// `DENOISE_*` flags.
    pub flags: u32,
    pub _pad: u32,
}

/// This frame's history is the second half of the history buffer (the previous frame's the
/// first); without it, the other way round.
pub const DENOISE_PARITY: u32 = 1;
/// No previous frame to reproject (the first frame, a new scene or image size).
pub const DENOISE_NO_HISTORY: u32 = 2;
/// Nothing moved since the previous frame: the history becomes the plain mean.
pub const DENOISE_STILL: u32 = 4;
/// Pack the display image as BGRA (as `DISPLAY_BGRA`).
pub const DENOISE_BGRA: u32 = 8;

/// Levels of the a-trous filter (steps 1 to 16 pixels).
pub const LEVELS: u32 = 5;
/// Taps of the a-trous kernel either side of the centre: 1, a 3x3 kernel (a 63-pixel
/// footprint over the five levels), or 2, SVGF's 5x5 (125 pixels).
pub const RADIUS: u32 = 1;
/// The least weight of the newest frame while the image moves (SVGF's alpha).
pub const ALPHA: f32 = 0.2;
/// History lengths stop growing here (a still image's mean then weighs frames alike).
pub const MAX_LEN: f32 = 4096.0;
/// Luminance edge-stopping: differences are divided by this many standard deviations of
/// the temporal estimate (SVGF's 4 on the per-frame deviation at `alpha = 0.2`, whose
/// estimate's deviation is a third of it).
pub const SIGMA_LUMINANCE: f32 = 12.0;
/// Exponent of the normal weight `max(0, n.n')^128` (SVGF's sigma_n).
const NORMAL_POWER_SQUARINGS: u32 = 7;
/// Reprojection: the largest relative difference of distances and the least cosine of
/// normals of a history tap that still counts as the same surface.
const MAX_DEPTH_CHANGE: f32 = 0.05;
const MIN_NORMAL_COS: f32 = 0.9;
/// Albedo channels below this are not divided out (black surfaces reflect nothing to
/// filter; dividing would only amplify noise).
const MIN_ALBEDO: f32 = 1e-3;

/// Rec. 709 luminance.
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// The albedo the radiance is divided by and multiplied back with.
pub fn demodulation(albedo: [f32; 3]) -> Vec3 {
    let a = |x: f32| if x >= MIN_ALBEDO { x } else { 1.0 };
    Vec3::new(a(albedo[0]), a(albedo[1]), a(albedo[2]))
}

/// A unit vector as two 16-bit signed fixed-point octahedral coordinates (Meyer et al.
/// 2010, "On floating-point normal vectors"): `x` in the low half, `y` in the high.
pub fn oct_encode(n: Vec3) -> u32 {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if l1 <= 0.0 || l1.is_nan() {
        return 0;
    }
    let (mut x, mut y) = (n.x / l1, n.y / l1);
    if n.z < 0.0 {
        let (ax, ay) = (x.abs(), y.abs());
        x = (1.0 - ay) * if x >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ax) * if y >= 0.0 { 1.0 } else { -1.0 };
    }
    let q = |v: f32| ((v.clamp(-1.0, 1.0) * 32767.0 + 32768.5) as u32).min(65535);
    q(x) | (q(y) << 16)
}

/// The unit vector of [`oct_encode`].
pub fn oct_decode(e: u32) -> Vec3 {
    // (The direction's length is at least 1/sqrt(3).)
    let n = oct_direction(e);
    n * inverse_sqrt(n.length_squared())
}

/// [`oct_decode`] before its normalisation (what a comparison of directions needs: no square
/// root, no division).
fn oct_direction(e: u32) -> Vec3 {
    let d = |v: u32| (v as f32 - 32768.0) * (1.0 / 32767.0);
    let (x, y) = (d(e & 0xffff), d(e >> 16));
    let z = 1.0 - x.abs() - y.abs();
    let t = (-z).max(0.0);
    Vec3::new(x + if x >= 0.0 { -t } else { t }, y + if y >= 0.0 { -t } else { t }, z)
}

/// Where the pinhole of camera `c` sees point `p` on a `width x height` image: continuous
/// pixel coordinates (the inverse of `path::camera_ray` at the lens centre) and the
/// distance; `(-1, -1)` for a point behind the camera.
pub fn project(c: &Camera, width: u32, height: u32, p: Vec3) -> (f32, f32, f32) {
    let o = xyz(c.origin);
    let (h, v) = (xyz(c.horizontal), xyz(c.vertical));
    let n = h.cross(v);
    let d = p - o;
    let w = xyz(c.lower_left) - o;
    let (nd, nw) = (n.dot(d), n.dot(w));
    // The image plane lies on the far side of the camera, `n.w` of it; a point must too.
    if nd == 0.0 || (nd > 0.0) != (nw > 0.0) {
        return (-1.0, -1.0, d.length());
    }
    let q = d * (nw / nd) - w;
    let s = q.dot(h) / h.length_squared();
    let t = q.dot(v) / v.length_squared();
    (s * width as f32, (1.0 - t) * height as f32, d.length())
}

/// Where world point `p` on object `object` was in the previous frame: moved back by the
/// object's motion (its inverse transform, then the previous one: `objects[f.prev_objects
/// + object]`) and seen by the previous camera ([`project`]).
pub fn motion(f: &Frame, objects: &[Object], object: u32, p: Vec3) -> (f32, f32, f32) {
    let now = at(objects, object);
    let then = at(objects, f.prev_objects + object);
    let (r, c) = (&now.rows, &now.normal_rows);
    // The inverse of the 3x3 part is the transposed cofactor matrix over the determinant.
    let det = xyz(r[0]).dot(xyz(c[0]));
    let x = p - Vec3::new(r[0][3], r[1][3], r[2][3]);
    let local = (xyz(c[0]) * x.x + xyz(c[1]) * x.y + xyz(c[2]) * x.z) / det;
    let row = |k: usize| xyz(then.rows[k]).dot(local) + then.rows[k][3];
    let before = Vec3::new(row(0), row(1), row(2));
    let before = if finite3(before) { before } else { p };
    project(&f.prev_camera, f.width, f.height, before)
}

/// The unit direction of camera `c`'s pinhole ray through the centre of pixel `(x, y)`.
pub fn pixel_direction(c: &Camera, width: u32, height: u32, x: u32, y: u32) -> Vec3 {
    let s = (x as f32 + 0.5) / width as f32;
    let t = 1.0 - (y as f32 + 0.5) / height as f32;
    let target = xyz(c.lower_left) + xyz(c.horizontal) * s + xyz(c.vertical) * t;
    (target - xyz(c.origin)).normalize()
}

/// Halves of the history buffer: (where this frame's planes start, the previous frame's).
fn halves(n: u32, flags: u32) -> (u32, u32) {
    let half = HISTORY_PLANES * n;
    if flags & DENOISE_PARITY != 0 {
        (half, 0)
    } else {
        (0, half)
    }
}

/// The pixels' surfaces in the filter buffer: (this frame's first index, the previous
/// frame's).
fn surfaces(n: u32, flags: u32) -> (u32, u32) {
    if flags & DENOISE_PARITY != 0 {
        (3 * n, 2 * n)
    } else {
        (2 * n, 3 * n)
    }
}

/// `c` where it is finite, else black.
fn sanitize(c: Vec3) -> Vec3 {
    if finite3(c) {
        c
    } else {
        Vec3::ZERO
    }
}

/// A pixel's surface, 16 bytes in the filter buffer: normal (octahedral), object, distance,
/// and the luminance of the temporal estimate. The next frame's reprojection compares its
/// surfaces with these; the 7x7 variance estimate reads them.
#[derive(Copy, Clone)]
struct Surface {
    normal: u32,
    object: u32,
    depth: f32,
    lum: f32,
}

impl Surface {
    fn pack(&self) -> [u32; 4] {
        [self.normal, self.object, self.depth.to_bits(), self.lum.to_bits()]
    }

    fn unpack(e: [u32; 4]) -> Surface {
        Surface {
            normal: e[0],
            object: e[1],
            depth: f32::from_bits(e[2]),
            lum: f32::from_bits(e[3]),
        }
    }
}

/// Entries of the filter buffer for `n` pixels: the two halves the a-trous levels filter
/// back and forth (a [`Tap`] a pixel), this frame's and the previous frame's [`Surface`]s
/// (swapped every frame, as the history's halves), and the pixels' [`Plane`]s.
pub const fn filter_entries(n: u32) -> u32 {
    5 * n
}

/// Where the pixels' [`Plane`]s start in the filter buffer.
const fn planes(n: u32) -> u32 {
    4 * n
}

/// What every a-trous level asks of a pixel's tangent plane, 16 bytes in the filter buffer
/// (written once by the variance pass: the three camera rays it takes would cost each of
/// the five levels a quarter of its time at 1080p).
#[derive(Copy, Clone)]
struct Plane {
    /// How much farther the plane is along the rays of the next pixel right and down than
    /// along the pixel's own: a tap's distance is compared with the plane's, predicted
    /// linearly (SVGF's depth gradient), so that no tap needs its own ray.
    gx: f32,
    gy: f32,
    /// A distance off the plane counts in units of a tap's footprint: 1 / the world size of
    /// a pixel at the centre's distance, foreshortened by the plane's slope (divided by the
    /// level's step).
    geometry: f32,
}

impl Plane {
    /// The plane of normal `normal` at distance `depth` through pixel `(x, y)`.
    fn of(f: &Frame, x: u32, y: u32, normal: Vec3, depth: f32) -> Plane {
        let cam = &f.camera;
        let dir = pixel_direction(cam, f.width, f.height, x, y);
        let plane_d = normal.dot(dir * depth);
        let along = |qx: u32, qy: u32| plane_d / normal.dot(pixel_direction(cam, f.width, f.height, qx, qy)) - depth;
        Plane {
            gx: along(x + 1, y),
            gy: along(x, y + 1),
            geometry: normal.dot(dir).abs() / (depth * f.pixel_spread + 1e-20),
        }
    }

    fn pack(&self) -> [u32; 4] {
        [self.gx.to_bits(), self.gy.to_bits(), self.geometry.to_bits(), 0]
    }

    fn unpack(e: [u32; 4]) -> Plane {
        Plane {
            gx: f32::from_bits(e[0]),
            gy: f32::from_bits(e[1]),
            geometry: f32::from_bits(e[2]),
        }
    }
}

/// A pixel as the a-trous filter reads it, in 16 bytes (two 32-byte reads a tap took the
/// filter 74% of the denoiser's time): the demodulated radiance and the standard deviation
/// of its luminance as half floats, the normal to 8 bits an octahedral coordinate, the
/// object to 16 bits ([`NO_OBJECT`]: passed through), and the distance.
#[derive(Copy, Clone)]
struct Tap {
    illum: Vec3,
    var: f32,
    normal: u32,
    object: u32,
    depth: f32,
}

/// [`Tap::object`] of a pixel without a surface.
const NO_OBJECT: u32 = 0xffff;
/// The largest finite half float: radiance and deviations are clamped to it.
const HALF_MAX: f32 = 65504.0;

impl Tap {
    fn pack(&self) -> [u32; 4] {
        let h = |v: f32| v.clamp(0.0, HALF_MAX);
        let sd = sqrt(self.var.max(0.0));
        [
            pack_half2(h(self.illum.x), h(self.illum.y)),
            pack_half2(h(self.illum.z), h(sd)),
            self.normal | (self.object << 16),
            self.depth.to_bits(),
        ]
    }

    fn unpack(e: [u32; 4]) -> Tap {
        let (r, g) = unpack_half2(e[0]);
        let (b, sd) = unpack_half2(e[1]);
        Tap {
            illum: Vec3::new(r, g, b),
            var: sd * sd,
            normal: e[2] & 0xffff,
            object: e[2] >> 16,
            depth: f32::from_bits(e[3]),
        }
    }
}

/// A 16-bit octahedral normal ([`oct_encode`]) to 8 bits a coordinate.
fn normal8(e: u32) -> u32 {
    ((e & 0xffff) >> 8) | ((e >> 24) << 8)
}

/// The unit vector of [`normal8`] (each coordinate at the middle of its 8-bit step).
fn normal8_decode(e: u32) -> Vec3 {
    oct_decode(((e & 0xff) << 8) | 0x80 | ((e >> 8) << 24) | (0x80 << 16))
}

/// [`normal8_decode`] before its normalisation ([`oct_direction`]).
fn normal8_direction(e: u32) -> Vec3 {
    oct_direction(((e & 0xff) << 8) | 0x80 | ((e >> 8) << 24) | (0x80 << 16))
}

/// An object index to the 16 bits of [`Tap::object`] (objects 65535 apart share one).
fn object16(o: u32) -> u32 {
    if o == INVALID {
        NO_OBJECT
    } else {
        o % NO_OBJECT
    }
}

/// Pass 1 at pixel `i`: the history of this frame from guide `i` and the previous frame's
/// history, and the pixel's surface.
pub fn temporal(
    i: u32,
    p: &DenoisePush,
    f: &Frame,
    guides: &[[u32; 4]],
    history: &mut [[u32; 4]],
    filter: &mut [[u32; 4]],
) {
    let n = f.width * f.height;
    if i >= n {
        return;
    }
    let (cur, prev) = halves(n, p.flags);
    let (cur_surface, prev_surface) = surfaces(n, p.flags);
    let g = Guide::load(guides, n, i);
    let inv = 1.0 / p.samples.max(1) as f32;
    let albedo = demodulation(g.albedo);
    let illum = sanitize(Vec3::from(g.color) * inv) / albedo;
    let emission = sanitize(Vec3::from(g.emission) * inv);
    let l = luminance(illum);
    let mut h = History {
        illum: illum.into(),
        len: 1.0,
        emission: emission.into(),
        w2: 1.0,
        m1: l,
        m2: l * l,
        ..Default::default()
    };
    if p.flags & (DENOISE_STILL | DENOISE_NO_HISTORY) == DENOISE_STILL {
        // Nothing moved: the pixel's own history, whatever its first sample hit this time
        // (at an edge the jittered first hit changes from frame to frame, and the pixel's
        // mean is the mixture).
        let t = History::load(history, prev, n, i);
        let len = (t.len + 1.0).min(MAX_LEN);
        let a = 1.0 / len;
        let mix = |old: f32, new: f32| old * (1.0 - a) + new * a;
        h.illum = [
            mix(t.illum[0], illum.x),
            mix(t.illum[1], illum.y),
            mix(t.illum[2], illum.z),
        ];
        h.emission = [
            mix(t.emission[0], emission.x),
            mix(t.emission[1], emission.y),
            mix(t.emission[2], emission.z),
        ];
        h.m1 = mix(t.m1, l);
        h.m2 = mix(t.m2, l * l);
        h.w2 = (1.0 - a) * (1.0 - a) * t.w2 + a * a;
        h.len = len;
    } else if g.object != INVALID && p.flags & DENOISE_NO_HISTORY == 0 {
        let (px, py) = (g.prev_x - 0.5, g.prev_y - 0.5);
        let (x0, y0) = (floor(px), floor(py));
        let (fx, fy) = (px - x0, py - y0);
        let normal = oct_decode(g.normal);
        let mut sum = History::default();
        let mut wsum = 0.0;
        let mut k = 0;
        while k < 4 {
            let (dx, dy) = (k & 1, k >> 1);
            k += 1;
            let (x, y) = (x0 + dx as f32, y0 + dy as f32);
            let w = if dx == 0 { 1.0 - fx } else { fx } * if dy == 0 { 1.0 - fy } else { fy };
            // Every tap is read (outside the image, its nearest pixel) before any is judged, so
            // that the loads go out together.
            let inside = x >= 0.0 && y >= 0.0 && x < f.width as f32 && y < f.height as f32;
            let q = y.clamp(0.0, f.height as f32 - 1.0) as u32 * f.width + x.clamp(0.0, f.width as f32 - 1.0) as u32;
            let s = Surface::unpack(*at(filter, prev_surface + q));
            let t = History::load(history, prev, n, q);
            // The normals' cosine at least MIN_NORMAL_COS, without normalising the tap's.
            let v = oct_direction(s.normal);
            let cos_l = v.dot(normal);
            let same = s.object == g.object
                && (s.depth - g.prev_depth).abs() <= MAX_DEPTH_CHANGE * g.prev_depth
                && cos_l >= 0.0
                && cos_l * cos_l >= MIN_NORMAL_COS * MIN_NORMAL_COS * v.length_squared();
            if inside && same && w > 0.0 {
                sum.illum = (Vec3::from(sum.illum) + Vec3::from(t.illum) * w).into();
                sum.emission = (Vec3::from(sum.emission) + Vec3::from(t.emission) * w).into();
                sum.len += t.len * w;
                sum.w2 += t.w2 * w;
                sum.m1 += t.m1 * w;
                sum.m2 += t.m2 * w;
                wsum += w;
            }
        }
        if wsum > 0.01 {
            let r = 1.0 / wsum;
            let len = (sum.len * r + 1.0).min(MAX_LEN);
            let a = (1.0 / len).max(ALPHA);
            let mix = |old: f32, new: f32| old * r * (1.0 - a) + new * a;
            h.illum = [
                mix(sum.illum[0], illum.x),
                mix(sum.illum[1], illum.y),
                mix(sum.illum[2], illum.z),
            ];
            h.emission = [
                mix(sum.emission[0], emission.x),
                mix(sum.emission[1], emission.y),
                mix(sum.emission[2], emission.z),
            ];
            h.m1 = mix(sum.m1, l);
            h.m2 = mix(sum.m2, l * l);
            h.w2 = (1.0 - a) * (1.0 - a) * sum.w2 * r + a * a;
            h.len = len;
        }
    }
    let surface = Surface {
        normal: g.normal,
        object: g.object,
        depth: g.depth,
        lum: luminance(Vec3::from(h.illum)),
    };
    *at_mut(filter, cur_surface + i) = surface.pack();
    h.store(history, cur, n, i);
}

/// Pass 2 at pixel `i`: the filter's input (demodulated radiance, variance of its
/// luminance) in the first half of `filter`.
pub fn variance(i: u32, p: &DenoisePush, f: &Frame, history: &[[u32; 4]], filter: &mut [[u32; 4]]) {
    let n = f.width * f.height;
    if i >= n {
        return;
    }
    let (cur, _) = halves(n, p.flags);
    let (surfaces, _) = surfaces(n, p.flags);
    let h = History::load(history, cur, n, i);
    let c = Surface::unpack(*at(filter, surfaces + i));
    let mut var = (h.m2 - h.m1 * h.m1).max(0.0) * h.w2;
    if c.object != INVALID && h.len < 4.0 {
        // Too few frames for temporal moments: the luminance moments of the 7x7
        // neighbourhood on the same surface, their variance raised while the history is short
        // (SVGF).
        let (x, y) = ((i % f.width) as i32, (i / f.width) as i32);
        let normal = oct_decode(c.normal);
        let depth_scale = 1.0 / (MAX_DEPTH_CHANGE * c.depth + 1e-20);
        let (mut m1, mut m2, mut wsum) = (0.0, 0.0, 0.0);
        let mut k = 0;
        while k < 49 {
            let (qx, qy) = (x + k % 7 - 3, y + k / 7 - 3);
            k += 1;
            if qx < 0 || qy < 0 || qx >= f.width as i32 || qy >= f.height as i32 {
                continue;
            }
            let t = Surface::unpack(*at(filter, surfaces + qy as u32 * f.width + qx as u32));
            if t.object != c.object {
                continue;
            }
            let w = normal_weight_of(normal, oct_direction(t.normal)) * exp(-(t.depth - c.depth).abs() * depth_scale);
            m1 += w * t.lum;
            m2 += w * t.lum * t.lum;
            wsum += w;
        }
        if wsum > 0.0 {
            let (m1, m2) = (m1 / wsum, m2 / wsum);
            var = (m2 - m1 * m1).max(0.0) * (4.0 / h.len);
        }
    }
    let tap = Tap {
        illum: sanitize(Vec3::from(h.illum)),
        var: if var.is_finite() { var } else { 0.0 },
        normal: normal8(c.normal),
        object: object16(c.object),
        depth: c.depth,
    };
    *at_mut(filter, i) = tap.pack();
    if tap.object != NO_OBJECT {
        let plane = Plane::of(f, i % f.width, i / f.width, normal8_decode(tap.normal), c.depth);
        *at_mut(filter, planes(n) + i) = plane.pack();
    }
}

/// `max(0, a.v / |v|)^128` for unit `a` (SVGF's normal weight, of `v` normalised).
fn normal_weight_of(a: Vec3, v: Vec3) -> f32 {
    let c = a.dot(v).max(0.0) * inverse_sqrt(v.length_squared());
    let mut w = c * c;
    let mut k = 1;
    while k < NORMAL_POWER_SQUARINGS {
        w *= w;
        k += 1;
    }
    w
}

/// Pass 3 at pixel `i`, level `p.level`: filters the half `level % 2` of `filter` into the
/// other; at level 0 while the image moves the result also becomes this frame's history. The
/// last level finishes the pixel instead ([`finish`]).
#[allow(clippy::too_many_arguments)]
pub fn atrous(
    i: u32,
    p: &DenoisePush,
    f: &Frame,
    guides: &[[u32; 4]],
    history: &mut [[u32; 4]],
    filter: &mut [[u32; 4]],
    output: &mut [[f32; 4]],
    image: &mut [u32],
) {
    let n = f.width * f.height;
    if i >= n {
        return;
    }
    let (src, dst) = if p.level.is_multiple_of(2) { (0, n) } else { (n, 0) };
    let c = Tap::unpack(*at(filter, src + i));
    // A pixel without a surface is passed through.
    let out = if c.object == NO_OBJECT {
        c
    } else {
        filtered(i, p, f, &c, filter, src)
    };
    if p.level == LEVELS - 1 {
        finish(i, p, f, out.illum, guides, history, output, image);
        return;
    }
    *at_mut(filter, dst + i) = out.pack();
    if p.level == 0 && p.flags & DENOISE_STILL == 0 && c.object != NO_OBJECT {
        // The history's first plane: its radiance.
        let (cur, _) = halves(n, p.flags);
        let b = |v: f32| v.to_bits();
        *at_mut(history, cur + i) = [b(out.illum.x), b(out.illum.y), b(out.illum.z), 0];
    }
}

/// The a-trous filter's output at pixel `i` of centre tap `c`, reading the taps of the half
/// of `filter` that starts at `src`.
fn filtered(i: u32, p: &DenoisePush, f: &Frame, c: &Tap, filter: &[[u32; 4]], src: u32) -> Tap {
    let (w, hgt) = (f.width as i32, f.height as i32);
    let (x, y) = ((i % f.width) as i32, (i / f.width) as i32);
    // The centre's variance prefiltered by a 3x3 Gaussian (SVGF) on the first level; the
    // later levels' variances are already the earlier levels' weighted means.
    let mut gvar = c.var;
    if p.level == 0 {
        gvar = 0.0;
        let mut k = 0;
        while k < 9 {
            let (dx, dy) = (k % 3 - 1, k / 3 - 1);
            k += 1;
            let (qx, qy) = ((x + dx).clamp(0, w - 1), (y + dy).clamp(0, hgt - 1));
            let kw = if dx == 0 { 0.5 } else { 0.25 } * if dy == 0 { 0.5 } else { 0.25 };
            gvar += kw * Tap::unpack(*at(filter, src + (qy * w + qx) as u32)).var;
        }
    }
    let normal = normal8_decode(c.normal);
    let Plane { gx, gy, geometry } = Plane::unpack(*at(filter, planes(f.width * f.height) + i));
    let lum = luminance(c.illum);
    let lum_scale = 1.0 / (SIGMA_LUMINANCE * sqrt(gvar.max(0.0)) + 1e-10);
    let step = 1i32 << p.level;
    // (Steps are powers of two: the division is exact.)
    let geometry_scale = geometry / step as f32;
    // The centre's weight is the kernel's.
    let h0 = kernel(0) * kernel(0);
    let mut sum = c.illum * h0;
    let (mut sum_var, mut wsum) = (h0 * h0 * c.var, h0);
    let r = RADIUS as i32;
    let mut dy = -r;
    while dy <= r {
        let qy = y + dy * step;
        let hy = kernel(dy);
        let mut dx = -r;
        while dx <= r {
            if dx == 0 && dy == 0 {
                dx += 1;
                continue;
            }
            let qx = x + dx * step;
            // Every tap is read (at the image's edge, the edge pixel's) and weighed, and the
            // ones outside the image or on another object get weight 0: no branch on the
            // data, so a warp's loads go out together and its lanes never diverge.
            let inside = qx >= 0 && qy >= 0 && qx < w && qy < hgt;
            let q = (qy.clamp(0, hgt - 1) * w + qx.clamp(0, w - 1)) as u32;
            let t = Tap::unpack(*at(filter, src + q));
            let h = hy * kernel(dx);
            let predicted = c.depth + (gx * dx as f32 + gy * dy as f32) * step as f32;
            // 1 / the tap's offset in steps.
            let inv_offset = match dx * dx + dy * dy {
                1 => 1.0,
                2 => core::f32::consts::FRAC_1_SQRT_2,
                d2 => 1.0 / sqrt(d2 as f32),
            };
            // The geometry and luminance weights in one exponential (0 for a tap without a
            // surface: its distance is infinite).
            let e = (t.depth - predicted).abs() * geometry_scale * inv_offset
                + (luminance(t.illum) - lum).abs() * lum_scale;
            let g = exp(-e);
            let edge = h * normal_weight_of(normal, normal8_direction(t.normal)) * if g >= 0.0 { g } else { 0.0 };
            // Weighed by a 0/1 factor rather than chosen: the compiler keeps every tap's
            // weight out of branches (in a branch, a warp straddling objects diverged, and the
            // filter took 1.7 times as long on the instances as on the bunny).
            let keep = (inside && t.object == c.object) as u32 as f32;
            let wt = edge * keep;
            sum += t.illum * wt;
            sum_var += wt * wt * t.var;
            wsum += wt;
            dx += 1;
        }
        dy += 1;
    }
    // (wsum is at least the centre's weight.)
    let r = 1.0 / wsum;
    Tap {
        illum: sum * r,
        var: sum_var * r * r,
        ..*c
    }
}

/// The a-trous kernel's weight at offset `d` in `-RADIUS..=RADIUS`: the B3 spline's 1/16,
/// 1/4, 3/8, 1/4, 1/16 (SVGF's 5x5), or the linear spline's 1/4, 1/2, 1/4 (3x3).
fn kernel(d: i32) -> f32 {
    match (RADIUS, d.abs()) {
        (1, 0) => 0.5,
        (1, _) => 0.25,
        (_, 0) => 0.375,
        (_, 1) => 0.25,
        _ => 0.0625,
    }
}

/// The end of pixel `i`, of filtered demodulated radiance `filtered`: remodulated by its
/// albedo, the first hit's emission added back, into `output` (`w` 1) and its display code
/// into `image`.
#[allow(clippy::too_many_arguments)]
fn finish(
    i: u32,
    p: &DenoisePush,
    f: &Frame,
    filtered: Vec3,
    guides: &[[u32; 4]],
    history: &[[u32; 4]],
    output: &mut [[f32; 4]],
    image: &mut [u32],
) {
    let n = f.width * f.height;
    let (cur, _) = halves(n, p.flags);
    let albedo = Guide::load(guides, n, i).albedo;
    let emission = History::load(history, cur, n, i).emission;
    let c = sanitize(filtered * demodulation(albedo) + Vec3::from(emission));
    *at_mut(output, i) = [c.x, c.y, c.z, 1.0];
    *at_mut(image, i) = display::pack(c, f, p.flags & DENOISE_BGRA != 0);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octahedral_normals_round_trip() {
        // The angle between a vector and its decoding.
        let angle = |n: Vec3| {
            let m = oct_decode(oct_encode(n));
            n.cross(m).length().atan2(n.dot(m))
        };
        let mut worst: f32 = 0.0;
        for i in 0..2000 {
            let (a, b) = (i as f32 * 0.618_034, i as f32 * 0.414_213_5);
            let z = 1.0 - 2.0 * ((a % 1.0 + 1.0) % 1.0);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = b * core::f32::consts::TAU;
            worst = worst.max(angle(Vec3::new(r * phi.cos(), r * phi.sin(), z)));
        }
        for n in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
            assert!(angle(n) < 1e-6, "{n}");
        }
        // 16 bits a coordinate: within 1e-4 radians.
        assert!(worst < 1e-4, "worst angle {worst}");
    }

    #[test]
    fn projection_inverts_the_camera_ray() {
        let camera = Camera {
            origin: [1.0, 2.0, 3.0, 0.0],
            lower_left: [-1.5, 0.5, 1.0, 0.0],
            horizontal: [4.0, 0.0, 0.0, 0.0],
            vertical: [0.0, 3.0, 0.0, 0.0],
            u: [1.0, 0.0, 0.0, 0.0],
            v: [0.0, 1.0, 0.0, 0.0],
        };
        for (x, y) in [(0, 0), (7, 3), (63, 47), (31, 20)] {
            let d = pixel_direction(&camera, 64, 48, x, y);
            let (px, py, dist) = project(&camera, 64, 48, xyz(camera.origin) + d * 5.0);
            assert!((px - (x as f32 + 0.5)).abs() < 1e-3 && (py - (y as f32 + 0.5)).abs() < 1e-3);
            assert!((dist - 5.0).abs() < 1e-4);
        }
        let behind = xyz(camera.origin) - pixel_direction(&camera, 64, 48, 10, 10);
        assert_eq!(project(&camera, 64, 48, behind).0, -1.0);
    }
}
