//! Scattering of the four materials (Ray Tracing in One Weekend's set, with exact Fresnel):
//! Lambertian diffuse (cosine sampling), metal (mirror direction blurred by a random point
//! in a ball of radius `roughness`), dielectric (unpolarised Fresnel reflectance choosing
//! between reflection and refraction, total internal reflection), and emissive (no scattering).
//! Directions follow the shading normal and are kept on the geometric side they belong to
//! (`crate::shading`'s rules).
use crate::math::sqrt;
use crate::pbr::{self, Pbr};
use crate::rng::Rng;
use crate::sampling;
use crate::shading::facing;
use crate::types::{xyz, Material, MaterialKind, FEATURE_DIELECTRIC, FEATURE_METAL, FEATURE_PBR};
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

/// The outcome of a scattering event: the new direction and the throughput factor
/// `f cos / pdf`. `diffuse` marks a non-delta event (Lambert or GGX) whose direction had
/// density `pdf` (the only kind next-event estimation and MIS apply to). `absorbed`: the
/// path ends.
#[derive(Copy, Clone, Debug)]
pub struct Scatter {
    pub dir: Vec3,
    pub weight: Vec3,
    pub pdf: f32,
    pub diffuse: bool,
    pub absorbed: bool,
}

pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Unpolarised Fresnel reflectance of a smooth dielectric boundary for light arriving at
/// `cos_i` (> 0) from the side of index 1 towards relative index `eta`; 1 beyond the
/// critical angle (pbrt-v4 `FrDielectric`). Also returns the cosine of the refracted ray.
pub fn fresnel(cos_i: f32, eta: f32) -> (f32, f32) {
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let cos_t = sqrt(1.0 - sin2_t);
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    ((r_parl * r_parl + r_perp * r_perp) * 0.5, cos_t)
}

/// Scatters a ray of unit direction `d` hitting a surface with unit geometric normal `ng`
/// and unit shading normal `ns` (on `ng`'s side; `ng` itself where the surface has none).
/// Kinds whose `FEATURE_*` bit is missing from `features` absorb, and so does a direction
/// on the wrong geometric side: below the surface for a reflection, above it for a
/// refraction.
pub fn scatter(m: &Material, d: Vec3, ng: Vec3, ns: Vec3, features: u32, rng: &mut Rng) -> Scatter {
    let albedo = xyz(m.albedo);
    // The normals on the side the ray came from.
    let entering = d.dot(ng) < 0.0;
    let (n, sn) = facing(d, ng, ns);
    let mut s = Scatter {
        dir: d,
        weight: albedo,
        pdf: 0.0,
        diffuse: false,
        absorbed: false,
    };
    let mut refracted = false;
    if m.kind == MaterialKind::Diffuse as u32 {
        s.dir = sampling::cosine_hemisphere(sn, rng.next_f32(), rng.next_f32());
        s.pdf = sampling::cosine_pdf(s.dir.dot(sn));
        s.diffuse = true;
        s.absorbed = s.pdf <= 0.0;
    } else if features & FEATURE_PBR != 0 && m.kind == MaterialKind::Pbr as u32 {
        let (t, b) = sampling::basis(sn);
        let wo = local(-d, t, b, sn);
        let ps = pbr::sample(&pbr_of(m), wo, rng.next_f32(), rng.next_f32(), rng.next_f32());
        s.dir = t * ps.wi.x + b * ps.wi.y + sn * ps.wi.z;
        s.weight = ps.weight;
        s.pdf = ps.pdf;
        s.diffuse = true;
        s.absorbed = ps.pdf <= 0.0 || ps.pdf.is_nan();
    } else if features & FEATURE_METAL != 0 && m.kind == MaterialKind::Metal as u32 {
        let fuzz = sampling::uniform_ball(rng.next_f32(), rng.next_f32(), rng.next_f32()) * m.roughness;
        s.dir = (reflect(d, sn) + fuzz).normalize();
        s.absorbed = s.dir.dot(sn) <= 0.0;
    } else if features & FEATURE_DIELECTRIC != 0 && m.kind == MaterialKind::Dielectric as u32 {
        let eta = if entering { m.ior } else { 1.0 / m.ior };
        let cos_i = (-d.dot(sn)).clamp(0.0, 1.0);
        let (r, cos_t) = fresnel(cos_i, eta);
        s.dir = if rng.next_f32() < r {
            reflect(d, sn)
        } else {
            refracted = true;
            (d / eta + (cos_i / eta - cos_t) * sn).normalize()
        };
        s.weight = Vec3::ONE;
    } else {
        s.absorbed = true;
    }
    // Rule 2 of `crate::shading`: leave on the geometric side the direction belongs to.
    let above = s.dir.dot(n) > 0.0;
    if above == refracted {
        s.absorbed = true;
    }
    s
}

/// `v` in the frame `(t, b, n)`.
fn local(v: Vec3, t: Vec3, b: Vec3, n: Vec3) -> Vec3 {
    Vec3::new(v.dot(t), v.dot(b), v.dot(n))
}

/// The GGX model's view of a [`MaterialKind::Pbr`] material.
fn pbr_of(m: &Material) -> Pbr {
    Pbr {
        base_color: xyz(m.albedo),
        metallic: m.metallic,
        roughness: m.roughness,
        ior: m.ior,
    }
}

/// What a non-delta material (Lambert, or GGX where `features` has [`FEATURE_PBR`])
/// reflects toward a path arriving along unit `d` from light arriving from unit direction
/// `wi`: `(f cos, pdf)`, the BSDF times the cosine at the shading normal and the density
/// with which [`scatter`] picks `wi`. `n` and `sn` are the geometric and shading normals on
/// the side the path is on ([`facing`]); light from below the geometric surface counts zero
/// (`crate::shading`'s rule 2).
pub fn eval(m: &Material, d: Vec3, wi: Vec3, n: Vec3, sn: Vec3, features: u32) -> (Vec3, f32) {
    let cos = wi.dot(sn);
    if wi.dot(n) <= 0.0 {
        return (Vec3::ZERO, 0.0);
    }
    if features & FEATURE_PBR != 0 && m.kind == MaterialKind::Pbr as u32 {
        let (t, b) = sampling::basis(sn);
        return pbr::eval(&pbr_of(m), local(-d, t, b, sn), local(wi, t, b, sn));
    }
    if cos <= 0.0 {
        return (Vec3::ZERO, 0.0);
    }
    (xyz(m.albedo) * (cos / PI), sampling::cosine_pdf(cos))
}
