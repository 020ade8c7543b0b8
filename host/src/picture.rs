//! A rendered picture and what is done with it afterwards: linear radiance from the sample
//! sums, saving (PNG from the display image, EXR from linear radiance), difference statistics
//! between two renders, and a side-by-side comparison image with a difference heat map.
//! (Plots are `crate::bench::plot`'s.)
use anyhow::{bail, ensure, Context, Result};
use image::{ImageFormat, Rgb, Rgb32FImage, RgbImage};
use std::path::{Path, PathBuf};

/// Rec.709 / sRGB luminance weights of linear R, G, B.
const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// Extensions `Picture::save` understands.
const SUPPORTED: &str = ".png (display image, 8-bit sRGB) and .exr (linear radiance, f32)";

/// Pixels whose luminance differs by more than this fraction of the image mean count as differing.
const DIFFERING_FRACTION: f64 = 0.05;

/// Width of the dark-grey gap between the panels of a comparison image.
const GAP: u32 = 4;
const GAP_COLOUR: [u8; 3] = [40, 40, 40];

/// An inferno-like colormap as evenly spaced stops, black first so that equal pixels are black.
const HEAT_STOPS: [[f32; 3]; 6] = [
    [0.0, 0.0, 0.0],
    [40.0, 11.0, 84.0],
    [120.0, 28.0, 109.0],
    [205.0, 62.0, 78.0],
    [249.0, 149.0, 8.0],
    [252.0, 255.0, 164.0],
];

/// One rendered image: the radiance sums the renderer accumulated and the display image it
/// derived from them. Row 0 is the top of the image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Picture {
    pub width: u32,
    pub height: u32,
    /// Per pixel, the sum of linear radiance over `samples` samples in xyz; w is a ray count.
    pub accum: Vec<[f32; 4]>,
    /// Samples per pixel summed into `accum`.
    pub samples: u32,
    /// Per pixel RGBA8 packed little-endian (`r | g << 8 | b << 16 | a << 24`), already exposed,
    /// clamped and sRGB-encoded.
    pub display: Vec<u32>,
}

impl Picture {
    /// This picture with its radiance and display codes replaced by the denoiser's (as the
    /// sums of as many samples; ray counts kept).
    pub fn denoised(self, d: &crate::cpu::Denoised) -> Picture {
        let n = self.samples as f32;
        let accum = self
            .accum
            .iter()
            .zip(&d.output)
            .map(|(a, o)| [o[0] * n, o[1] * n, o[2] * n, a[3]])
            .collect();
        Picture {
            accum,
            display: d.display.clone(),
            ..self
        }
    }

    /// Linear radiance per pixel: the sums divided by the sample count (zero for no samples).
    pub fn linear(&self) -> Vec<[f32; 3]> {
        let inv = if self.samples == 0 {
            0.0
        } else {
            1.0 / self.samples as f32
        };
        self.accum
            .iter()
            .map(|a| [a[0] * inv, a[1] * inv, a[2] * inv])
            .collect()
    }

