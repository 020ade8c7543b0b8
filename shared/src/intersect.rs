//! Ray-primitive tests under the numerics policy of DESIGN.md section 3:
//! - triangles: the watertight test of Woop, Benthin & Wald (JCGT 2013) with edge functions
//!   computed by Kahan's difference of products, so their signs are exact and two triangles
//!   sharing an edge never both miss a ray through it (pbrt-v4 `IntersectTriangle`);
//! - spheres: the stable quadratic of Haines et al., Ray Tracing Gems ch. 7, with the
//!   origin's offset from the centre kept exact and compensated sums (Ogita, Rump & Oishi
//!   2005) where it cancels, so small far spheres and large near ones keep a few ulps;
//! - boxes: the slab test with NaN-safe min/max, entry planes chosen by the direction's sign
//!   (either sign of zero), and Ize's widening of the far distance;
//! - secondary rays leave surfaces from origins offset by Wachter & Binder, Ray Tracing Gems
//!   ch. 6, and by at least a few ulps of the primitive's own scale, so they never re-hit the
//!   surface they start on.
use crate::math::{
    difference_of_products, difference_of_products_exact, exact_product, fma, max3, nmax, nmin, select, sqrt, two_sum,
    SLAB_WIDEN,
};
use crate::types::{xyz, Sphere, Triangle};
use spirv_std::glam::Vec3;

/// A ray with what every triangle test of it shares: the permutation that makes the largest
/// direction component `z`, and the shear that maps the direction to `+z`.
#[derive(Copy, Clone, Debug)]
pub struct TriRay {
    pub origin: Vec3,
    pub dir: Vec3,
    pub inv_dir: Vec3,
    /// Index of the direction's largest component.
    kz: u32,
    shear: Vec3,
}

/// `v` permuted so that component `kz` comes last: `(x, y, z)` cyclically rotated. By
/// selects ([`select`]): a `match` compiled to branches per vertex.
fn permute(v: Vec3, kz: u32) -> Vec3 {
    let (a, b) = (kz == 0, kz == 1);
    Vec3::new(
        select(a, v.y, select(b, v.z, v.x)),
        select(a, v.z, select(b, v.x, v.y)),
        select(a, v.x, select(b, v.y, v.z)),
    )
}

