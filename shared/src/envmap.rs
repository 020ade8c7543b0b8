//! An HDR environment map: radiance from every direction, read from an equirectangular image
//! and importance sampled in proportion to its radiance (pbrt-v4's `ImageInfiniteLight`, with
//! Walker's alias method, in Vose's construction, instead of its piecewise-constant 2D
//! distribution: one table read picks a texel).
//!
//! Directions and texels (world `+y` up): a direction at polar angle `theta` from `+y` and
//! azimuth `phi = atan2(x, -z)` lies at `u = 1/2 + phi / (2 pi)`, `v = theta / pi`, so the
//! image's centre looks along `-z` and its top row straight up, as Blender and most HDRI
//! viewers show them. The map turns about `+y` by [`Env::rotation`] and is scaled by
//! [`Env::intensity`].
//!
//! Sampling: a texel by the alias table, then a point uniform in it in `(u, v)`: the
//! solid-angle density is `pdf_uv / (2 pi^2 sin theta)` with `pdf_uv` the texel's probability
//! times the texel count ([`EnvEntry::pdf`]). Radiance is looked up bilinearly (smooth where
//! the map is seen directly), so a texel shows some of its neighbours' light: a texel's
//! probability is proportional to the largest luminance in its 3x3 neighbourhood times
//! `sin theta` at its centre (see [`texel_weight`]), which keeps the density above a fixed
//! fraction of the radiance everywhere, as pbrt-v4 builds its distribution from the filtered
//! image, instead of sampling a bright sun's bilinear fringe at the sky's rate.
use crate::math::{acos, atan2, floor, sin_cos, sqrt};
use crate::sync::at;
use bytemuck::{Pod, Zeroable};
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

/// One texel of the map with its alias-table entry (32 bytes: one read picks a texel).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct EnvEntry {
    /// Linear radiance.
    pub rgb: [f32; 3],
    /// Density of the texel in `(u, v)` (its probability times the texel count).
    pub pdf: f32,
    /// Probability of keeping this texel when the table's first pick lands on it.
    pub q: f32,
    /// The texel taken otherwise.
    pub alias: u32,
    pub _pad: [u32; 2],
}

const _: () = assert!(core::mem::size_of::<EnvEntry>() == 32);

/// The sampling weight of texel `(x, y)` of a `width x height` map whose luminances `lum`
/// gives: the largest luminance of it and its eight neighbours (wrapping around in `x`,
/// clamped in `y`) times `sin theta` at its centre. Used by the host to build the table.
pub fn texel_weight(lum: &dyn Fn(u32, u32) -> f32, x: u32, y: u32, width: u32, height: u32) -> f32 {
    let mut m = 0.0f32;
    for dy in 0..3u32 {
        let yy = (y + dy).clamp(1, height) - 1;
        for dx in 0..3u32 {
            let xx = (x + width + dx - 1) % width;
            m = m.max(lum(xx, yy));
        }
    }
    let (sin_theta, _) = sin_cos(PI * (y as f32 + 0.5) / height as f32);
    m * sin_theta
}

/// Luminance (Rec. 709) of linear `rgb`.
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// A direction sampled from the map.
#[derive(Copy, Clone, Debug)]
pub struct EnvSample {
    pub dir: Vec3,
    /// Radiance arriving from `dir` (intensity applied).
    pub radiance: Vec3,
    /// Solid-angle density (0: the map is black, no sample).
    pub pdf: f32,
}

/// The map as the renderer reads it.
#[derive(Copy, Clone)]
pub struct Env<'a> {
    /// `width * height` entries, row 0 at the top.
    pub entries: &'a [EnvEntry],
    pub width: u32,
    pub height: u32,
    /// Cosine and sine of the map's turn about `+y` (counter-clockwise seen from above).
    pub rotation: (f32, f32),
    pub intensity: f32,
}

