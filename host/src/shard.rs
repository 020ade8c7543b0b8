//! Shards of a render, for farms: `render --shard I/N` traces only samples `I*S/N ..
//! (I+1)*S/N` of a frame of `S` samples per pixel and writes their radiance sums, with the
//! shard's place and a hash of everything that decides the image, into a linear EXR;
//! `raytrace merge` adds the shards of a frame back up into the picture one run makes.
//!
//! Every sample draws from its own random stream (pixel, sample index, seed), so a shard's
//! samples are exactly the ones a single run would trace; the merged sums equal a single run's
//! within float rounding (the same as one GPU run against another whose submissions were split
//! differently: sums of float sums depend on their grouping), and merging the same shards
//! again gives the same bits (shards are added in index order).
//!
//! A shard file is the EXR channels R, G, B (radiance sums over the shard's samples) and A (ray
//! counts), and the text attributes [`ATTR_SHARD`] (`I/N`), [`ATTR_SAMPLES`] (`first count
//! total`), [`ATTR_HASH`] and the display settings (exposure, gamma) a merged PNG needs. It is
//! written to a temporary name and renamed, so a file under the shard's name is complete.
use crate::cli::Prepared;
use crate::picture::{temporary, Picture};
use anyhow::{bail, ensure, Context, Result};
use exr::prelude::{AttributeValue, Image, SpecificChannels, Text, Vec2, WritableImage};
use rayon::prelude::*;
use shared::types::{Frame, RenderPush, FLAG_GAMMA2};
use std::path::{Path, PathBuf};

/// `I/N` of the shard.
pub const ATTR_SHARD: &str = "raytraceShard";
/// `first count total`: the shard's first sample, its number of samples, the frame's.
pub const ATTR_SAMPLES: &str = "raytraceSamples";
/// [`settings_hash`] of the render, hexadecimal.
pub const ATTR_HASH: &str = "raytraceHash";
/// `exposure gamma2` (`gamma2`: 0 or 1) of the display image a merged PNG is made with.
pub const ATTR_DISPLAY: &str = "raytraceDisplay";

