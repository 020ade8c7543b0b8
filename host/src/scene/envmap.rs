//! HDR environment maps on the host: an equirectangular `.exr` or `.hdr` (Radiance RGBE)
//! image read through the `image` crate as linear RGB, cleaned, and turned into the GPU's
//! texel-and-alias-table entries (`shared::envmap`), built once at load.
//!
//! The alias table is Vose's construction ("A linear algorithm for generating random numbers
//! with a given distribution", IEEE TSE 1991) in `f64`, over the weights of
//! `shared::envmap::texel_weight`.
use super::SceneError;
use shared::envmap::{luminance, texel_weight, Env, EnvEntry};
use std::path::Path;

/// Widest map kept; wider ones are halved (2x2 box filter) until they fit, with a warning.
/// 4096 x 2048 is 2^23 texels: the sampler picks a texel from one `f32` uniform number,
/// whose 24 bits of mantissa could not reach every texel of an 8192 x 4096 map.
pub const MAX_WIDTH: u32 = 4096;

/// An environment map ready for the GPU.
#[derive(Clone, Debug)]
pub struct EnvMap {
    pub width: u32,
    pub height: u32,
    /// `width * height` texels with their alias-table entries, row 0 at the top.
    pub entries: Vec<EnvEntry>,
    /// The file it came from (or a label).
    pub source: String,
}

impl EnvMap {
    /// Reads an equirectangular `.exr` or `.hdr` file. Unreadable, corrupt or empty files
    /// are errors naming the file; non-finite or negative texels become black, wider maps
    /// than [`MAX_WIDTH`] are halved, and a map that is not twice as wide as high is used as
    /// it is: each with a warning.
    pub fn load(path: &Path) -> Result<(EnvMap, Vec<String>), SceneError> {
        let file = path.display().to_string();
        let error = |message: String| SceneError::Environment {
            file: file.clone(),
            message,
        };
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        if ext != "exr" && ext != "hdr" {
            return Err(error(
                "not an HDR image (environment maps are .exr or .hdr files)".into(),
            ));
        }
        let image = image::ImageReader::open(path)
            .map_err(|e| error(format!("cannot read the file: {e}")))?
            .with_guessed_format()
            .map_err(|e| error(format!("cannot read the file: {e}")))?
            .decode()
            .map_err(|e| error(format!("cannot decode the image: {e}")))?
            .into_rgb32f();
        let (width, height) = image.dimensions();
        if width == 0 || height == 0 {
            return Err(error("the image is empty".into()));
        }
        let rgb: Vec<[f32; 3]> = image.pixels().map(|p| p.0).collect();
        Ok(EnvMap::from_rgb(width, height, &rgb, &file))
    }

    /// A map from linear RGB texels (row 0 at the top), cleaned and with its alias table;
    /// `source` names it in warnings.
    pub fn from_rgb(width: u32, height: u32, rgb: &[[f32; 3]], source: &str) -> (EnvMap, Vec<String>) {
        let mut warnings = Vec::new();
        let mut texels: Vec<[f32; 3]> = rgb.to_vec();
        texels.resize((width * height) as usize, [0.0; 3]);
        let bad = texels
            .iter_mut()
            .flat_map(|t| t.iter_mut())
            .filter(|c| !(c.is_finite() && **c >= 0.0))
            .map(|c| *c = 0.0)
            .count();
        if bad > 0 {
            warnings.push(format!(
                "{source}: {bad} texel components were NaN, infinite or negative: they are black"
            ));
        }
        if width != 2 * height {
            warnings.push(format!(
                "{source}: {width}x{height} is not an equirectangular 2:1 map: it is stretched over the sphere"
            ));
        }
        let (mut w, mut h) = (width, height);
        while w > MAX_WIDTH {
            (texels, w, h) = halve(&texels, w, h);
        }
        if w != width {
            warnings.push(format!(
                "{source}: {width}x{height} is larger than the renderer keeps: halved to {w}x{h}"
            ));
        }
        let entries = alias_table(&texels, w, h);
        (
            EnvMap {
                width: w,
                height: h,
                entries,
                source: source.to_string(),
            },
            warnings,
        )
    }

