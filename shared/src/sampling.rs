//! Sampling routines of the path tracer, each with its probability density: cosine-weighted
//! hemisphere, uniform sphere, uniform triangle, disk; and the orthonormal basis of Duff et al.
//! (JCGT 2017) that turns a local direction into a world one.
use crate::math::{sin_cos, sqrt};
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

/// Two unit vectors completing unit `n` to a right-handed orthonormal basis.
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Cosine-weighted direction about unit `n` from two uniform numbers; pdf `cos / pi`.
pub fn cosine_hemisphere(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = sqrt(u1);
    let (s, c) = sin_cos(2.0 * PI * u2);
    let (t, b) = basis(n);
    t * (r * c) + b * (r * s) + n * sqrt((1.0 - u1).max(0.0))
}

/// Density of [`cosine_hemisphere`] for a direction at `cos` from the normal.
pub fn cosine_pdf(cos: f32) -> f32 {
    cos.max(0.0) / PI
}

/// Uniform direction on the unit sphere; pdf `1 / (4 pi)`.
pub fn uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = sqrt((1.0 - z * z).max(0.0));
    let (s, c) = sin_cos(2.0 * PI * u2);
    Vec3::new(r * c, r * s, z)
}

/// Uniform barycentric weights `(b1, b2)` on a triangle; pdf `1 / area`.
pub fn uniform_triangle(u1: f32, u2: f32) -> (f32, f32) {
    let su = sqrt(u1);
    (u2 * su, 1.0 - su)
}

/// Uniform point `(x, y)` on the unit disk.
pub fn uniform_disk(u1: f32, u2: f32) -> (f32, f32) {
    let r = sqrt(u1);
    let (s, c) = sin_cos(2.0 * PI * u2);
    (r * c, r * s)
}

/// Uniform point in the unit ball from three uniform numbers.
pub fn uniform_ball(u1: f32, u2: f32, u3: f32) -> Vec3 {
    uniform_sphere(u1, u2) * crate::math::powf(u3, 1.0 / 3.0)
}

/// Power heuristic (beta = 2) weight of a sample from the strategy with density `a` against
/// one with density `b` (Veach 1997).
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}
