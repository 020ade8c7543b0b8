//! The scene's textures as the GPU reads them: one buffer of RGBA8 texels holding every
//! texture's full mip chain, and a [`TextureInfo`] per texture (layout in `shared::texture`).
//! The CPU executor samples these same texels with the same `shared::texture` code.
//!
//! Images are decoded with the `image` crate (PNG, JPEG, WebP, EXR; any pixel format, converted
//! to RGBA8; float images are linear and are sRGB-encoded when they are colours). Mip levels
//! halve each side, rounding down (pbrt-v4 `util/mipmap.cpp` builds the same pyramid, after
//! rounding up to powers of two, which this does not need): each texel of a smaller level is the
//! area-weighted box-filter average of the texels it covers: 2x2 texels where both sides are
//! even, three along an odd side (5 to 2: weights 0.4, 0.4, 0.2 and 0.2, 0.4, 0.4), so the
//! average of the texture is kept at every level. Colour (sRGB) textures are filtered in linear space
//! and re-encoded, their RGB weighted by alpha (a transparent texel's colour does not bleed into
//! its neighbours); data textures are averaged as they are.
//!
//! Textures larger than [`TextureLimits::max_side`] are resampled down with the same filter,
//! and the set is kept within [`TextureLimits::max_texels`] (what one storage buffer holds) by
//! dropping the top level of the largest textures; each with a warning naming the texture and
//! both sizes. A file or embedded image added twice (same bytes, same colour space) is stored
//! once: glTF materials share images.
use rayon::prelude::*;
use shared::texture::{
    chain_texels, level_size, linear_to_srgb, mip_levels, srgb_to_linear, tex_flags, TextureInfo, WRAP_CLAMP,
    WRAP_MIRROR, WRAP_REPEAT,
};
use std::collections::{HashMap, HashSet};
use std::hash::{Hash, Hasher};
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// How a texture is read between and beyond its texels: `shared::texture::WRAP_*` for each
/// axis, and nearest-texel lookups instead of bilinear ones.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Sampler {
    pub wrap_u: u32,
    pub wrap_v: u32,
    pub nearest: bool,
}

impl Default for Sampler {
    /// glTF's default: repeat on both axes, bilinear.
    fn default() -> Sampler {
        Sampler {
            wrap_u: WRAP_REPEAT,
            wrap_v: WRAP_REPEAT,
            nearest: false,
        }
    }
}

impl Sampler {
    /// A glTF sampler's wrap modes (`wrapS` is `u`, `wrapT` is `v`); nearest lookups where its
    /// magnification filter is `NEAREST` (pixel art), else bilinear (and always mipmapped).
    pub fn from_gltf(s: &gltf::texture::Sampler) -> Sampler {
        let wrap = |m: gltf::texture::WrappingMode| match m {
            gltf::texture::WrappingMode::ClampToEdge => WRAP_CLAMP,
            gltf::texture::WrappingMode::MirroredRepeat => WRAP_MIRROR,
            gltf::texture::WrappingMode::Repeat => WRAP_REPEAT,
        };
        Sampler {
            wrap_u: wrap(s.wrap_s()),
            wrap_v: wrap(s.wrap_t()),
            nearest: s.mag_filter() == Some(gltf::texture::MagFilter::Nearest),
        }
    }
}

/// The largest textures a [`TextureSet`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureLimits {
    /// Largest width or height of a texture: larger images are resampled down to it.
    pub max_side: u32,
    /// Texels of all textures with their mip levels together (4 bytes each): the largest
    /// textures lose their top levels until the set fits. At most 2^31.
    pub max_texels: u64,
}

impl Default for TextureLimits {
    /// 8192 texels a side, 2^28 texels (1 GiB) in all.
    fn default() -> TextureLimits {
        TextureLimits {
            max_side: 8192,
            max_texels: 1 << 28,
        }
    }
}

/// Where a texture's image came from, to store it once.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
enum Source {
    /// A file, by its canonical path where it has one.
    File(PathBuf),
    /// Image bytes, by their length and hash.
    Bytes(usize, u64),
}

/// Every texture of a scene: [`TextureSet::infos`] and [`TextureSet::texels`] are the GPU
/// buffers' contents; a material refers to a texture by its index in `infos`.
#[derive(Clone, Debug, Default)]
pub struct TextureSet {
    /// One entry per texture index.
    pub infos: Vec<TextureInfo>,
    /// Every texture's mip chain, RGBA8 with red in the low byte (`shared::texture`).
    pub texels: Vec<u32>,
    /// The name of each texture (its file, or what the caller called it) for messages.
    names: Vec<String>,
    limits: TextureLimits,
    /// Texture index by source, colour space and flags.
    by_source: HashMap<(Source, bool, u32), u32>,
    /// A texture index holding the texels of a source in a colour space.
    data_by_source: HashMap<(Source, bool), u32>,
    /// Sources that could not be read (warned about once).
    failed: HashSet<Source>,
}

