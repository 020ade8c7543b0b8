//! glTF 2.0's metallic-roughness material as a BSDF: GGX (Trowbridge-Reitz) microfacet
//! reflection with the height-correlated Smith shadowing (Heitz 2014, "Understanding the
//! Masking-Shadowing Function"), sampled by its distribution of visible normals (Heitz 2018,
//! "Sampling the GGX Distribution of Visible Normals", JCGT 7(4)); pbrt-v4's
//! `TrowbridgeReitzDistribution` is the reference for every formula here.
//!
//! The material mixes two BSDFs by `metallic`, as glTF's appendix B does:
//! - metal: `F(h.v) D G / (4 cos_o cos_i)` with Schlick's Fresnel from `F0 = base_color`;
//! - dielectric: the same specular lobe with a scalar Schlick Fresnel from
//!   `F0 = ((ior - 1) / (ior + 1))^2` (0.04 at glTF's 1.5), over a diffuse base coupled to it
//!   as Ashikhmin and Shirley (2000, "An Anisotropic Phong BRDF Model") do:
//!   `28 / (23 pi) base (1 - F0) (1 - (1 - cos_o / 2)^5) (1 - (1 - cos_i / 2)^5)`, which
//!   reflects only what the specular layer lets through and, unlike glTF's `fresnel_mix`
//!   (whose diffuse weight `1 - F(h.v)` lets a grazing viewer get ~1.5 back from a white
//!   surface), keeps the sum at or below one. Both lobes are reciprocal.
//!
//! Everything is in the local shading frame: the normal is `+z`, `wo` points toward the
//! viewer, `wi` toward the light; the caller keeps `wo.z > 0` (`crate::shading`).
//! Single-scattering GGX loses the energy of light that bounces more than once between
//! microfacets: up to about 40% for a white metal at roughness 1 seen at grazing angles
//! (Kulla and Conty 2017, "Revisiting Physically Based Shading at Imageworks", figure 2);
//! the white furnace test bounds what is kept.
//!
//! Sampling picks the specular lobe (VNDF) or the diffuse one (cosine) with a probability
//! from their estimated weights at `wo`, and returns the density of the whole mixture, which
//! [`eval`] also returns for any `wi`, so next-event estimation can weight by MIS.
use crate::math::sqrt;
use crate::sampling;
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

/// Smallest GGX alpha: below it the lobe is narrower than `f32` can evaluate steadily (its
/// peak `1 / (pi alpha^2)` is 3.2e5 here), and a mirror is close enough.
pub const MIN_ALPHA: f32 = 1e-3;

/// A metallic-roughness material.
#[derive(Copy, Clone, Debug)]
pub struct Pbr {
    pub base_color: Vec3,
    /// 0 dielectric, 1 metal.
    pub metallic: f32,
    /// Perceptual roughness: GGX alpha is its square (at least [`MIN_ALPHA`]).
    pub roughness: f32,
    /// The dielectric's index of refraction (its specular `F0`).
    pub ior: f32,
}

/// A direction sampled by [`sample`].
#[derive(Copy, Clone, Debug)]
pub struct PbrSample {
    pub wi: Vec3,
    /// `f |cos wi| / pdf`; zero when the sample falls below the surface.
    pub weight: Vec3,
    /// Solid-angle density of the whole sampling strategy for `wi` (0: no sample).
    pub pdf: f32,
}

/// GGX alpha of perceptual roughness `r`.
pub fn alpha(r: f32) -> f32 {
    (r * r).max(MIN_ALPHA)
}

/// The GGX distribution of normals `D(wm)` (per unit solid angle of `wm`, projected: its
/// integral times `wm.z` over the hemisphere is 1).
pub fn ggx_d(wm: Vec3, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let c2 = wm.z * wm.z;
    let k = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * k * k)
}

/// Smith's `Lambda(w)` for GGX: the shadowed fraction's auxiliary function.
pub fn ggx_lambda(w: Vec3, alpha: f32) -> f32 {
    let c2 = w.z * w.z;
    if c2 <= 0.0 {
        return f32::INFINITY;
    }
    let t2 = (1.0 - c2).max(0.0) / c2;
    (sqrt(1.0 + alpha * alpha * t2) - 1.0) * 0.5
}

/// Masking of one direction, `G1 = 1 / (1 + Lambda)`.
pub fn ggx_g1(w: Vec3, alpha: f32) -> f32 {
    1.0 / (1.0 + ggx_lambda(w, alpha))
}

/// Height-correlated masking-shadowing of a pair, `G2 = 1 / (1 + Lambda(wo) + Lambda(wi))`.
pub fn ggx_g2(wo: Vec3, wi: Vec3, alpha: f32) -> f32 {
    1.0 / (1.0 + ggx_lambda(wo, alpha) + ggx_lambda(wi, alpha))
}