impl TriRay {
    pub fn new(origin: Vec3, dir: Vec3) -> TriRay {
        let a = dir.abs();
        let kz = if a.x > a.y && a.x > a.z {
            0
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let d = permute(dir, kz);
        TriRay {
            origin,
            dir,
            inv_dir: Vec3::ONE / dir,
            kz,
            shear: Vec3::new(-d.x / d.z, -d.y / d.z, 1.0 / d.z),
        }
    }
}

/// Watertight ray-triangle test. Returns `(t, b1, b2)` of a hit with `0 < t < t_max`
/// (barycentric weights of `v1` and `v2`), or `t = INFINITY`. Zero-area triangles never hit.
pub fn triangle(r: &TriRay, tri: &Triangle, t_max: f32) -> (f32, f32, f32) {
    const MISS: (f32, f32, f32) = (f32::INFINITY, 0.0, 0.0);
    let s = r.shear;
    // Vertices relative to the origin, permuted, then sheared so the ray is the +z axis.
    let p0 = permute(xyz(tri.v0) - r.origin, r.kz);
    let p1 = permute(xyz(tri.v1) - r.origin, r.kz);
    let p2 = permute(xyz(tri.v2) - r.origin, r.kz);
    let (x0, y0) = (fma(s.x, p0.z, p0.x), fma(s.y, p0.z, p0.y));
    let (x1, y1) = (fma(s.x, p1.z, p1.x), fma(s.y, p1.z, p1.y));
    let (x2, y2) = (fma(s.x, p2.z, p2.x), fma(s.y, p2.z, p2.y));
    let e0 = difference_of_products(x1, y2, y1, x2);
    let e1 = difference_of_products(x2, y0, y2, x0);
    let e2 = difference_of_products(x0, y1, y0, x1);
    // Every test computed and their verdicts combined without a branch (`&`, `|`), so that
    // the lanes of a subgroup testing triangles run them together whichever test each fails.
    let outside = ((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) & ((e0 > 0.0) | (e1 > 0.0) | (e2 > 0.0));
    let det = e0 + e1 + e2;
    let t_scaled = e0 * (s.z * p0.z) + e1 * (s.z * p1.z) + e2 * (s.z * p2.z);
    // `t_scaled / det` in `(0, t_max]` for either sign of `det` (neither for 0 or NaN).
    let bound = t_max * det;
    let in_range =
        ((det < 0.0) & (t_scaled < 0.0) & (t_scaled >= bound)) | ((det > 0.0) & (t_scaled > 0.0) & (t_scaled <= bound));
    let inv = 1.0 / det;
    let t = t_scaled * inv;
    // Written so that a NaN (non-finite vertex or ray, overflowing shear) is a miss too.
    let hit = !outside & in_range & (t > 0.0) & (t < t_max);
    (
        select(hit, t, MISS.0),
        select(hit, e1 * inv, 0.0),
        select(hit, e2 * inv, 0.0),
    )
}

/// Moller & Trumbore's ray-triangle test (JGT 1997), the common fast one, kept to measure
/// what the watertight test costs (`raytrace bench accuracy`): its edge tests round, so a ray
/// through a shared edge or vertex can miss both triangles. Same results as [`triangle`].
pub fn triangle_moller_trumbore(r: &TriRay, tri: &Triangle, t_max: f32) -> (f32, f32, f32) {
    const MISS: (f32, f32, f32) = (f32::INFINITY, 0.0, 0.0);
    let v0 = xyz(tri.v0);
    let (e1, e2) = (xyz(tri.v1) - v0, xyz(tri.v2) - v0);
    let p = r.dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return MISS;
    }
    let inv = 1.0 / det;
    let s = r.origin - v0;
    let b1 = s.dot(p) * inv;
    if b1 < 0.0 || b1 > 1.0 {
        return MISS;
    }
    let q = s.cross(e1);
    let b2 = r.dir.dot(q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return MISS;
    }
    let t = e2.dot(q) * inv;
    if t > 0.0 && t < t_max {
        (t, b1, b2)
    } else {
        MISS
    }
}

/// Nearest intersection distance in `(0, t_max)` of a ray with a sphere, or `INFINITY`.
/// Ray Tracing Gems ch. 7: the roots as `c / q` and `q / a`, which lose no precision to
/// cancellation, with three more steps that keep a few ulps for small far spheres and large
/// near ones:
/// - `f = origin - center` is kept exactly, as `f + fe` (its rounding alone is a sizeable
///   part of a small sphere's radius, or of the height above a large sphere's surface);
/// - `c = |f|^2 - r^2` is summed from exact squares (Ogita, Rump & Oishi's Dot2), so the
///   cancellation of an origin near the surface costs nothing;
/// - the discriminant `a r^2 - |f x d|^2 = b^2 - a c` is taken from whichever form cancels
///   less: `|f x d|`, the centre's distance from the line times `|d|`, has exact-sign cross
///   products and serves small far spheres; `b^2 - a c` serves rays that cut steeply into
///   large near ones.
///
/// The exact products come from `fma`, or where the device's `fma` rounds twice (`split`)
/// from Dekker's splitting (see [`exact_product`]).
pub fn sphere(origin: Vec3, dir: Vec3, s: &Sphere, t_max: f32, split: bool) -> f32 {
    let center = xyz(s.center_radius);
    let r = s.center_radius[3];
    let (fx, ex) = two_sum(origin.x, -center.x);
    let (fy, ey) = two_sum(origin.y, -center.y);
    let (fz, ez) = two_sum(origin.z, -center.z);
    let (f, fe) = (Vec3::new(fx, fy, fz), Vec3::new(ex, ey, ez));
    let a = dir.dot(dir);
    // A direction too short to square (|d| < 1e-19) would make every `a` term vanish.
    if a < f32::MIN_POSITIVE {
        return f32::INFINITY;
    }
    let b = -(f.dot(dir) + fe.dot(dir));
    let c = norm2_minus_r2(f, fe, r, split);
    let fxd = Vec3::new(
        difference_of_products_exact(f.y, dir.z, f.z, dir.y, split),
        difference_of_products_exact(f.z, dir.x, f.x, dir.z, split),
        difference_of_products_exact(f.x, dir.y, f.y, dir.x, split),
    ) + fe.cross(dir);
    let l = fxd.length();
    let disc = if l < b.abs() {
        let ra = r * sqrt(a);
        (ra + l) * (ra - l)
    } else {
        difference_of_products_exact(b, b, a, c, split)
    };
    if disc.is_nan() || disc < 0.0 {
        return f32::INFINITY;
    }
    let root = sqrt(disc);
    let q = if b >= 0.0 { b + root } else { b - root };
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q / a) };
    let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
    if near > 0.0 && near < t_max {
        near
    } else if far > 0.0 && far < t_max {
        far
    } else {
        f32::INFINITY
    }
}