impl TextureSet {
    /// An empty set with the default [`TextureLimits`].
    pub fn new() -> TextureSet {
        TextureSet::default()
    }

    /// An empty set with these limits (`max_texels` at most 2^31, `max_side` at least 1).
    pub fn with_limits(limits: TextureLimits) -> TextureSet {
        TextureSet {
            limits: clamp_limits(limits),
            ..TextureSet::default()
        }
    }

    /// Number of textures.
    pub fn len(&self) -> usize {
        self.infos.len()
    }

    /// Whether the set has no textures.
    pub fn is_empty(&self) -> bool {
        self.infos.is_empty()
    }

    /// The name texture `index` was added under.
    pub fn name(&self, index: u32) -> &str {
        &self.names[index as usize]
    }

    /// The limits textures are kept within.
    pub fn limits(&self) -> TextureLimits {
        self.limits
    }

    /// Adds a texture made from `img` and returns its index. `srgb`: its RGB are colours
    /// encoded with the sRGB curve (glTF base colour and emissive textures), else data
    /// (normals, metallic-roughness, occlusion). The full mip chain is built here; an image
    /// larger than the limits is downsampled with a warning naming `name` and both sizes.
    pub fn add_image(
        &mut self,
        img: &image::DynamicImage,
        srgb: bool,
        sampler: Sampler,
        name: &str,
        warnings: &mut Vec<String>,
    ) -> u32 {
        let (offset, width, height, levels) = self.store(img, srgb, name, warnings);
        let index = self.infos.len() as u32;
        self.infos.push(TextureInfo {
            offset,
            width,
            height,
            levels,
            flags: tex_flags(srgb, sampler.nearest, sampler.wrap_u, sampler.wrap_v),
            _pad: [0; 3],
        });
        self.names.push(name.to_string());
        self.fit_budget(warnings);
        index
    }

    /// Adds the image file at `path` (any format the `image` crate reads, told by its
    /// contents) as [`TextureSet::add_image`] does; the same file added again in the same
    /// colour space returns the same index (a new one sharing its texels where the sampler
    /// differs). A missing, unreadable or corrupt file gives a warning naming it and the
    /// problem (once) and `None`: the caller uses a neutral value instead.
    pub fn add_file(&mut self, path: &Path, srgb: bool, sampler: Sampler, warnings: &mut Vec<String>) -> Option<u32> {
        let source = Source::File(path.canonicalize().unwrap_or_else(|_| path.to_path_buf()));
        let name = path.display().to_string();
        self.add_source(source, srgb, sampler, &name, warnings, || {
            let reader = image::ImageReader::open(path).map_err(|e| format!("cannot read the texture: {e}"))?;
            decode(
                reader
                    .with_guessed_format()
                    .map_err(|e| format!("cannot read the texture: {e}"))?,
            )
        })
    }

    /// Adds an image held in memory (a glTF image in a buffer view or a `data:` URI) as
    /// [`TextureSet::add_file`] does; `mime_hint` (the glTF `mimeType`) is used where the bytes
    /// do not tell their format. `name` names it in warnings.
    pub fn add_bytes(
        &mut self,
        bytes: &[u8],
        mime_hint: Option<&str>,
        name: &str,
        srgb: bool,
        sampler: Sampler,
        warnings: &mut Vec<String>,
    ) -> Option<u32> {
        let mut hasher = std::hash::DefaultHasher::new();
        bytes.hash(&mut hasher);
        let source = Source::Bytes(bytes.len(), hasher.finish());
        self.add_source(source, srgb, sampler, name, warnings, || {
            let mut reader = image::ImageReader::new(Cursor::new(bytes))
                .with_guessed_format()
                .map_err(|e| format!("cannot read the texture: {e}"))?;
            if reader.format().is_none() {
                if let Some(format) = mime_hint.and_then(image::ImageFormat::from_mime_type) {
                    reader.set_format(format);
                }
            }
            decode(reader)
        })
    }