/// A microfacet normal visible from `wo` (`wo.z > 0`), with density [`vndf_pdf`]
/// (Heitz 2018, listing 1).
pub fn sample_vndf(wo: Vec3, alpha: f32, u1: f32, u2: f32) -> Vec3 {
    // The view direction in the hemisphere configuration (alpha = 1).
    let wh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let t1 = if wh.z < 0.99999 {
        Vec3::Z.cross(wh).normalize()
    } else {
        Vec3::X
    };
    let t2 = wh.cross(t1);
    // A point on the disk, warped onto the part of the hemisphere's projection it sees.
    let (px, py) = sampling::uniform_disk(u1, u2);
    let h = sqrt((1.0 - px * px).max(0.0));
    let s = 0.5 * (1.0 + wh.z);
    let py = (1.0 - s) * h + s * py;
    let pz = sqrt((1.0 - px * px - py * py).max(0.0));
    let nh = t1 * px + t2 * py + wh * pz;
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

/// Density of [`sample_vndf`]: `G1(wo) max(0, wo.wm) D(wm) / wo.z`.
pub fn vndf_pdf(wo: Vec3, wm: Vec3, alpha: f32) -> f32 {
    ggx_g1(wo, alpha) * wo.dot(wm).max(0.0) * ggx_d(wm, alpha) / wo.z
}

/// Schlick's Fresnel at cosine `c` from the reflectance `f0` at normal incidence.
fn schlick(f0: Vec3, c: f32) -> Vec3 {
    let m = (1.0 - c).clamp(0.0, 1.0);
    let m2 = m * m;
    f0 + (Vec3::ONE - f0) * (m2 * m2 * m)
}

/// The dielectric's reflectance at normal incidence.
fn dielectric_f0(ior: f32) -> f32 {
    let r = (ior - 1.0) / (ior + 1.0);
    r * r
}

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Probability that [`sample`] takes the specular lobe at `wo`: the lobes' estimated
/// weights, the metal's whole and the dielectric's Fresnel at `wo` against the diffuse
/// base's albedo.
fn specular_probability(m: &Pbr, wo: Vec3) -> f32 {
    let f0 = dielectric_f0(m.ior);
    let spec = m.metallic + (1.0 - m.metallic) * schlick(Vec3::splat(f0), wo.z).x;
    let diffuse = (1.0 - m.metallic) * luminance(m.base_color).max(0.0) * (1.0 - f0);
    if spec + diffuse > 0.0 {
        spec / (spec + diffuse)
    } else {
        1.0
    }
}

/// Ashikhmin and Shirley's diffuse term without the albedo: `28 / (23 pi) (1 - F0)` times
/// the two `1 - (1 - cos / 2)^5` factors.
fn coupled_diffuse(f0: f32, cos_o: f32, cos_i: f32) -> f32 {
    let fall = |c: f32| {
        let m = 1.0 - 0.5 * c;
        let m2 = m * m;
        1.0 - m2 * m2 * m
    };
    28.0 / (23.0 * PI) * (1.0 - f0) * fall(cos_o) * fall(cos_i)
}

/// `(f(wo, wi) wi.z, pdf)`: the BSDF times the cosine (zero below the surface) and the
/// density with which [`sample`] returns `wi`.
pub fn eval(m: &Pbr, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return (Vec3::ZERO, 0.0);
    }
    let a = alpha(m.roughness);
    let wm = (wo + wi).normalize();
    let (cos_o, cos_i, cos_h) = (wo.z, wi.z, wo.dot(wm).max(0.0));
    let spec = ggx_d(wm, a) * ggx_g2(wo, wi, a) / (4.0 * cos_o * cos_i);
    let f0 = dielectric_f0(m.ior);
    let metal = schlick(m.base_color, cos_h) * (spec * m.metallic);
    let dielectric = schlick(Vec3::splat(f0), cos_h) * spec + m.base_color * coupled_diffuse(f0, cos_o, cos_i);
    let f = metal + dielectric * (1.0 - m.metallic);
    let p_spec = specular_probability(m, wo);
    let pdf_spec = if cos_h > 0.0 {
        vndf_pdf(wo, wm, a) / (4.0 * cos_h)
    } else {
        0.0
    };
    let pdf = p_spec * pdf_spec + (1.0 - p_spec) * sampling::cosine_pdf(cos_i);
    (f * cos_i, pdf)
}