    /// Writes by extension: `.png` the display image (8-bit sRGB RGB; the display alpha is
    /// dropped, a render being opaque), `.exr` linear radiance (f32 RGB). Other extensions are an
    /// error naming the path and the supported ones. Missing parent folders are created. The
    /// file is written under a temporary name and renamed: a file under `path` is complete.
    pub fn save(&self, path: &Path) -> Result<()> {
        let tmp = temporary(path);
        if let Err(e) = self.save_as(path, &tmp) {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
        std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
    }

    /// [`Self::save`]'s format for `path`, written to `to`.
    fn save_as(&self, path: &Path, to: &Path) -> Result<()> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("png") => {
                self.check_display(path)?;
                let bytes = self.display.iter().flat_map(|&p| rgb(p)).collect();
                let img = RgbImage::from_raw(self.width, self.height, bytes)
                    .with_context(|| format!("building the PNG image for {}", path.display()))?;
                create_parent(path)?;
                img.save_with_format(to, ImageFormat::Png)
                    .with_context(|| format!("writing PNG file {}", to.display()))
            }
            Some("exr") => {
                self.check_accum(path)?;
                let values = self.linear().into_iter().flatten().collect();
                let img = Rgb32FImage::from_raw(self.width, self.height, values)
                    .with_context(|| format!("building the EXR image for {}", path.display()))?;
                create_parent(path)?;
                img.save_with_format(to, ImageFormat::OpenExr)
                    .with_context(|| format!("writing EXR file {}", to.display()))
            }
            _ => bail!("cannot save picture as {}: supported are {SUPPORTED}", path.display()),
        }
    }

    /// Rec.709 luminance of `linear()`, averaged over the pixels (zero for an empty picture).
    pub fn mean_luminance(&self) -> f64 {
        let lin = self.linear();
        if lin.is_empty() {
            return 0.0;
        }
        lin.iter().map(|&p| luminance(p)).sum::<f64>() / lin.len() as f64
    }

    fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    fn check_accum(&self, what: &Path) -> Result<()> {
        ensure!(
            self.accum.len() == self.pixels(),
            "{}: picture is {}x{} but has {} radiance values",
            what.display(),
            self.width,
            self.height,
            self.accum.len()
        );
        Ok(())
    }

    fn check_display(&self, what: &Path) -> Result<()> {
        ensure!(
            self.display.len() == self.pixels(),
            "{}: picture is {}x{} but has {} display pixels",
            what.display(),
            self.width,
            self.height,
            self.display.len()
        );
        Ok(())
    }
}

/// The largest difference of one colour byte between two display images.
pub fn max_display_diff(a: &Picture, b: &Picture) -> u32 {
    a.display
        .iter()
        .zip(&b.display)
        .flat_map(|(x, y)| (0..3).map(move |k| ((x >> (8 * k)) & 255).abs_diff((y >> (8 * k)) & 255)))
        .max()
        .unwrap_or(0)
}

/// A packed pixel with its first and third bytes exchanged: BGRA to RGBA and back.
pub fn swap_red_blue(p: u32) -> u32 {
    (p & 0xff00_ff00) | ((p & 0xff) << 16) | ((p >> 16) & 0xff)
}

/// How two renders of the same image differ, on linear radiance.
#[derive(Clone, Debug, PartialEq)]
pub struct DiffStats {
    /// Root mean square of the per-channel differences.
    pub rmse: f64,
    /// Mean absolute per-channel difference.
    pub mean_abs: f64,
    /// Largest absolute per-channel difference.
    pub max_abs: f64,
    /// `rmse` over the mean luminance of `a` (zero if `a` is black).
    pub relative_rmse: f64,
    /// Mean R, G, B of `a`.
    pub mean_a: [f64; 3],
    /// Mean R, G, B of `b`.
    pub mean_b: [f64; 3],
    /// Fraction of pixels whose luminance differs by more than 5% of `a`'s mean luminance.
    pub differing_pixels: f64,
}

/// Compares the linear radiance of `a` (the reference) and `b` channel by channel; an error if
/// their sizes differ.
pub fn diff_stats(a: &Picture, b: &Picture) -> Result<DiffStats> {
    check_same_size(a, b)?;
    let (la, lb) = (a.linear(), b.linear());
    let n = la.len();
    let (mut sq, mut abs, mut max_abs) = (0.0f64, 0.0f64, 0.0f64);
    let (mut mean_a, mut mean_b) = ([0.0f64; 3], [0.0f64; 3]);
    for (pa, pb) in la.iter().zip(&lb) {
        for k in 0..3 {
            let d = (pa[k] as f64 - pb[k] as f64).abs();
            sq += d * d;
            abs += d;
            max_abs = max_abs.max(d);
            mean_a[k] += pa[k] as f64;
            mean_b[k] += pb[k] as f64;
        }
    }
    if n == 0 {
        return Ok(DiffStats {
            rmse: 0.0,
            mean_abs: 0.0,
            max_abs: 0.0,
            relative_rmse: 0.0,
            mean_a,
            mean_b,
            differing_pixels: 0.0,
        });
    }
    let values = (3 * n) as f64;
    let rmse = (sq / values).sqrt();
    let mean_lum = a.mean_luminance();
    let threshold = DIFFERING_FRACTION * mean_lum;
    let differing = la
        .iter()
        .zip(&lb)
        .filter(|&(&pa, &pb)| (luminance(pa) - luminance(pb)).abs() > threshold);
    Ok(DiffStats {
        rmse,
        mean_abs: abs / values,
        max_abs,
        relative_rmse: if mean_lum > 0.0 { rmse / mean_lum } else { 0.0 },
        mean_a: mean_a.map(|s| s / n as f64),
        mean_b: mean_b.map(|s| s / n as f64),
        differing_pixels: differing.count() as f64 / n as f64,
    })
}