    /// The texture of `source`, from what is stored or else from `load` (a decoded image or
    /// what went wrong).
    fn add_source(
        &mut self,
        source: Source,
        srgb: bool,
        sampler: Sampler,
        name: &str,
        warnings: &mut Vec<String>,
        load: impl FnOnce() -> Result<image::DynamicImage, String>,
    ) -> Option<u32> {
        let flags = tex_flags(srgb, sampler.nearest, sampler.wrap_u, sampler.wrap_v);
        if let Some(&index) = self.by_source.get(&(source.clone(), srgb, flags)) {
            return Some(index);
        }
        if self.failed.contains(&source) {
            return None;
        }
        let index = if let Some(&same) = self.data_by_source.get(&(source.clone(), srgb)) {
            // The same texels under another sampler.
            let info = TextureInfo {
                flags,
                ..self.infos[same as usize]
            };
            self.infos.push(info);
            self.names.push(name.to_string());
            self.infos.len() as u32 - 1
        } else {
            match load() {
                Ok(img) => {
                    let index = self.add_image(&img, srgb, sampler, name, warnings);
                    self.data_by_source.insert((source.clone(), srgb), index);
                    index
                }
                Err(problem) => {
                    warnings.push(format!("{name}: {problem}"));
                    self.failed.insert(source);
                    return None;
                }
            }
        };
        self.by_source.insert((source, srgb, flags), index);
        Some(index)
    }

    /// Applies new limits to the textures stored (dropping top levels, with a warning for
    /// each texture reduced) and to those added from now on: for a budget known only once the
    /// device is (its largest storage buffer).
    pub fn limit(&mut self, limits: TextureLimits, warnings: &mut Vec<String>) {
        self.limits = clamp_limits(limits);
        let mut shrunk = Vec::new();
        for (offset, indices) in self.blocks() {
            let first = self.infos[indices[0]];
            let mut info = first;
            while info.width.max(info.height) > self.limits.max_side && info.levels > 1 {
                info = without_top_level(info);
            }
            if info != first {
                self.retarget(offset, &indices, info);
                shrunk.push((indices[0], first));
            }
        }
        for (index, before) in shrunk {
            let after = self.infos[index];
            warnings.push(format!(
                "{}: texture of {}x{} texels reduced to {}x{} (at most {} texels a side)",
                self.names[index], before.width, before.height, after.width, after.height, self.limits.max_side
            ));
        }
        self.fit_budget(warnings);
    }

    /// Stores the mip chain of `img` at the end of the texel buffer: its offset, size and
    /// levels.
    fn store(
        &mut self,
        img: &image::DynamicImage,
        srgb: bool,
        name: &str,
        warnings: &mut Vec<String>,
    ) -> (u32, u32, u32, u32) {
        let (mut w, mut h) = (img.width(), img.height());
        let mut words = to_words(img, srgb);
        if w == 0 || h == 0 {
            warnings.push(format!("{name}: the image is empty ({w}x{h}): a white texel is used"));
            (w, h, words) = (1, 1, vec![u32::MAX]);
        }
        let offset = self.texels.len() as u32;
        let max_side = self.limits.max_side;
        // The level the next one is filtered from, in linear space (none: level 0's words).
        let mut linear: Option<Vec<[f32; 4]>> = None;
        if w.max(h) > max_side {
            let scale = max_side as f64 / w.max(h) as f64;
            let fit = |n: u32| ((n as f64 * scale).round() as u32).clamp(1, max_side);
            let (nw, nh) = (fit(w), fit(h));
            warnings.push(format!(
                "{name}: texture of {w}x{h} texels downsampled to {nw}x{nh} (at most {max_side} texels a side)"
            ));
            let level = resample(&words_source(&words, srgb), w, h, nw, nh, srgb);
            words = encode(&level, srgb);
            linear = Some(level);
            (w, h) = (nw, nh);
        }
        let levels = mip_levels(w, h);
        self.texels.reserve(chain_texels(w, h, levels) as usize);
        self.texels.extend_from_slice(&words);
        drop(words);
        for l in 1..levels {
            let (sw, sh) = level_size(w, h, l - 1);
            let (dw, dh) = level_size(w, h, l);
            let next = match &linear {
                Some(src) => resample(&|i: usize| src[i], sw, sh, dw, dh, srgb),
                None => {
                    let start = self.texels.len() - (sw * sh) as usize;
                    resample(&words_source(&self.texels[start..], srgb), sw, sh, dw, dh, srgb)
                }
            };
            self.texels.extend(encode(&next, srgb));
            linear = Some(next);
        }
        (offset, w, h, levels)
    }