/// `|f + fe|^2 - r^2` where `fe` is small against `f`: the exact products `f_i^2` and
/// `-r^2` are added by TwoSum and every rounding error is gathered into one correction
/// (Ogita, Rump & Oishi 2005, Dot2), as if in twice the precision.
fn norm2_minus_r2(f: Vec3, fe: Vec3, r: f32, split: bool) -> f32 {
    let (xx, ex) = exact_product(f.x, f.x, split);
    let (yy, ey) = exact_product(f.y, f.y, split);
    let (zz, ez) = exact_product(f.z, f.z, split);
    let (rr, er) = exact_product(-r, r, split);
    let (s1, e1) = two_sum(xx, yy);
    let (s2, e2) = two_sum(s1, zz);
    let (s3, e3) = two_sum(s2, rr);
    let err = (ex + ey + ez + er) + (e1 + e2 + e3);
    s3 + (err + fe.dot(f * 2.0 + fe))
}

/// Entry distance of a ray into the closed box `[lo, hi]` within `[0, t_max]`, or
/// `INFINITY`. Each axis's entry plane is chosen by the direction's sign, not by comparing
/// the two distances: then a ray running parallel to an axis inside that axis's slab, or on
/// one of its planes (a NaN slab distance, `0 * inf`), is not narrowed by it, for either sign
/// of zero. (Ordering by distance turned an origin on a plane with a `-0.0` direction
/// component into a miss.)
pub fn slab(origin: Vec3, inv_dir: Vec3, lo: Vec3, hi: Vec3, t_max: f32) -> f32 {
    let t0 = (lo - origin) * inv_dir;
    let t1 = (hi - origin) * inv_dir;
    let pick = |a: f32, b: f32, inv: f32| if inv < 0.0 { (b, a) } else { (a, b) };
    let (nx, fx) = pick(t0.x, t1.x, inv_dir.x);
    let (ny, fy) = pick(t0.y, t1.y, inv_dir.y);
    let (nz, fz) = pick(t0.z, t1.z, inv_dir.z);
    let near = slab_near([nx, ny, nz]);
    if near <= slab_far([fx, fy, fz], t_max) {
        near
    } else {
        f32::INFINITY
    }
}

/// The plain slab test (Kay & Kajiya; min/max of the two planes per axis, no widening),
/// kept to measure what [`slab`] costs. Its min/max of a NaN distance (a ray on a slab plane
/// parallel to it) is whatever the hardware's min/max gives, and the far distance rounds
/// down as often as up, so boxes of flat or touching primitives can be missed.
pub fn slab_plain(origin: Vec3, inv_dir: Vec3, lo: Vec3, hi: Vec3, t_max: f32) -> f32 {
    let t0 = (lo - origin) * inv_dir;
    let t1 = (hi - origin) * inv_dir;
    let (lo, hi) = (t0.min(t1), t0.max(t1));
    let near = lo.x.max(lo.y).max(lo.z).max(0.0);
    let far = hi.x.min(hi.y).min(hi.z).min(t_max);
    if near <= far {
        near
    } else {
        f32::INFINITY
    }
}

/// The latest of `0` and the entry distances; a NaN one is passed over (`nmax`).
fn slab_near(entry: [f32; 3]) -> f32 {
    nmax(nmax(nmax(0.0, entry[0]), entry[1]), entry[2])
}