/// Shard `index` of `count`.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Shard {
    type Err = String;

    /// `I/N` with `0 <= I < N`.
    fn from_str(s: &str) -> Result<Shard, String> {
        let bad = || format!("a shard is I/N with 0 <= I < N (for example 0/4), not {s:?}");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (u32, u32) = (
            i.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// The shard's samples of a frame of `spp` samples per pixel: (first, count). Shards
    /// differ by at most one sample; an error where there are more shards than samples.
    pub fn samples(&self, spp: u32) -> Result<(u32, u32)> {
        ensure!(
            self.count <= spp,
            "{} shards of {spp} samples per pixel: each shard needs at least one sample (use at most {spp} shards, or more --spp)",
            self.count
        );
        let at = |i: u32| (i as u64 * spp as u64 / self.count as u64) as u32;
        Ok((at(self.index), at(self.index + 1) - at(self.index)))
    }

    /// The file name `render` gives shard files by default.
    pub fn default_path(&self, scene: &str) -> PathBuf {
        PathBuf::from(format!("{scene}.shard-{}-of-{}.exr", self.index, self.count))
    }
}

/// 64-bit FNV-1a, fed piece by piece.
struct Fnv(u64);

impl Fnv {
    fn add(&mut self, bytes: &[u8]) {
        // Each piece's length first, so that pieces cannot run into each other.
        for &b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
}

/// A hash of everything that decides the image of `p`: the program's version and commit,
/// every buffer of the scene as the GPU receives it, the frame (camera, size, depth, seed,
/// flags, features), the samples per pixel and the BVH options. Shards merge only when
/// their hashes agree.
pub fn settings_hash(p: &Prepared) -> String {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    h.add(concat!(env!("CARGO_PKG_VERSION"), " ", env!("RAYTRACE_COMMIT")).as_bytes());
    let d = &p.data;
    h.add(bytemuck::cast_slice(&d.model_tris));
    h.add(bytemuck::cast_slice(&d.model_spheres));
    h.add(bytemuck::cast_slice(&d.prim_object));
    h.add(bytemuck::cast_slice(&d.objects));
    h.add(bytemuck::cast_slice(&d.materials));
    h.add(bytemuck::cast_slice(&d.light_words()));
    h.add(bytemuck::cast_slice(&d.attrs));
    h.add(bytemuck::cast_slice(&d.punctual));
    h.add(bytemuck::cast_slice(
        d.env.as_ref().map_or(&[][..], |e| e.entries.as_slice()),
    ));
    h.add(bytemuck::cast_slice(&d.textures.infos));
    h.add(bytemuck::cast_slice(&d.textures.texels));
    h.add(bytemuck::bytes_of(&p.frame));
    h.add(&p.spp.to_le_bytes());
    h.add(format!("{:?}", p.build(p.spp)).as_bytes());
    format!("{:016x}", h.0)
}

/// What a shard file holds.
#[derive(Clone, Debug)]
pub struct ShardFile {
    pub path: PathBuf,
    pub shard: Shard,
    pub first: u32,
    pub samples: u32,
    pub total: u32,
    pub hash: String,
    pub exposure: f32,
    pub gamma2: bool,
    pub width: u32,
    pub height: u32,
    /// Radiance sums (xyz) and ray counts (w) per pixel, row 0 on top.
    pub accum: Vec<[f32; 4]>,
}

/// Writes shard `shard` of `p`, whose sums `picture` holds (samples `first..` of it), to
/// `path` (an `.exr`), atomically.
pub fn write(path: &Path, picture: &Picture, shard: Shard, first: u32, p: &Prepared) -> Result<()> {
    ensure!(
        path.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("exr")),
        "{}: a shard is written as .exr (its radiance sums and sample count, which a PNG cannot hold)",
        path.display()
    );
    let (w, h) = (picture.width as usize, picture.height as usize);
    ensure!(
        picture.accum.len() == w * h,
        "shard picture holds {} pixels, not {w}x{h}",
        picture.accum.len()
    );
    let accum = &picture.accum;
    let channels = SpecificChannels::rgba(|Vec2(x, y): Vec2<usize>| {
        let a = accum[y * w + x];
        (a[0], a[1], a[2], a[3])
    });
    let mut image = Image::from_channels((w, h), channels);
    let text = |s: String| AttributeValue::Text(Text::from(s.as_str()));
    let attrs = &mut image.layer_data.attributes.other;
    attrs.insert(Text::from(ATTR_SHARD), text(shard.to_string()));
    attrs.insert(
        Text::from(ATTR_SAMPLES),
        text(format!("{first} {} {}", picture.samples, p.spp)),
    );
    attrs.insert(Text::from(ATTR_HASH), text(settings_hash(p)));
    let gamma2 = p.frame.flags & FLAG_GAMMA2 != 0;
    attrs.insert(
        Text::from(ATTR_DISPLAY),
        text(format!("{:?} {}", p.frame.exposure, gamma2 as u32)),
    );
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating folder {}", dir.display()))?;
    }
    let tmp = temporary(path);
    if let Err(e) = image.write().to_file(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("writing shard file {}", tmp.display()));
    }
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// Reads a shard file, or says what is wrong with it.
pub fn read(path: &Path) -> Result<ShardFile> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size: Vec2<usize>, _| (size.0, vec![[0f32; 4]; size.0 * size.1]),
        |(w, px): &mut (usize, Vec<[f32; 4]>), Vec2(x, y): Vec2<usize>, (r, g, b, a): (f32, f32, f32, f32)| {
            px[y * *w + x] = [r, g, b, a];
        },
    )
    .with_context(|| {
        format!(
            "reading shard file {} (an EXR written by `render --shard`)",
            path.display()
        )
    })?;
    let layer = &image.layer_data;
    let attr = |name: &str| -> Result<String> {
        let key = Text::from(name);
        match layer
            .attributes
            .other
            .get(&key)
            .or_else(|| image.attributes.other.get(&key))
        {
            Some(AttributeValue::Text(t)) => Ok(t.to_string()),
            _ => bail!(
                "{}: no {name} attribute: not a shard written by `raytrace render --shard`",
                path.display()
            ),
        }
    };
    let bad = |name: &str, v: &str| anyhow::anyhow!("{}: malformed {name} attribute {v:?}", path.display());
    let shard_text = attr(ATTR_SHARD)?;
    let shard: Shard = shard_text.parse().map_err(|_| bad(ATTR_SHARD, &shard_text))?;
    let samples_text = attr(ATTR_SAMPLES)?;
    let nums: Vec<u32> = samples_text
        .split_whitespace()
        .map(|v| v.parse())
        .collect::<Result<_, _>>()
        .map_err(|_| bad(ATTR_SAMPLES, &samples_text))?;
    let [first, samples, total] = nums[..] else {
        return Err(bad(ATTR_SAMPLES, &samples_text));
    };
    let display = attr(ATTR_DISPLAY)?;
    let (exposure, gamma2) = display
        .split_once(' ')
        .and_then(|(e, g)| Some((e.parse::<f32>().ok()?, g == "1")))
        .ok_or_else(|| bad(ATTR_DISPLAY, &display))?;
    let size = layer.size;
    let (_, accum) = layer.channel_data.pixels.clone();
    Ok(ShardFile {
        path: path.to_path_buf(),
        shard,
        first,
        samples,
        total,
        hash: attr(ATTR_HASH)?,
        exposure,
        gamma2,
        width: size.0 as u32,
        height: size.1 as u32,
        accum,
    })
}