/// Writes one PNG to `path`: `a`'s display image, `b`'s, and a heat map of the per-pixel
/// luminance difference `|a - b|` of linear radiance, side by side with 4-pixel dark-grey gaps
/// (width `3W + 8`). The heat map is black where the pictures are equal and reaches the top of
/// an inferno-like colormap at `scale`; larger differences saturate.
pub fn write_comparison(a: &Picture, b: &Picture, scale: f32, path: &Path) -> Result<()> {
    check_same_size(a, b).with_context(|| format!("writing comparison image {}", path.display()))?;
    for p in [a, b] {
        p.check_accum(path)?;
        p.check_display(path)?;
    }
    ensure!(
        scale.is_finite() && scale > 0.0,
        "{}: heat-map scale must be positive and finite, got {scale}",
        path.display()
    );
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    ensure!(
        ext.as_deref() == Some("png"),
        "cannot write comparison image {}: it is written as .png only",
        path.display()
    );
    let (w, h) = (a.width, a.height);
    let width = w
        .checked_mul(3)
        .and_then(|v| v.checked_add(2 * GAP))
        .with_context(|| format!("{}: comparison of {w}-pixel-wide pictures is too wide", path.display()))?;
    let (la, lb) = (a.linear(), b.linear());
    let mut img = RgbImage::from_pixel(width, h, Rgb(GAP_COLOUR));
    for y in 0..h {
        for x in 0..w {
            let i = y as usize * w as usize + x as usize;
            img.put_pixel(x, y, Rgb(rgb(a.display[i])));
            img.put_pixel(w + GAP + x, y, Rgb(rgb(b.display[i])));
            let d = (luminance(la[i]) - luminance(lb[i])).abs() as f32 / scale;
            img.put_pixel(2 * (w + GAP) + x, y, Rgb(heat(d)));
        }
    }
    create_parent(path)?;
    img.save_with_format(path, ImageFormat::Png)
        .with_context(|| format!("writing comparison image {}", path.display()))
}

/// The heat-map colour of `t` in [0, 1]; above 1 (and NaN) saturates to the top.
fn heat(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    let f = t * (HEAT_STOPS.len() - 1) as f32;
    let i = (f.floor() as usize).min(HEAT_STOPS.len() - 2);
    let u = f - i as f32;
    let (lo, hi) = (HEAT_STOPS[i], HEAT_STOPS[i + 1]);
    let c = |k: usize| (lo[k] + (hi[k] - lo[k]) * u).round().clamp(0.0, 255.0) as u8;
    let mut rgb = [c(0), c(1), c(2)];
    if t > 0.0 && rgb == [0, 0, 0] {
        // Any difference at all stays distinguishable from equality.
        rgb = [1, 0, 1];
    }
    rgb
}

/// The R, G, B bytes of a packed display pixel.
fn rgb(p: u32) -> [u8; 3] {
    let [r, g, b, _] = p.to_le_bytes();
    [r, g, b]
}

fn luminance(p: [f32; 3]) -> f64 {
    LUMA[0] * p[0] as f64 + LUMA[1] * p[1] as f64 + LUMA[2] * p[2] as f64
}

fn check_same_size(a: &Picture, b: &Picture) -> Result<()> {
    ensure!(
        (a.width, a.height) == (b.width, b.height),
        "pictures differ in size: {}x{} and {}x{}",
        a.width,
        a.height,
        b.width,
        b.height
    );
    ensure!(
        a.accum.len() == b.accum.len(),
        "pictures hold different numbers of radiance values: {} and {}",
        a.accum.len(),
        b.accum.len()
    );
    Ok(())
}