    /// The map as the path tracer reads it, turned by `rotation_deg` about `+y` and scaled by
    /// `intensity`.
    pub fn env(&self, rotation_deg: f32, intensity: f32) -> Env<'_> {
        let (s, c) = rotation_deg.to_radians().sin_cos();
        Env {
            entries: &self.entries,
            width: self.width,
            height: self.height,
            rotation: (c, s),
            intensity,
        }
    }

    /// Total luminance power of the map over the sphere (texel luminance times solid angle).
    pub fn power(&self) -> f64 {
        let (w, h) = (self.width as f64, self.height as f64);
        self.entries
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let y = (i as u32 / self.width) as f64;
                let (t0, t1) = (std::f64::consts::PI * y / h, std::f64::consts::PI * (y + 1.0) / h);
                luminance(e.rgb) as f64 * (2.0 * std::f64::consts::PI / w) * (t0.cos() - t1.cos())
            })
            .sum()
    }
}

/// A map of half the width and height (odd rows and columns folded into the last).
fn halve(t: &[[f32; 3]], w: u32, h: u32) -> (Vec<[f32; 3]>, u32, u32) {
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = vec![[0.0f32; 3]; (nw * nh) as usize];
    let mut count = vec![0u32; (nw * nh) as usize];
    for y in 0..h {
        for x in 0..w {
            let i = ((y / 2).min(nh - 1) * nw + (x / 2).min(nw - 1)) as usize;
            let c = t[(y * w + x) as usize];
            for k in 0..3 {
                out[i][k] += c[k];
            }
            count[i] += 1;
        }
    }
    for (o, n) in out.iter_mut().zip(count) {
        for c in o.iter_mut() {
            *c /= n as f32;
        }
    }
    (out, nw, nh)
}