    /// Texture indices grouped by the texels they share (their offset), in buffer order.
    fn blocks(&self) -> Vec<(u32, Vec<usize>)> {
        let mut by_offset: HashMap<u32, Vec<usize>> = HashMap::new();
        for (i, info) in self.infos.iter().enumerate() {
            by_offset.entry(info.offset).or_default().push(i);
        }
        let mut blocks: Vec<(u32, Vec<usize>)> = by_offset.into_iter().collect();
        blocks.sort_by_key(|(offset, _)| *offset);
        blocks
    }

    /// Points the textures `indices` that share the texels at `offset` at the levels of
    /// `info` (their own flags kept).
    fn retarget(&mut self, offset: u32, indices: &[usize], info: TextureInfo) {
        for &i in indices {
            debug_assert_eq!(self.infos[i].offset, offset);
            self.infos[i] = TextureInfo {
                flags: self.infos[i].flags,
                ..info
            };
        }
    }

    /// Drops the top level of the largest texture until all fit in `max_texels`, with a
    /// warning for each texture reduced, then compacts the buffer.
    fn fit_budget(&mut self, warnings: &mut Vec<String>) {
        let budget = self.limits.max_texels;
        let blocks = self.blocks();
        let before: Vec<TextureInfo> = blocks.iter().map(|(_, indices)| self.infos[indices[0]]).collect();
        let mut after = before.clone();
        let mut total: u64 = after.iter().map(chain_len).sum();
        while total > budget {
            let Some(largest) = after
                .iter_mut()
                .filter(|info| info.levels > 1)
                .max_by_key(|info| info.width as u64 * info.height as u64)
            else {
                warnings.push(format!(
                    "textures: {total} texels do not fit in the budget of {budget} even at 1x1 each"
                ));
                break;
            };
            total -= largest.width as u64 * largest.height as u64;
            *largest = without_top_level(*largest);
        }
        for (((offset, indices), old), new) in blocks.iter().zip(&before).zip(&after) {
            if old != new {
                self.retarget(*offset, indices, *new);
                warnings.push(format!(
                    "{}: texture of {}x{} texels reduced to {}x{} to fit all textures in {budget} texels",
                    self.names[indices[0]], old.width, old.height, new.width, new.height
                ));
            }
        }
        self.compact();
    }

    /// Removes the texels no texture uses any more (dropped levels), keeping the order.
    fn compact(&mut self) {
        let blocks = self.blocks();
        let used: u64 = blocks
            .iter()
            .map(|(_, indices)| chain_len(&self.infos[indices[0]]))
            .sum();
        if used == self.texels.len() as u64 {
            return;
        }
        let mut texels = Vec::with_capacity(used as usize);
        for (offset, indices) in blocks {
            let start = offset as usize;
            let len = chain_len(&self.infos[indices[0]]) as usize;
            let moved = texels.len() as u32;
            texels.extend_from_slice(&self.texels[start..start + len]);
            for i in indices {
                self.infos[i].offset = moved;
            }
        }
        self.texels = texels;
    }
}

/// Texels of a texture's stored levels.
fn chain_len(info: &TextureInfo) -> u64 {
    chain_texels(info.width, info.height, info.levels) as u64
}

/// `limits` within what the texel buffer's `u32` offsets address.
fn clamp_limits(limits: TextureLimits) -> TextureLimits {
    TextureLimits {
        max_side: limits.max_side.max(1),
        max_texels: limits.max_texels.min(1 << 31),
    }
}

/// `info` without its top level: the next level becomes level 0.
fn without_top_level(info: TextureInfo) -> TextureInfo {
    let (width, height) = level_size(info.width, info.height, 1);
    TextureInfo {
        offset: info.offset + info.width * info.height,
        width,
        height,
        levels: info.levels - 1,
        ..info
    }
}

/// Decodes an image, without the `image` crate's default 512 MiB cap (large textures are
/// downsampled after decoding).
fn decode<R: std::io::BufRead + std::io::Seek>(
    mut reader: image::ImageReader<R>,
) -> Result<image::DynamicImage, String> {
    if reader.format().is_none() {
        return Err("not an image format the renderer reads (PNG, JPEG, WebP, EXR)".to_string());
    }
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(8 << 30);
    reader.limits(limits);
    reader.decode().map_err(|e| format!("cannot decode the texture: {e}"))
}

/// The image's texels as RGBA8 words (red in the low byte): 8- and 16-bit images as they are
/// (16 bits rounded to 8), float images (linear) sRGB-encoded where `srgb`.
fn to_words(img: &image::DynamicImage, srgb: bool) -> Vec<u32> {
    let float = matches!(
        img,
        image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
    );
    if float && srgb {
        let linear: Vec<[f32; 4]> = img.to_rgba32f().pixels().map(|p| p.0).collect();
        return encode(&linear, true);
    }
    img.to_rgba8().pixels().map(|p| u32::from_le_bytes(p.0)).collect()
}

