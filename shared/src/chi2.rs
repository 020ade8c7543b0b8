//! A chi-square goodness-of-fit test of a direction sampler against its density, for the
//! samplers' unit tests (pbrt-v4's `chi2.cpp` method): directions binned over the sphere by
//! `(z, phi)`, expected counts from the density integrated over each bin with a midpoint
//! rule, bins expecting fewer than 5 pooled, the statistic turned into a p-value by the
//! Wilson-Hilferty normal approximation.
use crate::math::sqrt;
use crate::rng::Rng;
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

const Z_BINS: usize = 40;
const PHI_BINS: usize = 40;
const SAMPLES: usize = 200_000;

/// The p-value of `SAMPLES` directions from `draw` (`None`: no sample) against density `pdf`
/// (per unit solid angle): small when they disagree.
pub fn p_value(draw: &dyn Fn(&mut Rng) -> Option<Vec3>, pdf: &dyn Fn(Vec3) -> f32) -> f64 {
    let bin = |z: usize, p: usize| z * PHI_BINS + p;
    let mut observed = vec![0f64; Z_BINS * PHI_BINS];
    let mut r = Rng::new(17, 19, 23);
    for _ in 0..SAMPLES {
        if let Some(w) = draw(&mut r) {
            let z = (((w.z + 1.0) * 0.5 * Z_BINS as f32) as usize).min(Z_BINS - 1);
            let mut phi = w.y.atan2(w.x);
            if phi < 0.0 {
                phi += 2.0 * PI;
            }
            let p = ((phi / (2.0 * PI) * PHI_BINS as f32) as usize).min(PHI_BINS - 1);
            observed[bin(z, p)] += 1.0;
        }
    }
    const SUB: usize = 8;
    let (mut chi2, mut dof) = (0.0f64, 0i32);
    let (mut pooled_o, mut pooled_e) = (0.0, 0.0);
    for z in 0..Z_BINS {
        for p in 0..PHI_BINS {
            let mut sum = 0.0f64;
            for i in 0..SUB {
                for j in 0..SUB {
                    let zz = -1.0 + 2.0 * (z as f32 + (i as f32 + 0.5) / SUB as f32) / Z_BINS as f32;
                    let phi = (p as f32 + (j as f32 + 0.5) / SUB as f32) / PHI_BINS as f32 * 2.0 * PI;
                    let s = sqrt((1.0 - zz * zz).max(0.0));
                    sum += pdf(Vec3::new(s * phi.cos(), s * phi.sin(), zz)) as f64;
                }
            }
            // A bin's solid angle is dz dphi.
            let area = (2.0 / Z_BINS as f64) * (2.0 * core::f64::consts::PI / PHI_BINS as f64);
            let expected = sum / (SUB * SUB) as f64 * area * SAMPLES as f64;
            let o = observed[bin(z, p)];
            if expected < 5.0 {
                pooled_o += o;
                pooled_e += expected;
            } else {
                chi2 += (o - expected).powi(2) / expected;
                dof += 1;
            }
        }
    }
    if pooled_e >= 5.0 {
        chi2 += (pooled_o - pooled_e).powi(2) / pooled_e;
        dof += 1;
    }
    let k = (dof - 1).max(1) as f64;
    let z = ((chi2 / k).powf(1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / (2.0 / (9.0 * k)).sqrt();
    0.5 * erfc(z / core::f64::consts::SQRT_2)
}

/// Complementary error function (Numerical Recipes' `erfcc`, relative error below 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[test]
fn a_wrong_density_fails_and_the_right_one_passes() {
    let draw = |r: &mut Rng| Some(crate::sampling::cosine_hemisphere(Vec3::Z, r.next_f32(), r.next_f32()));
    assert!(p_value(&draw, &|w: Vec3| crate::sampling::cosine_pdf(w.z)) > 0.01);
    assert!(p_value(&draw, &|w: Vec3| if w.z > 0.0 { 0.5 / PI } else { 0.0 }) < 1e-6);
}