/// Where a file is written before it is renamed to `path` (so that no half-written file
/// carries the final name): `.NAME.partial-PID` beside it, hidden and without the final
/// extension, so that no pattern such as `shard-*.exr` takes it.
pub fn temporary(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or("out".into(), |s| s.to_string_lossy().to_string());
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

fn create_parent(path: &Path) -> Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => std::fs::create_dir_all(dir)
            .with_context(|| format!("creating folder {} for {}", dir.display(), path.display())),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    #[test]
    fn red_and_blue_swap_and_swap_back() {
        assert_eq!(swap_red_blue(0xff11_2233), 0xff33_2211);
        assert_eq!(swap_red_blue(swap_red_blue(0x1234_5678)), 0x1234_5678);
    }

    fn temp(name: &str) -> PathBuf {
        std::env::temp_dir()
            .join(format!("raytrace-picture-test-{}", std::process::id()))
            .join(name)
    }

    /// A picture whose every pixel is distinct, with `samples` samples summed.
    fn gradient(w: u32, h: u32, samples: u32) -> Picture {
        let n = (w * h) as usize;
        let accum = (0..n)
            .map(|i| {
                let v = i as f32 / n as f32;
                [
                    v * samples as f32,
                    (1.0 - v) * samples as f32,
                    0.25 * samples as f32 + i as f32,
                    samples as f32,
                ]
            })
            .collect();
        let display = (0..n as u32)
            .map(|i| (i * 7 % 256) | (i / 3 % 256) << 8 | 200 << 16 | (255 - i % 4) << 24)
            .collect();
        Picture {
            width: w,
            height: h,
            accum,
            samples,
            display,
        }
    }

    #[test]
    fn png_round_trip_is_exact_with_row_zero_on_top() {
        let p = gradient(7, 5, 4);
        let path = temp("nested/folder/round.png");
        p.save(&path).unwrap();
        let decoded = image::open(&path).unwrap();
        assert_eq!(decoded.color(), image::ColorType::Rgb8);
        let back = decoded.to_rgb8();
        assert_eq!(back.dimensions(), (7, 5));
        for y in 0..5 {
            for x in 0..7 {
                assert_eq!(
                    back.get_pixel(x, y).0,
                    rgb(p.display[(y * 7 + x) as usize]),
                    "pixel {x},{y}"
                );
            }
        }
    }

    #[test]
    fn exr_round_trip_keeps_linear_values() {
        let p = gradient(6, 3, 3);
        let path = temp("round.exr");
        p.save(&path).unwrap();
        let back = image::open(&path).unwrap().into_rgb32f();
        assert_eq!(back.dimensions(), (6, 3));
        let lin = p.linear();
        for y in 0..3 {
            for x in 0..6 {
                assert_eq!(back.get_pixel(x, y).0, lin[(y * 6 + x) as usize], "pixel {x},{y}");
            }
        }
    }

    #[test]
    fn unknown_extension_errors_naming_the_path() {
        let p = gradient(2, 2, 1);
        for name in ["pic.jpg", "pic"] {
            let path = temp(name);
            let err = format!("{:#}", p.save(&path).unwrap_err());
            assert!(err.contains(&path.display().to_string()), "{err}");
            assert!(err.contains(".png") && err.contains(".exr"), "{err}");
        }
    }

    #[test]
    fn mismatched_buffers_error_instead_of_panicking() {
        let mut p = gradient(3, 3, 1);
        p.display.pop();
        assert!(p.save(&temp("short.png")).is_err());
        p.accum.pop();
        assert!(p.save(&temp("short.exr")).is_err());
    }

    #[test]
    fn linear_and_mean_luminance() {
        let p = Picture {
            width: 1,
            height: 2,
            accum: vec![[2.0, 4.0, 6.0, 9.0], [0.0; 4]],
            samples: 2,
            display: vec![0; 2],
        };
        assert_eq!(p.linear(), vec![[1.0, 2.0, 3.0], [0.0; 3]]);
        let lum = 0.2126 + 0.7152 * 2.0 + 0.0722 * 3.0;
        assert!((p.mean_luminance() - lum / 2.0).abs() < 1e-9);
        assert_eq!(Picture::default().mean_luminance(), 0.0);
    }

    #[test]
    fn diff_of_identical_pictures_is_zero() {
        let p = gradient(8, 4, 5);
        let d = diff_stats(&p, &p).unwrap();
        assert_eq!(
            (d.rmse, d.mean_abs, d.max_abs, d.relative_rmse, d.differing_pixels),
            (0.0, 0.0, 0.0, 0.0, 0.0)
        );
        assert_eq!(d.mean_a, d.mean_b);
    }

    #[test]
    fn diff_of_a_known_offset() {
        let flat = |v: f32| Picture {
            width: 4,
            height: 2,
            accum: vec![[v * 2.0, v * 2.0, v * 2.0, 0.0]; 8],
            samples: 2,
            display: vec![0; 8],
        };
        let (a, b) = (flat(0.5), flat(0.75));
        let d = diff_stats(&a, &b).unwrap();
        assert!((d.rmse - 0.25).abs() < 1e-12);
        assert!((d.mean_abs - 0.25).abs() < 1e-12);
        assert!((d.max_abs - 0.25).abs() < 1e-12);
        assert!((d.relative_rmse - 0.5).abs() < 1e-9, "{}", d.relative_rmse);
        assert_eq!(d.mean_a, [0.5; 3]);
        assert_eq!(d.mean_b, [0.75; 3]);
        assert_eq!(d.differing_pixels, 1.0);

        let mut c = a.clone();
        c.accum[3] = [1.0 * 2.0, 0.5 * 2.0, 0.5 * 2.0, 0.0];
        let d = diff_stats(&a, &c).unwrap();
        assert_eq!(d.differing_pixels, 1.0 / 8.0);
        assert!((d.max_abs - 0.5).abs() < 1e-12);
        assert!((d.rmse - (0.25f64 / 24.0).sqrt()).abs() < 1e-12);
        assert_eq!(diff_stats(&flat(0.0), &flat(0.0)).unwrap().relative_rmse, 0.0);
    }

    #[test]
    fn size_mismatch_errors() {
        let err = diff_stats(&gradient(4, 3, 1), &gradient(3, 4, 1))
            .unwrap_err()
            .to_string();
        assert!(err.contains("4x3") && err.contains("3x4"), "{err}");
        assert!(write_comparison(&gradient(4, 3, 1), &gradient(4, 4, 1), 1.0, &temp("mismatch.png")).is_err());
    }

    #[test]
    fn comparison_has_three_panels_and_black_heat_where_equal() {
        let (w, h) = (5u32, 3u32);
        let a = gradient(w, h, 2);
        let mut b = a.clone();
        b.accum[(w + 2) as usize][1] += 1.0;
        let path = temp("cmp/compare.png");
        write_comparison(&a, &b, 0.5, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (3 * w + 8, h));
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                assert_eq!(img.get_pixel(x, y).0, rgb(a.display[i]));
                assert_eq!(img.get_pixel(w + 4 + x, y).0, rgb(b.display[i]));
                let heat = img.get_pixel(2 * w + 8 + x, y).0;
                if (x, y) == (2, 1) {
                    assert_ne!(heat, [0, 0, 0]);
                } else {
                    assert_eq!(heat, [0, 0, 0], "pixel {x},{y}");
                }
            }
            assert_eq!(img.get_pixel(w, y).0, GAP_COLOUR);
            assert_eq!(img.get_pixel(2 * w + 7, y).0, GAP_COLOUR);
        }
        assert!(write_comparison(&a, &b, 0.0, &path).is_err());
        assert!(write_comparison(&a, &b, 1.0, &temp("compare.exr")).is_err());
    }

    #[test]
    fn heat_map_saturates_and_stays_visible() {
        assert_eq!(heat(0.0), [0, 0, 0]);
        assert_eq!(heat(1.0), [252, 255, 164]);
        assert_eq!(heat(7.0), heat(1.0));
        assert_eq!(heat(f32::NAN), heat(1.0));
        assert_ne!(heat(1e-6), [0, 0, 0]);
    }
}