/// Sums the shards of one frame, given in any order, into the picture a single run makes:
/// an error that names the problem where they are not the shards of one render (hashes,
/// shard counts, sizes or sample ranges disagree) or some are missing or given twice.
pub fn merge(paths: &[PathBuf]) -> Result<Picture> {
    ensure!(!paths.is_empty(), "no shard files given");
    let mut shards = paths.iter().map(|p| read(p)).collect::<Result<Vec<_>>>()?;
    let first = shards[0].clone();
    for s in &shards[1..] {
        let differs = |what: &str, a: &dyn std::fmt::Display, b: &dyn std::fmt::Display| {
            anyhow::anyhow!(
                "{} and {} are not shards of the same render: their {what} differ ({a} and {b})",
                first.path.display(),
                s.path.display()
            )
        };
        if s.hash != first.hash {
            return Err(differs("scene and settings (hashes)", &first.hash, &s.hash));
        }
        if s.shard.count != first.shard.count {
            return Err(differs("shard counts", &first.shard.count, &s.shard.count));
        }
        if (s.width, s.height) != (first.width, first.height) {
            return Err(differs(
                "image sizes",
                &format!("{}x{}", first.width, first.height),
                &format!("{}x{}", s.width, s.height),
            ));
        }
    }
    shards.sort_by_key(|s| s.shard.index);
    let n = first.shard.count;
    let mut missing = Vec::new();
    let mut twice = Vec::new();
    for i in 0..n {
        let with: Vec<&ShardFile> = shards.iter().filter(|s| s.shard.index == i).collect();
        match with.len() {
            0 => missing.push(i.to_string()),
            1 => {}
            _ => twice.push(format!(
                "{i} ({})",
                with.iter()
                    .map(|s| s.path.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
        }
    }
    ensure!(
        twice.is_empty(),
        "shards given more than once: {} (each of the {n} shards exactly once)",
        twice.join("; ")
    );
    ensure!(
        missing.is_empty(),
        "shards missing of {n}: {} (render them with `raytrace render ... --shard I/{n}`)",
        missing.join(", ")
    );
    let mut next = 0;
    for s in &shards {
        ensure!(
            s.first == next && s.total == first.total,
            "{}: samples {}..{} of {}, where shard {} should hold samples from {next} of {}",
            s.path.display(),
            s.first,
            s.first + s.samples,
            s.total,
            s.shard,
            first.total
        );
        next += s.samples;
    }
    ensure!(
        next == first.total,
        "the shards hold {next} samples per pixel of {}",
        first.total
    );
    let total = first.total;
    let frame = Frame {
        width: first.width,
        height: first.height,
        exposure: first.exposure,
        flags: if first.gamma2 { FLAG_GAMMA2 } else { 0 },
        ..Default::default()
    };
    Ok(sum_pictures(
        shards.into_iter().map(|s| s.accum).collect(),
        total,
        &frame,
    ))
}

/// The picture of the sums `parts` (of `samples` samples per pixel in all, each part a sum
/// for every pixel of `frame`) added in the order given, its display image made as the
/// renderers make it for `frame` (its size, exposure and gamma).
pub fn sum_pictures(parts: Vec<Vec<[f32; 4]>>, samples: u32, frame: &Frame) -> Picture {
    let (w, h) = (frame.width, frame.height);
    let mut parts = parts.into_iter();
    // The first part is the start of the sum: a renderer's sums start at +0, and +0 + x is
    // x for every sum (none is -0), so this is the same as adding it to zeros, without
    // making and touching another image's memory.
    let mut accum = parts.next().unwrap_or_default();
    accum.resize((w * h) as usize, [0.0; 4]);
    let rest: Vec<Vec<[f32; 4]>> = parts.collect();
    // Pixels in parallel, each one's parts added in the parts' order (the same bits as one
    // pass after another).
    accum
        .par_chunks_mut(w.max(1) as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let at = y * w as usize;
            for part in &rest {
                for (a, b) in row.iter_mut().zip(&part[at..]) {
                    *a = [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]];
                }
            }
        });
    let push = RenderPush {
        samples,
        ..Default::default()
    };
    let display = crate::cpu::display_image(&accum, &push, frame);
    Picture {
        width: w,
        height: h,
        accum,
        samples,
        display,
    }
}