/// RGBA8 words read as linear RGBA in `[0, 1]` (sRGB decoded where `srgb`).
fn words_source(words: &[u32], srgb: bool) -> impl Fn(usize) -> [f32; 4] + Sync + '_ {
    let table: [f32; 256] = std::array::from_fn(|b| {
        let c = b as f32 / 255.0;
        if srgb {
            srgb_to_linear(c)
        } else {
            c
        }
    });
    move |i| {
        let [r, g, b, a] = words[i].to_le_bytes();
        [
            table[r as usize],
            table[g as usize],
            table[b as usize],
            a as f32 / 255.0,
        ]
    }
}

/// Linear RGBA texels as RGBA8 words, RGB sRGB-encoded where `srgb`; rounded to nearest.
fn encode(linear: &[[f32; 4]], srgb: bool) -> Vec<u32> {
    let byte = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    linear
        .par_iter()
        .map(|&[r, g, b, a]| {
            let c = |x: f32| {
                if srgb {
                    byte(linear_to_srgb(x.clamp(0.0, 1.0)))
                } else {
                    byte(x)
                }
            };
            u32::from_le_bytes([c(r), c(g), c(b), byte(a)])
        })
        .collect()
}

/// For each of `dst` texels along an axis of `src` texels (`dst <= src`), the first source
/// texel it covers and the weights of those it covers: the lengths of their overlaps with
/// `[x * src / dst, (x + 1) * src / dst)`, divided by that interval's length.
fn box_taps(src: u32, dst: u32) -> Vec<(usize, Vec<f32>)> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|x| {
            let (lo, hi) = (x as f64 * scale, (x + 1) as f64 * scale);
            let first = lo.floor() as usize;
            let last = ((hi.ceil() as usize).min(src as usize)).max(first + 1);
            let weights = (first..last)
                .map(|i| ((hi.min(i as f64 + 1.0) - lo.max(i as f64)) / scale) as f32)
                .collect();
            (first, weights)
        })
        .collect()
}