/// Texels with Vose's alias table over [`texel_weight`]; a black map gets density 0
/// everywhere (and keeps every texel).
fn alias_table(texels: &[[f32; 3]], w: u32, h: u32) -> Vec<EnvEntry> {
    let lum = |x: u32, y: u32| luminance(texels[(y * w + x) as usize]);
    let weights: Vec<f64> = (0..w * h)
        .map(|i| texel_weight(&lum, i % w, i / w, w, h) as f64)
        .collect();
    let total: f64 = weights.iter().sum();
    let n = weights.len();
    let mut entries: Vec<EnvEntry> = texels
        .iter()
        .enumerate()
        .map(|(i, t)| EnvEntry {
            rgb: *t,
            pdf: 0.0,
            q: 1.0,
            alias: i as u32,
            _pad: [0; 2],
        })
        .collect();
    if !(total > 0.0 && total.is_finite()) {
        return entries;
    }
    let mut scaled: Vec<f64> = weights.iter().map(|w| w / total * n as f64).collect();
    for (e, s) in entries.iter_mut().zip(&scaled) {
        e.pdf = *s as f32;
    }
    let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
    while let (Some(&l), Some(&g)) = (small.last(), large.last()) {
        small.pop();
        entries[l].q = scaled[l] as f32;
        entries[l].alias = g as u32;
        scaled[g] -= 1.0 - scaled[l];
        if scaled[g] < 1.0 {
            large.pop();
            small.push(g);
        }
    }
    // What is left keeps itself (1 up to rounding).
    entries
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use shared::rng::Rng;

    fn hdri(name: &str) -> Option<std::path::PathBuf> {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/hdri")
            .join(name);
        if p.exists() {
            Some(p)
        } else {
            eprintln!(
                "skipped: {} is not there (the steering data beside the repository)",
                p.display()
            );
            None
        }
    }

    fn temp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("raytrace-envmap-{}-{name}", std::process::id()));
        let _ = std::fs::create_dir_all(&d);
        d
    }

    #[test]
    fn the_shared_hdris_load_and_their_samples_follow_the_light() {
        for name in ["studio.exr", "sunset.exr", "city.exr", "forest.exr"] {
            let Some(path) = hdri(name) else { return };
            let (map, warnings) = EnvMap::load(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!((map.width, map.height), (512, 256), "{name}");
            // Some of these maps hold slightly negative texels (studio.exr: 2028 components).
            assert!(warnings.iter().all(|w| w.contains("negative")), "{name}: {warnings:?}");
            assert!(map.power() > 0.0);
            assert!(map.entries.iter().all(|e| e.rgb.iter().all(|c| c.is_finite())));
            // The table's probabilities sum to one, and the sampled estimate of the map's
            // luminance power matches the texel sum within the bilinear lookup's smoothing.
            let p: f64 = map.entries.iter().map(|e| e.pdf as f64).sum::<f64>() / map.entries.len() as f64;
            assert!((p - 1.0).abs() < 1e-4, "{name}: {p}");
            let env = map.env(0.0, 1.0);
            let mut r = Rng::new(9, 8, 7);
            let n = 200_000;
            let mut est = 0.0;
            for _ in 0..n {
                let s = env.sample(r.next_f32(), r.next_f32(), r.next_f32(), r.next_f32());
                if s.pdf > 0.0 {
                    est += luminance(s.radiance.to_array()) as f64 / s.pdf as f64;
                }
            }
            let est = est / n as f64;
            assert!(
                (est - map.power()).abs() < 0.05 * map.power(),
                "{name}: {est} vs {}",
                map.power()
            );
        }
    }

    #[test]
    fn a_written_hdr_file_loads_back() {
        let dir = temp("hdr");
        let path = dir.join("grad.hdr");
        let (w, h) = (16u32, 8u32);
        let img = image::Rgb32FImage::from_fn(w, h, |x, y| image::Rgb([x as f32 * 0.5, y as f32, 2.0]));
        image::DynamicImage::ImageRgb32F(img).save(&path).unwrap();
        let (map, warnings) = EnvMap::load(&path).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        let t = map.entries[(3 * w + 5) as usize].rgb;
        // RGBE keeps 8 bits of mantissa a pixel.
        for (got, want) in t.iter().zip([2.5f32, 3.0, 2.0]) {
            assert!((got - want).abs() <= want / 64.0, "{t:?}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn bad_texels_are_black_with_one_warning() {
        let rgb = vec![[1.0, f32::NAN, 2.0], [f32::INFINITY, -1.0, 0.5], [0.25; 3], [1.0; 3]];
        let (map, warnings) = EnvMap::from_rgb(2, 2, &rgb, "bad.exr");
        assert_eq!(map.entries[0].rgb, [1.0, 0.0, 2.0]);
        assert_eq!(map.entries[1].rgb, [0.0, 0.0, 0.5]);
        let bad: Vec<_> = warnings.iter().filter(|w| w.contains("NaN")).collect();
        assert_eq!(bad.len(), 1, "{warnings:?}");
        assert!(bad[0].contains("bad.exr") && bad[0].contains("3 texel"), "{bad:?}");
        // 2x2 is not 2:1.
        assert!(warnings.iter().any(|w| w.contains("2:1")), "{warnings:?}");
        // A black map still loads: no samples, black sky.
        let (black, _) = EnvMap::from_rgb(4, 2, &[[0.0; 3]; 8], "black.exr");
        let s = black.env(0.0, 1.0).sample(0.5, 0.5, 0.5, 0.5);
        assert_eq!(s.pdf, 0.0);
        assert_eq!(black.env(0.0, 1.0).radiance(Vec3::X), Vec3::ZERO);
    }

    #[test]
    fn bad_files_are_named() {
        let dir = temp("bad");
        let missing = dir.join("missing.exr");
        let e = EnvMap::load(&missing).unwrap_err().to_string();
        assert!(e.contains("missing.exr") && e.contains("cannot read"), "{e}");
        let png = dir.join("map.png");
        std::fs::write(&png, b"not really").unwrap();
        let e = EnvMap::load(&png).unwrap_err().to_string();
        assert!(e.contains(".exr or .hdr"), "{e}");
        if let Some(studio) = hdri("studio.exr") {
            let bytes = std::fs::read(studio).unwrap();
            let cut = dir.join("cut.exr");
            std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
            let e = EnvMap::load(&cut).unwrap_err().to_string();
            assert!(e.contains("cut.exr") && e.contains("decode"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn wide_maps_are_halved() {
        let (w, h) = (MAX_WIDTH * 2 + 2, 3);
        let rgb = vec![[1.0f32, 2.0, 3.0]; (w * h) as usize];
        let (map, warnings) = EnvMap::from_rgb(w, h, &rgb, "wide.exr");
        assert!(map.width <= MAX_WIDTH, "{}", map.width);
        assert!(warnings.iter().any(|w| w.contains("halved")), "{warnings:?}");
        assert!(map.entries.iter().all(|e| e.rgb == [1.0, 2.0, 3.0]));
    }
}