impl Env<'_> {
    /// `(u, v)` in `[0, 1]^2` and `sin theta` of world direction `d` (unit).
    fn uv(&self, d: Vec3) -> (f32, f32, f32) {
        let (c, s) = self.rotation;
        // Into the map's frame: turn by minus the rotation about y.
        let x = c * d.x - s * d.z;
        let z = s * d.x + c * d.z;
        let theta = acos(d.y);
        let u = 0.5 + atan2(x, -z) / (2.0 * PI);
        let sin_theta = sqrt((1.0 - d.y * d.y).max(0.0));
        (u - floor(u), (theta / PI).clamp(0.0, 1.0), sin_theta)
    }

    /// World direction at `(u, v)`.
    fn direction(&self, u: f32, v: f32) -> Vec3 {
        let (sin_t, cos_t) = sin_cos(PI * v);
        let (sin_p, cos_p) = sin_cos(2.0 * PI * (u - 0.5));
        let (x, y, z) = (sin_t * sin_p, cos_t, -sin_t * cos_p);
        let (c, s) = self.rotation;
        Vec3::new(c * x + s * z, y, -s * x + c * z)
    }

    fn texel(&self, x: u32, y: u32) -> Vec3 {
        let e = at(self.entries, y * self.width + x);
        Vec3::new(e.rgb[0], e.rgb[1], e.rgb[2])
    }

    /// Radiance of rays leaving the scene along unit `d`: bilinear between texel centres,
    /// wrapping around in `u`, clamped at the poles.
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        let (u, v, _) = self.uv(d);
        let fx = u * self.width as f32 - 0.5;
        let fy = (v * self.height as f32 - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (floor(fx), floor(fy));
        let (tx, ty) = (fx - x0, fy - y0);
        let w = self.width as i32;
        let wrap = |x: i32| (((x % w) + w) % w) as u32;
        let (xa, xb) = (wrap(x0 as i32), wrap(x0 as i32 + 1));
        let ya = y0 as u32;
        let yb = (ya + 1).min(self.height - 1);
        let top = self.texel(xa, ya) * (1.0 - tx) + self.texel(xb, ya) * tx;
        let bottom = self.texel(xa, yb) * (1.0 - tx) + self.texel(xb, yb) * tx;
        (top * (1.0 - ty) + bottom * ty) * self.intensity
    }

    /// Solid-angle density with which [`Env::sample`] returns unit direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        let (u, v, sin_theta) = self.uv(d);
        if sin_theta <= 0.0 {
            return 0.0;
        }
        let x = ((u * self.width as f32) as u32).min(self.width - 1);
        let y = ((v * self.height as f32) as u32).min(self.height - 1);
        at(self.entries, y * self.width + x).pdf / (2.0 * PI * PI * sin_theta)
    }

    /// A direction toward the map, from four uniform numbers: `u1`, `u2` pick the texel by
    /// the alias table, `u3`, `u4` the point in it.
    pub fn sample(&self, u1: f32, u2: f32, u3: f32, u4: f32) -> EnvSample {
        let n = self.width * self.height;
        let first = ((u1 * n as f32) as u32).min(n - 1);
        let e = at(self.entries, first);
        let texel = if u2 < e.q { first } else { e.alias };
        let chosen = at(self.entries, texel);
        let (x, y) = (texel % self.width, texel / self.width);
        let u = (x as f32 + u3) / self.width as f32;
        let v = (y as f32 + u4) / self.height as f32;
        let dir = self.direction(u, v);
        let sin_theta = sqrt((1.0 - dir.y * dir.y).max(0.0));
        let pdf = if sin_theta > 0.0 && chosen.pdf > 0.0 {
            chosen.pdf / (2.0 * PI * PI * sin_theta)
        } else {
            0.0
        };
        EnvSample {
            dir,
            radiance: self.radiance(dir),
            pdf,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// A map whose texels have the given radiance, with an alias table built the simple way
    /// (every texel keeps itself with probability min(1, p N), excess donated in order): a
    /// valid alias table, so the sampler's tests do not depend on the host's builder.
    fn map(width: u32, height: u32, rgb: &dyn Fn(u32, u32) -> Vec3) -> Vec<EnvEntry> {
        let n = (width * height) as usize;
        let mut weight = vec![0f64; n];
        let mut entries = vec![EnvEntry::default(); n];
        let lum = |x: u32, y: u32| luminance(rgb(x, y).to_array());
        for y in 0..height {
            for x in 0..width {
                let c = rgb(x, y);
                let i = (y * width + x) as usize;
                entries[i].rgb = [c.x, c.y, c.z];
                weight[i] = texel_weight(&lum, x, y, width, height) as f64;
            }
        }
        let total: f64 = weight.iter().sum();
        let scaled: Vec<f64> = weight.iter().map(|w| w / total * n as f64).collect();
        // Vose.
        let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
        let mut s = scaled.clone();
        while !small.is_empty() && !large.is_empty() {
            let (l, g) = (small.pop().unwrap(), *large.last().unwrap());
            entries[l].q = s[l] as f32;
            entries[l].alias = g as u32;
            s[g] -= 1.0 - s[l];
            if s[g] < 1.0 {
                large.pop();
                small.push(g);
            }
        }
        for i in large.into_iter().chain(small) {
            entries[i].q = 1.0;
            entries[i].alias = i as u32;
        }
        for i in 0..n {
            entries[i].pdf = scaled[i] as f32;
        }
        entries
    }

    fn sunny(x: u32, y: u32) -> Vec3 {
        let sky = Vec3::new(0.2, 0.3, 0.5) * (1.0 + y as f32 / 8.0);
        if (40..43).contains(&x) && (5..7).contains(&y) {
            sky + Vec3::splat(500.0)
        } else {
            sky
        }
    }

    const W: u32 = 64;
    const H: u32 = 32;

    fn turned(entries: &[EnvEntry], degrees: f32) -> Env<'_> {
        let (s, c) = degrees.to_radians().sin_cos();
        Env {
            entries,
            width: W,
            height: H,
            rotation: (c, s),
            intensity: 2.0,
        }
    }

    #[test]
    fn texel_centres_map_back_to_their_direction() {
        let e = map(W, H, &sunny);
        let env = turned(&e, 37.0);
        for (u, v) in [(0.5, 0.5), (0.1, 0.3), (0.9, 0.8)] {
            let d = env.direction(u, v);
            let (u2, v2, _) = env.uv(d);
            assert!((u - u2).abs() < 1e-5 && (v - v2).abs() < 1e-5, "{u},{v} -> {u2},{v2}");
        }
        // The unrotated map's centre looks along -z, its top up.
        let e0 = turned(&e, 0.0);
        assert!((e0.direction(0.5, 0.5) - Vec3::NEG_Z).length() < 1e-6);
        assert!((e0.direction(0.3, 0.0) - Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn samples_carry_their_own_density_and_radiance() {
        let e = map(W, H, &sunny);
        let env = turned(&e, 37.0);
        let mut r = Rng::new(1, 2, 3);
        for _ in 0..5000 {
            let s = env.sample(r.next_f32(), r.next_f32(), r.next_f32(), r.next_f32());
            if s.dir.y.abs() == 1.0 {
                continue;
            }
            assert!(s.pdf > 0.0);
            let p = env.pdf(s.dir);
            assert!((p - s.pdf).abs() <= 1e-3 * p, "{p} vs {}", s.pdf);
            assert!((env.radiance(s.dir) - s.radiance).length() <= 1e-4 * s.radiance.length());
        }
    }

    #[test]
    fn the_density_integrates_to_one_and_the_estimate_to_the_maps_power() {
        let e = map(W, H, &sunny);
        let env = turned(&e, 0.0);
        let mut r = Rng::new(4, 5, 6);
        let n = 400_000;
        // Uniform directions: E[pdf / (1 / 4 pi)] = 1.
        let mut total = 0.0f64;
        for _ in 0..n {
            let d = crate::sampling::uniform_sphere(r.next_f32(), r.next_f32());
            total += env.pdf(d) as f64 * 4.0 * core::f64::consts::PI;
        }
        let mean = total / n as f64;
        assert!((mean - 1.0).abs() < 0.02, "density integrates to {mean}");
        // The importance-sampled estimate of the radiance's integral over the sphere agrees
        // with a fine midpoint quadrature of it over (u, v) (the bilinear lookup is not the
        // texels' step function, so there is no closed form).
        let mut is = 0.0f64;
        for _ in 0..n {
            let s = env.sample(r.next_f32(), r.next_f32(), r.next_f32(), r.next_f32());
            // A point exactly at a pole has no density (and measure zero).
            if s.pdf > 0.0 {
                is += (s.radiance.x / s.pdf) as f64;
            }
        }
        let is = is / n as f64;
        let (gw, gh) = (8 * W, 8 * H);
        let mut quad = 0.0f64;
        for j in 0..gh {
            for i in 0..gw {
                let (u, v) = ((i as f32 + 0.5) / gw as f32, (j as f32 + 0.5) / gh as f32);
                let sin_theta = (PI * v).sin() as f64;
                quad += env.radiance(env.direction(u, v)).x as f64 * sin_theta;
            }
        }
        let quad = quad * 2.0 * core::f64::consts::PI * core::f64::consts::PI / (gw * gh) as f64;
        assert!(
            (is - quad).abs() < 0.01 * quad,
            "importance sampled {is} vs quadrature {quad}"
        );
    }

    #[test]
    fn sampling_passes_chi_square() {
        // A softer sun than `sunny`'s: the test's bins integrate the density numerically, and
        // a 500x step inside a bin would test that integration rather than the sampler.
        let e = map(W, H, &|x, y| sunny(x, y).min(Vec3::splat(20.0)));
        for degrees in [0.0, 37.0] {
            let env = turned(&e, degrees);
            let p = crate::chi2::p_value(
                &|r: &mut Rng| {
                    let s = env.sample(r.next_f32(), r.next_f32(), r.next_f32(), r.next_f32());
                    (s.pdf > 0.0).then_some(s.dir)
                },
                &|d: Vec3| env.pdf(d),
            );
            // Bonferroni over the two rotations at 0.01.
            assert!(p > 0.005, "rotation {degrees}: p = {p}");
        }
    }

    #[test]
    fn a_black_map_gives_no_samples() {
        let e = map(4, 2, &|_, _| Vec3::ZERO);
        let e: Vec<EnvEntry> = e.into_iter().map(|x| EnvEntry { pdf: 0.0, ..x }).collect();
        let env = Env {
            entries: &e,
            width: 4,
            height: 2,
            rotation: (1.0, 0.0),
            intensity: 1.0,
        };
        let s = env.sample(0.3, 0.4, 0.5, 0.6);
        assert_eq!(s.pdf, 0.0);
        assert_eq!(env.radiance(Vec3::Y), Vec3::ZERO);
    }
}