/// The earliest of `t_max` and the exit distances widened by [`SLAB_WIDEN`] (covering the
/// rounding of `(bound - origin) * inv_dir`: Ize 2013; pbrt-v4 `Bounds3::IntersectP`); a NaN
/// one is passed over. One product: rounding is monotonic, so widening the least exit
/// equals taking the least widened exit, bit for bit.
fn slab_far(exit: [f32; 3], t_max: f32) -> f32 {
    nmin(nmin(nmin(exit[0], exit[1]), exit[2]) * SLAB_WIDEN, t_max)
}

/// Geometric normal (unnormalised: twice the area) of a triangle.
pub fn triangle_normal(t: &Triangle) -> Vec3 {
    (xyz(t.v1) - xyz(t.v0)).cross(xyz(t.v2) - xyz(t.v0))
}

/// The hit point `b0 v0 + b1 v1 + b2 v2`: more accurate than `origin + t dir`.
pub fn triangle_point(t: &Triangle, b1: f32, b2: f32) -> Vec3 {
    let b0 = 1.0 - b1 - b2;
    xyz(t.v0) * b0 + xyz(t.v1) * b1 + xyz(t.v2) * b2
}

/// Largest coordinate magnitude of a triangle's vertices: the scale its hit points and its
/// intersection tests round at (see [`offset_origin`]).
pub fn triangle_scale(t: &Triangle) -> f32 {
    max3(xyz(t.v0).abs().max(xyz(t.v1).abs()).max(xyz(t.v2).abs()))
}

/// A sphere's radius: the scale the radial error of its re-projected hit points grows with
/// (see [`offset_origin`]; the centre's magnitude does not matter, [`sphere`] is exact in
/// `origin - center`).
pub fn sphere_scale(s: &Sphere) -> f32 {
    s.center_radius[3].abs()
}

/// Origin for a ray leaving a surface at `p` on the side of `n` (unit normal, pointing where
/// the ray goes): Wachter & Binder's offset, a few ulps in integer space far from the origin
/// and a small float step near it; and at least `scale * 2^-19` along `n`, where `scale` is
/// the primitive's [`triangle_scale`] or [`sphere_scale`]. The hit point and the intersection
/// tests of the new ray round at the primitive's scale, not at `p`'s: a point near the origin
/// on a large ground sphere or quad is uncertain by a few ulps of `scale`, far more than
/// Wachter & Binder's step there, and the new ray would hit the surface it leaves.
pub fn offset_origin(p: Vec3, n: Vec3, scale: f32) -> Vec3 {
    let step = scale * SCALE_STEP;
    Vec3::new(
        offset_axis(p.x, n.x, step),
        offset_axis(p.y, n.y, step),
        offset_axis(p.z, n.z, step),
    )
}

/// Offset of [`offset_origin`] relative to the primitive's scale: 16 ulps of it.
const SCALE_STEP: f32 = 1.0 / 524_288.0;

/// One coordinate of [`offset_origin`]: whichever of the two offsets moves it farther.
fn offset_axis(p: f32, n: f32, step: f32) -> f32 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let moved = if p.abs() < ORIGIN {
        fma(FLOAT_SCALE, n, p)
    } else {
        let of = (INT_SCALE * n) as i32;
        let of = if p < 0.0 { -of } else { of };
        f32::from_bits((p.to_bits() as i32).wrapping_add(of) as u32)
    };
    let scaled = fma(step, n, p);
    if n > 0.0 {
        moved.max(scaled)
    } else {
        moved.min(scaled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permute_puts_component_kz_last_rotating_the_others() {
        let v = Vec3::new(1.0, -0.0, f32::NAN);
        let bits = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
        assert_eq!(bits(permute(v, 0)), bits(Vec3::new(v.y, v.z, v.x)));
        assert_eq!(bits(permute(v, 1)), bits(Vec3::new(v.z, v.x, v.y)));
        assert_eq!(bits(permute(v, 2)), bits(v));
        assert_eq!(select(true, 1.0, 2.0), 1.0);
        assert_eq!(select(false, 1.0, 2.0), 2.0);
    }
}