/// A direction `wi` for the viewer `wo` from three uniform numbers: the specular lobe by its
/// visible normals or the diffuse lobe by the cosine, chosen by `u3`.
pub fn sample(m: &Pbr, wo: Vec3, u1: f32, u2: f32, u3: f32) -> PbrSample {
    let none = PbrSample {
        wi: Vec3::Z,
        weight: Vec3::ZERO,
        pdf: 0.0,
    };
    if wo.z <= 0.0 {
        return none;
    }
    let wi = if u3 < specular_probability(m, wo) {
        let wm = sample_vndf(wo, alpha(m.roughness), u1, u2);
        2.0 * wo.dot(wm) * wm - wo
    } else {
        sampling::cosine_hemisphere(Vec3::Z, u1, u2)
    };
    let (f_cos, pdf) = eval(m, wo, wi);
    if pdf <= 0.0 || pdf.is_nan() {
        return PbrSample { wi, ..none };
    }
    PbrSample {
        wi,
        weight: f_cos / pdf,
        pdf,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn rng() -> Rng {
        Rng::new(7, 11, 13)
    }

    fn dir(cos: f32) -> Vec3 {
        Vec3::new(sqrt(1.0 - cos * cos), 0.0, cos)
    }

    fn white(metallic: f32, roughness: f32) -> Pbr {
        Pbr {
            base_color: Vec3::ONE,
            metallic,
            roughness,
            ior: 1.5,
        }
    }

    /// Mean and standard error of `weight.x` over `n` samples.
    fn albedo(m: &Pbr, wo: Vec3, n: u32) -> (f64, f64) {
        let mut r = rng();
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let x = sample(m, wo, r.next_f32(), r.next_f32(), r.next_f32()).weight.x as f64;
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        (mean, ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
    }

    #[test]
    fn schlick_matches_its_closed_form() {
        let f = schlick(Vec3::splat(0.04), 0.3).x;
        assert!((f - (0.04 + 0.96 * 0.7f32.powi(5))).abs() < 1e-6);
    }

    #[test]
    fn white_furnace_keeps_energy_within_bounds() {
        // Single-scattering GGX: a white metal keeps nearly all at low roughness (we require
        // 97% below roughness 0.25 at cos >= 0.3) and loses much at high roughness: at
        // alpha = 1 seen from the normal, D = 1/pi and G2 = 2 mu / (1 + mu), so its albedo is
        // int D G2 / 4 = 1 - ln 2 exactly (checked below). A white dielectric
        // keeps at least its coupled diffuse base's albedo,
        // 28/23 (1 - F0) fall(cos_o) 2 int_0^1 fall(mu) mu dmu (the specular layer adds).
        for roughness in [0.05, 0.2, 0.5, 0.8, 1.0] {
            for cos in [1.0, 0.7, 0.3, 0.1] {
                for metallic in [1.0, 0.0] {
                    let (e, se) = albedo(&white(metallic, roughness), dir(cos), 40_000);
                    assert!(
                        e <= 1.0 + 4.0 * se + 1e-3,
                        "m {metallic} r {roughness} cos {cos}: {e} +- {se}"
                    );
                    let floor = if metallic == 0.0 {
                        let fall = |c: f64| 1.0 - (1.0 - 0.5 * c).powi(5);
                        let steps = 1000;
                        let integral: f64 = (0..steps)
                            .map(|k| {
                                let mu = (k as f64 + 0.5) / steps as f64;
                                fall(mu) * mu
                            })
                            .sum::<f64>()
                            / steps as f64;
                        let f0 = dielectric_f0(1.5) as f64;
                        28.0 / 23.0 * (1.0 - f0) * fall(cos as f64) * 2.0 * integral
                    } else if roughness < 0.25 && cos >= 0.3 {
                        0.97
                    } else {
                        0.25
                    };
                    assert!(
                        e >= floor - 4.0 * se,
                        "m {metallic} r {roughness} cos {cos}: {e} +- {se}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_white_metal_of_roughness_one_keeps_one_minus_ln_2_at_normal_incidence() {
        let (e, se) = albedo(&white(1.0, 1.0), Vec3::Z, 200_000);
        let want = 1.0 - core::f64::consts::LN_2;
        assert!((e - want).abs() < 4.0 * se, "{e} +- {se}, want {want}");
    }

    #[test]
    fn sampling_agrees_with_eval_by_another_estimator() {
        // The mean of sample().weight equals the integral of eval's f cos, estimated with
        // cosine-distributed directions instead.
        for (metallic, roughness, cos) in [(0.0, 0.3, 0.8), (1.0, 0.5, 0.5), (0.5, 0.7, 0.2), (0.0, 1.0, 0.9)] {
            let m = Pbr {
                base_color: Vec3::new(0.8, 0.5, 0.2),
                metallic,
                roughness,
                ior: 1.5,
            };
            let wo = dir(cos);
            let (a, se_a) = albedo(&m, wo, 100_000);
            let mut r = Rng::new(3, 5, 8);
            let n = 400_000;
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let wi = sampling::cosine_hemisphere(Vec3::Z, r.next_f32(), r.next_f32());
                let x = (eval(&m, wo, wi).0.x / sampling::cosine_pdf(wi.z)) as f64;
                s += x;
                s2 += x * x;
            }
            let b = s / n as f64;
            let se_b = ((s2 / n as f64 - b * b).max(0.0) / n as f64).sqrt();
            let tol = 5.0 * (se_a * se_a + se_b * se_b).sqrt() + 1e-3;
            assert!(
                (a - b).abs() < tol,
                "{metallic} {roughness} {cos}: {a} vs {b} (tol {tol})"
            );
        }
    }

    #[test]
    fn sampled_pdf_and_weight_equal_eval() {
        let m = Pbr {
            base_color: Vec3::new(0.9, 0.6, 0.3),
            metallic: 0.4,
            roughness: 0.35,
            ior: 1.45,
        };
        let mut r = rng();
        for k in 0..2000 {
            let wo = dir(0.05 + 0.95 * r.next_f32());
            let s = sample(&m, wo, r.next_f32(), r.next_f32(), r.next_f32());
            if s.pdf == 0.0 {
                continue;
            }
            let (f, pdf) = eval(&m, wo, s.wi);
            assert!((pdf - s.pdf).abs() <= 1e-3 * pdf, "{k}: {pdf} vs {}", s.pdf);
            assert!((f / pdf - s.weight).abs().max_element() <= 1e-3 * s.weight.max_element().max(1e-3));
        }
    }

    #[test]
    fn the_brdf_is_reciprocal() {
        let m = Pbr {
            base_color: Vec3::new(0.7, 0.4, 0.9),
            metallic: 0.3,
            roughness: 0.45,
            ior: 1.5,
        };
        let mut r = rng();
        for _ in 0..1000 {
            let a = sampling::uniform_sphere(r.next_f32(), r.next_f32());
            let b = sampling::uniform_sphere(r.next_f32(), r.next_f32());
            let (a, b) = (Vec3::new(a.x, a.y, a.z.abs()), Vec3::new(b.x, b.y, b.z.abs()));
            if a.z < 1e-3 || b.z < 1e-3 {
                continue;
            }
            let fab = eval(&m, a, b).0 / b.z;
            let fba = eval(&m, b, a).0 / a.z;
            assert!(
                (fab - fba).abs().max_element() <= 1e-4 * fab.max_element().max(1.0),
                "{fab} {fba}"
            );
        }
    }

    #[test]
    fn extreme_inputs_stay_finite() {
        let wos = [Vec3::Z, dir(1e-4), dir(0.5)];
        for roughness in [0.0, 1.0] {
            for base in [Vec3::ZERO, Vec3::ONE] {
                for metallic in [0.0, 1.0] {
                    let m = Pbr {
                        base_color: base,
                        metallic,
                        roughness,
                        ior: 1.5,
                    };
                    let mut r = rng();
                    for wo in wos {
                        for _ in 0..200 {
                            let s = sample(&m, wo, r.next_f32(), r.next_f32(), r.next_f32());
                            assert!(
                                s.weight.is_finite() && s.pdf.is_finite() && s.pdf >= 0.0,
                                "{m:?} {wo}: {s:?}"
                            );
                            assert!(s.weight.min_element() >= 0.0);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn sampling_passes_chi_square() {
        let cases = [(0.3, 0.8, 0.0), (0.6, 0.4, 0.5), (0.9, 0.15, 1.0), (0.5, 1.0, 0.2)];
        // Bonferroni: each case and each sampler tested at 0.01 / 8.
        let level = 0.01 / (2 * cases.len()) as f64;
        for (roughness, cos, metallic) in cases {
            let wo = dir(cos);
            let a = alpha(roughness);
            let vndf = crate::chi2::p_value(
                &|r: &mut Rng| {
                    let wm = sample_vndf(wo, a, r.next_f32(), r.next_f32());
                    let wi = 2.0 * wo.dot(wm) * wm - wo;
                    (wi.z > 0.0).then_some(wi)
                },
                &|wi: Vec3| {
                    let wm = (wo + wi).normalize();
                    if wi.z <= 0.0 {
                        0.0
                    } else {
                        vndf_pdf(wo, wm, a) / (4.0 * wo.dot(wm))
                    }
                },
            );
            assert!(vndf > level, "VNDF r {roughness} cos {cos}: p = {vndf}");
            let m = Pbr {
                base_color: Vec3::new(0.6, 0.6, 0.6),
                metallic,
                roughness,
                ior: 1.5,
            };
            let mixture = crate::chi2::p_value(
                &|r: &mut Rng| {
                    let s = sample(&m, wo, r.next_f32(), r.next_f32(), r.next_f32());
                    (s.pdf > 0.0).then_some(s.wi)
                },
                &|wi: Vec3| eval(&m, wo, wi).1,
            );
            assert!(
                mixture > level,
                "mixture r {roughness} cos {cos} m {metallic}: p = {mixture}"
            );
        }
    }
}