/// A `sw` x `sh` image (texel `i` given by `src`, linear RGBA) box-filtered down to `dw` x
/// `dh`. With `alpha_weighted` the RGB of each texel is the alpha-weighted average of those
/// it covers (the plain average where they are all transparent); alpha is averaged.
fn resample<F>(src: &F, sw: u32, sh: u32, dw: u32, dh: u32, alpha_weighted: bool) -> Vec<[f32; 4]>
where
    F: Fn(usize) -> [f32; 4] + Sync + ?Sized,
{
    let (xt, yt) = (box_taps(sw, dw), box_taps(sh, dh));
    let mut out = vec![[0.0f32; 4]; dw as usize * dh as usize];
    out.par_chunks_mut(dw as usize).zip(&yt).for_each(|(row, (y0, wy))| {
        for (texel, (x0, wx)) in row.iter_mut().zip(&xt) {
            // Sums of w * rgb * a, w * a and w * rgb.
            let mut weighted = [0.0f32; 3];
            let mut alpha = 0.0f32;
            let mut plain = [0.0f32; 3];
            for (j, &vy) in wy.iter().enumerate() {
                let base = (y0 + j) * sw as usize;
                for (i, &vx) in wx.iter().enumerate() {
                    let [r, g, b, a] = src(base + x0 + i);
                    let w = vx * vy;
                    for (k, c) in [r, g, b].into_iter().enumerate() {
                        weighted[k] += w * c * a;
                        plain[k] += w * c;
                    }
                    alpha += w * a;
                }
            }
            let rgb = if alpha_weighted && alpha > 1e-6 {
                weighted.map(|s| s / alpha)
            } else {
                plain
            };
            *texel = [rgb[0], rgb[1], rgb[2], alpha];
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{DynamicImage, ImageBuffer, LumaA, Rgb, Rgba};
    use shared::glam::Vec2;
    use shared::texture::{sample, texel, TEX_SRGB};

    /// A fresh folder for one test's files.
    fn scratch(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("raytrace-texture-{}-{test}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The levels of texture `index` as words, level by level.
    fn levels(set: &TextureSet, index: u32) -> Vec<Vec<u32>> {
        let info = set.infos[index as usize];
        (0..info.levels)
            .map(|l| {
                let (base, w, h) = shared::texture::level_base(&info, l);
                set.texels[base as usize..(base + w * h) as usize].to_vec()
            })
            .collect()
    }

    fn grey(v: u8) -> u32 {
        u32::from_le_bytes([v, v, v, 255])
    }

    /// A 4x4 checker of 1x1 squares of `a` and `b`.
    fn checker(a: u8, b: u8) -> DynamicImage {
        DynamicImage::ImageRgba8(ImageBuffer::from_fn(4, 4, |x, y| {
            let v = if (x + y) % 2 == 0 { a } else { b };
            Rgba([v, v, v, 255])
        }))
    }

    #[test]
    fn mip_chain_of_a_checker_is_its_average() {
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        let i = set.add_image(&checker(0, 200), false, Sampler::default(), "checker", &mut warnings);
        assert!(warnings.is_empty(), "{warnings:?}");
        let info = set.infos[i as usize];
        assert_eq!((info.width, info.height, info.levels, info.offset), (4, 4, 3, 0));
        assert_eq!(info.flags, 0);
        let l = levels(&set, i);
        assert_eq!(l[1], vec![grey(100); 4]);
        assert_eq!(l[2], vec![grey(100)]);
        assert_eq!(set.texels.len(), 16 + 4 + 1);
        // Sampled through the shared code: level 0 at a texel centre, the top at lod 2.
        let uv = Vec2::new(1.5 / 4.0, 0.5 / 4.0);
        assert!((sample(&info, &set.texels, uv, 0.0).x - 200.0 / 255.0).abs() < 1e-6);
        assert!((sample(&info, &set.texels, uv, 2.0).x - 100.0 / 255.0).abs() < 1e-6);
    }

    #[test]
    fn srgb_mips_are_filtered_in_linear_space() {
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        let i = set.add_image(&checker(0, 255), true, Sampler::default(), "checker", &mut warnings);
        let expected = (linear_to_srgb(0.5) * 255.0).round() as u8;
        assert_eq!(expected, 188);
        let l = levels(&set, i);
        assert_eq!(l[1], vec![grey(188); 4]);
        assert_eq!(l[2], vec![grey(188)], "not the 128 of averaging encoded values");
        let info = set.infos[i as usize];
        assert_eq!(info.flags & TEX_SRGB, TEX_SRGB);
        let top = texel(&info, &set.texels, 2, 0, 0);
        assert!((top.x - 0.5).abs() < 0.003, "{top}");
        // The same texels as data average the encoded values.
        let j = set.add_image(&checker(0, 255), false, Sampler::default(), "checker", &mut warnings);
        assert_eq!(levels(&set, j)[2], vec![grey(128)]);
    }

    #[test]
    fn transparent_texels_do_not_bleed_into_colour_mips() {
        // Red opaque texels beside transparent black ones.
        let img = DynamicImage::ImageRgba8(ImageBuffer::from_fn(2, 2, |x, _| {
            if x == 0 {
                Rgba([255, 0, 0, 255])
            } else {
                Rgba([0, 0, 0, 0])
            }
        }));
        let mut set = TextureSet::new();
        let i = set.add_image(&img, true, Sampler::default(), "leaf", &mut Vec::new());
        assert_eq!(levels(&set, i)[1], vec![u32::from_le_bytes([255, 0, 0, 128])]);
    }

    #[test]
    fn odd_sizes_keep_the_average() {
        // A 5x3 ramp: level 1 is 2x1 (weights 0.4 0.4 0.2 | 0.2 0.4 0.4 across, 1/3 down).
        let img = DynamicImage::ImageRgba8(ImageBuffer::from_fn(5, 3, |x, _| {
            let v = [0, 50, 100, 150, 250][x as usize];
            Rgba([v, v, v, 255])
        }));
        let mut set = TextureSet::new();
        let i = set.add_image(&img, false, Sampler::default(), "ramp", &mut Vec::new());
        let l = levels(&set, i);
        assert_eq!(l.iter().map(Vec::len).collect::<Vec<_>>(), [15, 2, 1]);
        // 0.4 * 0 + 0.4 * 50 + 0.2 * 100 = 40; 0.2 * 100 + 0.4 * 150 + 0.4 * 250 = 180.
        assert_eq!(l[1], vec![grey(40), grey(180)]);
        assert_eq!(l[2], vec![grey(110)]);
        assert_eq!(box_taps(5, 2)[0], (0, vec![0.4, 0.4, 0.2]));
        assert_eq!(box_taps(4, 2)[1], (2, vec![0.5, 0.5]));
    }

    #[test]
    fn pngs_of_every_pixel_format_load() {
        let dir = scratch("formats");
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        // 16-bit RGB: 0x8080 -> 128, 0xffff -> 255.
        let deep: ImageBuffer<Rgb<u16>, Vec<u16>> = ImageBuffer::from_fn(2, 2, |x, _| {
            if x == 0 {
                Rgb([0x8080, 0, 0xffff])
            } else {
                Rgb([0, 0xffff, 0])
            }
        });
        let path = dir.join("deep.png");
        deep.save(&path).unwrap();
        let i = set.add_file(&path, false, Sampler::default(), &mut warnings).unwrap();
        assert_eq!(set.infos[i as usize].width, 2);
        assert_eq!(levels(&set, i)[0][0], u32::from_le_bytes([128, 0, 255, 255]));
        assert_eq!(levels(&set, i)[0][1], u32::from_le_bytes([0, 255, 0, 255]));
        // Grey with alpha.
        let la: ImageBuffer<LumaA<u8>, Vec<u8>> = ImageBuffer::from_fn(3, 1, |x, _| LumaA([60 * x as u8, 100]));
        let path = dir.join("grey_alpha.png");
        la.save(&path).unwrap();
        let j = set.add_file(&path, true, Sampler::default(), &mut warnings).unwrap();
        assert_eq!(
            levels(&set, j)[0],
            [0, 60, 120].map(|v| u32::from_le_bytes([v, v, v, 100]))
        );
        // A linear float image (EXR) as a colour texture is sRGB-encoded.
        let hdr: ImageBuffer<Rgba<f32>, Vec<f32>> = ImageBuffer::from_pixel(1, 1, Rgba([0.5, 0.0, 1.0, 1.0]));
        let k = set.add_image(
            &DynamicImage::ImageRgba32F(hdr),
            true,
            Sampler::default(),
            "hdr",
            &mut warnings,
        );
        assert_eq!(levels(&set, k)[0][0], u32::from_le_bytes([188, 0, 255, 255]));
        assert!(warnings.is_empty(), "{warnings:?}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_non_power_of_two_png() {
        let dir = scratch("npot");
        let img: ImageBuffer<Rgb<u8>, Vec<u8>> = ImageBuffer::from_fn(300, 200, |x, y| {
            Rgb([(x % 256) as u8, (y % 256) as u8, ((x + y) % 7) as u8])
        });
        let path = dir.join("npot.png");
        img.save(&path).unwrap();
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        let i = set.add_file(&path, true, Sampler::default(), &mut warnings).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        let info = set.infos[i as usize];
        assert_eq!((info.width, info.height, info.levels), (300, 200, 9));
        let sizes: Vec<(u32, u32)> = (0..9).map(|l| level_size(300, 200, l)).collect();
        assert_eq!(
            sizes,
            [
                (300, 200),
                (150, 100),
                (75, 50),
                (37, 25),
                (18, 12),
                (9, 6),
                (4, 3),
                (2, 1),
                (1, 1)
            ]
        );
        assert_eq!(set.texels.len() as u32, chain_texels(300, 200, 9));
        // Level 0 is the file's texels; a texel centre samples it exactly.
        let l0 = &levels(&set, i)[0];
        assert_eq!(l0[3 * 300 + 7], u32::from_le_bytes([7, 3, 3, 255]));
        let t = sample(&info, &set.texels, Vec2::new(7.5 / 300.0, 3.5 / 200.0), 0.0);
        assert!((t.x - srgb_to_linear(7.0 / 255.0)).abs() < 1e-6, "{t}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn bad_files_warn_once_and_give_none() {
        let dir = scratch("bad");
        let corrupt = dir.join("corrupt.png");
        let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
        bytes.extend([0xde, 0xad, 0xbe, 0xef].repeat(16));
        std::fs::write(&corrupt, &bytes).unwrap();
        let missing = dir.join("missing.png");
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        for _ in 0..2 {
            assert_eq!(set.add_file(&corrupt, true, Sampler::default(), &mut warnings), None);
            assert_eq!(set.add_file(&missing, true, Sampler::default(), &mut warnings), None);
        }
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(
            warnings[0].contains("corrupt.png") && warnings[0].contains("decode"),
            "{}",
            warnings[0]
        );
        assert!(
            warnings[1].contains("missing.png") && warnings[1].contains("read"),
            "{}",
            warnings[1]
        );
        // Bytes that are no image.
        assert_eq!(
            set.add_bytes(b"hello", None, "image 3", false, Sampler::default(), &mut warnings),
            None
        );
        assert_eq!(warnings.len(), 3);
        assert!(warnings[2].starts_with("image 3: "), "{}", warnings[2]);
        assert!(set.is_empty() && set.texels.is_empty());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn oversized_textures_are_downsampled() {
        let wide = DynamicImage::ImageRgba8(ImageBuffer::from_pixel(9000, 10, Rgba([10, 20, 30, 255])));
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        let i = set.add_image(&wide, false, Sampler::default(), "wide.png", &mut warnings);
        let info = set.infos[i as usize];
        assert_eq!((info.width, info.height, info.levels), (8192, 9, 14));
        assert_eq!(warnings.len(), 1);
        let w = &warnings[0];
        assert!(
            w.starts_with("wide.png: ") && w.contains("9000x10") && w.contains("8192x9"),
            "{w}"
        );
        assert!(levels(&set, i)
            .iter()
            .flatten()
            .all(|&t| t == u32::from_le_bytes([10, 20, 30, 255])));
    }

    #[test]
    fn the_texel_budget_drops_top_levels_of_the_largest() {
        let limits = TextureLimits {
            max_side: 64,
            max_texels: 1000,
        };
        let mut set = TextureSet::with_limits(limits);
        let mut warnings = Vec::new();
        let small = set.add_image(&checker(0, 200), false, Sampler::default(), "small", &mut warnings);
        let big_img = DynamicImage::ImageRgba8(ImageBuffer::from_pixel(32, 32, Rgba([1, 2, 3, 4])));
        let big = set.add_image(&big_img, false, Sampler::default(), "big", &mut warnings);
        // 21 + 1365 texels > 1000: the 32x32 loses its top level (21 + 341).
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].starts_with("big: ") && warnings[0].contains("32x32") && warnings[0].contains("16x16"));
        let b = set.infos[big as usize];
        assert_eq!((b.width, b.height, b.levels, b.offset), (16, 16, 5, 21));
        assert_eq!(set.texels.len(), 21 + 341);
        assert_eq!(levels(&set, small)[2], vec![grey(100)]);
        assert!(levels(&set, big)
            .iter()
            .flatten()
            .all(|&t| t == u32::from_le_bytes([1, 2, 3, 4])));
        // Tighter limits later: a side of 4 at most.
        set.limit(
            TextureLimits {
                max_side: 4,
                max_texels: 1000,
            },
            &mut warnings,
        );
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings[1].contains("16x16") && warnings[1].contains("4x4"));
        assert_eq!(set.infos[big as usize].width, 4);
        assert_eq!(set.texels.len(), 21 + 21);
        assert!(levels(&set, big)
            .iter()
            .flatten()
            .all(|&t| t == u32::from_le_bytes([1, 2, 3, 4])));
        assert_eq!(levels(&set, small)[0][..2], [grey(0), grey(200)]);
    }

    #[test]
    fn the_same_image_is_stored_once() {
        let dir = scratch("dedup");
        let path = dir.join("a.png");
        checker(0, 200).save(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let mut set = TextureSet::new();
        let mut warnings = Vec::new();
        let a = set.add_file(&path, true, Sampler::default(), &mut warnings).unwrap();
        let same = set.add_file(&dir.join(".").join("a.png"), true, Sampler::default(), &mut warnings);
        assert_eq!(same, Some(a));
        let stored = set.texels.len();
        // As data it is another texture with its own levels.
        let data = set.add_file(&path, false, Sampler::default(), &mut warnings).unwrap();
        assert_ne!(data, a);
        assert_eq!(set.texels.len(), 2 * stored);
        // Another sampler shares the texels.
        let clamp = Sampler {
            wrap_u: WRAP_CLAMP,
            wrap_v: WRAP_MIRROR,
            nearest: true,
        };
        let c = set.add_file(&path, true, clamp, &mut warnings).unwrap();
        assert_ne!(c, a);
        assert_eq!(set.infos[c as usize].offset, set.infos[a as usize].offset);
        assert_eq!(
            set.infos[c as usize].flags,
            tex_flags(true, true, WRAP_CLAMP, WRAP_MIRROR)
        );
        assert_eq!(set.texels.len(), 2 * stored);
        // Embedded bytes: once, whatever the name.
        let e = set.add_bytes(
            &bytes,
            Some("image/png"),
            "image 0",
            true,
            Sampler::default(),
            &mut warnings,
        );
        let f = set.add_bytes(&bytes, None, "image 1", true, Sampler::default(), &mut warnings);
        assert!(e.is_some() && e == f);
        assert_eq!(set.texels.len(), 3 * stored);
        assert_eq!(set.len(), 4);
        assert_eq!(set.name(e.unwrap()), "image 0");
        assert!(warnings.is_empty(), "{warnings:?}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
