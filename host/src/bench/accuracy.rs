//! `raytrace bench accuracy [SCENE]`: what accuracy costs in time, on the GPU.
//!
//! 1. Convergence: relative MSE against a converged reference (rendered once, cached as EXR)
//!    and GPU trace time, for 1..max samples per pixel, with plain path tracing, next-event
//!    estimation, NEE with MIS, NEE with MIS without Russian roulette, and the denoiser's
//!    section: NEE with MIS denoised once at each point (`render --denoise`, its time added;
//!    moving frames are `bench denoise`'s); efficiency `1 / (relMSE x seconds)`.
//! 2. Maximum depth 1..16 at a fixed sample count: error (bias included) against time.
//! 3. BVH quality: 30- and 63-bit Morton codes (build time, SAH cost, rays per second) and
//!    brute force.
//! 4. Intersection precision: the watertight triangle test against Moller-Trumbore and the
//!    robust slab test against the plain one (rays per second on the scene, and rays that
//!    leak through closed meshes aimed at their shared vertices and edges).
use crate::bench::percentile;
use crate::bench::plot::{line_chart, Chart, Scale, Series};
use crate::bvh::{BuildOptions, MortonBits};
use crate::cli::{open_devices_on, parse_devices, OpenDevices, Prepared, SceneArgs, Work};
use crate::gpu::driver::DriverBuild;
use crate::gpu::{denoise_ms, stage_ms, Denoise, Gpu, GpuOptions, GpuRenderer, Kernels};
use crate::inputs::hard_cases::{closed_meshes, rays_at_vertices_and_edges, scene_of, OFFSETS};
use crate::picture::Picture;
use crate::render::Accel;
use crate::scene::SceneGpu;
use anyhow::{bail, Context, Result};
use glam::Vec3;
use shared::types::{
    Frame, Node, Object, Ray, FLAG_BVH, FLAG_MIS, FLAG_NEE, FLAG_RUSSIAN_ROULETTE, INVALID, VARIANT_MOLLER_TRUMBORE,
    VARIANT_PLAIN_SLAB,
};
use shared::wide::WideNode;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Settings of `raytrace bench accuracy`.
#[derive(Clone, Debug, clap::Args, serde::Serialize)]
pub struct Options {
    /// Built-in scene name or scene file.
    #[arg(default_value = "cornell")]
    pub scene: String,
    #[arg(long, default_value = "256x256", value_parser = crate::cli::parse_size)]
    pub size: (u32, u32),
    /// Largest samples per pixel of the convergence curves (powers of two up to it).
    #[arg(long, default_value_t = 1024)]
    pub max_spp: u32,
    /// Samples per pixel of the reference image.
    #[arg(long, default_value_t = 65536)]
    pub reference_spp: u32,
    /// Samples per pixel of the depth sweep.
    #[arg(long, default_value_t = 64)]
    pub depth_spp: u32,
    /// Samples per pixel of the rays-per-second frames.
    #[arg(long, default_value_t = 16)]
    pub speed_spp: u32,
    /// Image size of the rays-per-second frames (large enough to fill the GPU).
    #[arg(long, default_value = "1920x1080", value_parser = crate::cli::parse_size)]
    pub speed_size: (u32, u32),
    /// Timed repetitions of every build and rays-per-second frame (median).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Folder of cached reference images.
    #[arg(long, default_value = "bench/cache")]
    pub cache: PathBuf,
    /// Render the reference on these devices, each a share of its samples as `render
    /// --devices` splits them: `all`, or indices or names separated by commas (`0,1`). The
    /// measured renders stay on the one device the benchmark runs on.
    #[arg(long)]
    pub devices: Option<String>,
    /// `driver`: adds the driver's acceleration structures (built `--driver-build`) to the BVH
    /// quality section (devices with VK_KHR_ray_tracing_pipeline).
    #[arg(long, value_enum, default_value_t = Accel::Lbvh)]
    pub accel: Accel,
    /// How the driver builds its bottom levels (with `--accel driver`).
    #[arg(long, value_enum, default_value_t = DriverBuild::FastBuild)]
    pub driver_build: DriverBuild,
}

/// Relative MSE's guard against dark pixels: `(x - ref)^2 / (ref^2 + EPS)` (pbrt's choice).
pub const REL_MSE_EPS: f64 = 1e-2;

/// One point of a convergence or depth curve.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Point {
    pub spp: u32,
    pub depth: u32,
    /// GPU time of the path tracing, ms (every sample up to `spp`).
    pub ms: f64,
    pub rel_mse: f64,
    /// `1 / (rel_mse * seconds)`.
    pub efficiency: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Curve {
    pub name: String,
    pub points: Vec<Point>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct BvhRow {
    pub name: String,
    /// Median GPU time of transform + build, ms (0 for brute force).
    pub build_ms: f64,
    /// Surface-area-heuristic cost (traversal and intersection cost 1, root area 1).
    pub sah: f64,
    pub depth: u32,
    pub rays_per_s: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct PrecisionRow {
    pub name: String,
    pub rays_per_s: f64,
    /// Rays aimed at shared vertices and edges of closed meshes.
    pub rays: usize,
    /// Of those, rays that found nothing through the BVH, and by brute force.
    pub leaks_bvh: usize,
    pub leaks_brute: usize,
    /// Leaks through the BVH per mesh offset ([`OFFSETS`]).
    pub leaks_by_offset: Vec<usize>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub options: Options,
    pub max_depth: u32,
    pub reference: String,
    /// How the reference was made: read from the cache, or rendered where and in how long.
    pub reference_made: String,
    pub convergence: Vec<Curve>,
    pub depth: Curve,
    pub bvh: Vec<BvhRow>,
    pub precision: Vec<PrecisionRow>,
}

/// Mean over pixels and channels of `(x - ref)^2 / (ref^2 + REL_MSE_EPS)`.
pub fn rel_mse(image: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let sum: f64 = image
        .iter()
        .zip(reference)
        .flat_map(|(a, r)| (0..3).map(move |k| (a[k] as f64, r[k] as f64)))
        .map(|(a, r)| (a - r) * (a - r) / (r * r + REL_MSE_EPS))
        .sum();
    sum / (3 * image.len().max(1)) as f64
}

/// SAH cost of a BVH (nodes `0..n-1` internal, `n-1..2n-1` leaves of one primitive each),
/// relative to the root's area, with traversal and intersection costing 1 each.
pub fn sah_cost(nodes: &[Node]) -> f64 {
    let area = |n: &Node| {
        let d = Vec3::from(n.max) - Vec3::from(n.min);
        2.0 * (d.x as f64 * d.y as f64 + d.y as f64 * d.z as f64 + d.z as f64 * d.x as f64)
    };
    let Some(root) = nodes.first() else {
        return 0.0;
    };
    let root_area = area(root).max(f64::MIN_POSITIVE);
    nodes.iter().map(area).sum::<f64>() / root_area
}

/// [`sah_cost`] of a wide BVH (`shared::wide`): each node's area (its slots' union) once,
/// each leaf's area once per primitive, relative to the root's area.
pub fn sah_cost_wide(wide: &[WideNode]) -> f64 {
    let area = |lo: [f32; 3], hi: [f32; 3]| {
        let d = Vec3::from(hi) - Vec3::from(lo);
        2.0 * (d.x as f64 * d.y as f64 + d.y as f64 * d.z as f64 + d.z as f64 * d.x as f64)
    };
    let Some(root) = wide.first() else {
        return 0.0;
    };
    let union = |w: &WideNode| {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for k in (0..shared::wide::WIDTH).filter(|&k| w.child[k] != INVALID) {
            let (l, h) = w.child_box(k);
            for a in 0..3 {
                lo[a] = lo[a].min(l[a]);
                hi[a] = hi[a].max(h[a]);
            }
        }
        (lo, hi)
    };
    let (lo, hi) = union(root);
    let root_area = area(lo, hi).max(f64::MIN_POSITIVE);
    let mut cost = root_area;
    for w in wide {
        for k in (0..shared::wide::WIDTH).filter(|&k| w.child[k] != INVALID) {
            let (l, h) = w.child_box(k);
            let c = w.child[k];
            cost += if c & shared::wide::LEAF != 0 {
                area(l, h) * shared::wide::leaf_range(c).1 as f64
            } else {
                area(l, h)
            };
        }
    }
    cost / root_area
}

fn prepare(scene: &str, size: (u32, u32)) -> Result<Prepared> {
    let size = format!("{}x{}", size.0, size.1);
    <SceneArgs as clap::Parser>::try_parse_from(["raytrace", scene, "--size", &size])?.prepare()
}

fn with_flags(f: &Frame, on: u32, off: u32) -> Frame {
    Frame {
        flags: (f.flags | on) & !off,
        ..*f
    }
}

/// Transform and build milliseconds of one submission.
fn build_ms(t: &[(&'static str, f64)]) -> f64 {
    t.iter()
        .filter(|(l, _)| !matches!(*l, "trace" | "display" | "begin"))
        .map(|(_, s)| s * 1e3)
        .sum()
}

/// The reference image: `spp` samples with NEE and MIS (unbiased, as every configuration
/// measured) and an independent seed, from `cache` when rendered before with the same frame.
fn reference(refs: &mut References, p: &Prepared, spp: u32, cache: &Path) -> Result<Reference> {
    cached_reference(refs, &p.data, &p.data.objects, &p.frame, &p.scene.name, spp, cache)
}

/// What renders converged references: a renderer of the benchmark's device, or the devices
/// of `--devices`, each a share of the samples (`render --devices`'s split and sum).
pub enum References {
    One(Box<GpuRenderer>),
    Devices(OpenDevices),
}

impl References {
    /// A renderer on `gpu`, or where `devices` names some (as `--devices` takes them), those
    /// devices opened beside it.
    pub fn new(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, devices: Option<&str>) -> Result<References> {
        Ok(match devices {
            None => References::One(Box::new(GpuRenderer::new(gpu, kernels)?)),
            Some(list) => {
                let list = parse_devices(list)?;
                let open = open_devices_on(gpu.shared_instance(), &list, &GpuOptions::default())
                    .context("opening the reference's devices (--devices)")?;
                References::Devices(open)
            }
        })
    }
}

/// A reference image, its file, and how it was made.
pub struct Reference {
    pub pixels: Vec<[f32; 3]>,
    pub path: PathBuf,
    /// "cached", or where it was rendered and in how long.
    pub made: String,
}

/// The reference image of `frame` over `data` with its objects placed by `objects`: `spp`
/// samples with NEE and MIS and an independent seed, rendered by `refs` or read from `cache`,
/// where it is kept as EXR named by the scene `name`, the size, `spp` and a hash of the frame
/// and scene data (the same file whether one device rendered it or several: their images
/// differ only by float rounding).
pub fn cached_reference(
    refs: &mut References,
    data: &SceneGpu,
    objects: &[Object],
    frame: &Frame,
    name: &str,
    spp: u32,
    cache: &Path,
) -> Result<Reference> {
    let mut f = with_flags(frame, FLAG_NEE | FLAG_MIS | FLAG_RUSSIAN_ROULETTE | FLAG_BVH, 0);
    f.seed ^= 0x9e37_79b9;
    let key = fnv1a(bytemuck::bytes_of(&f))
        ^ fnv1a(bytemuck::cast_slice(&data.model_tris))
        ^ fnv1a(bytemuck::cast_slice(&data.materials))
        ^ fnv1a(bytemuck::cast_slice(objects));
    let path = cache.join(format!(
        "reference-{}-{}x{}-{spp}spp-{key:016x}.exr",
        crate::bench::slug(name),
        f.width,
        f.height
    ));
    if path.exists() {
        let img = image::open(&path)
            .with_context(|| format!("reading the cached reference {}", path.display()))?
            .to_rgb32f();
        if img.dimensions() == (f.width, f.height) {
            eprintln!("reference: {}", path.display());
            return Ok(Reference {
                pixels: img.pixels().map(|p| p.0).collect(),
                path,
                made: "cached".into(),
            });
        }
    }
    eprintln!("rendering the reference ({spp} spp) to {}", path.display());
    let load = |r: &mut GpuRenderer, first: u32| {
        r.set_first_sample(first);
        r.load(data, &f)?;
        if objects != data.objects.as_slice() {
            r.set_objects(objects)?;
        }
        Ok(())
    };
    let t = Instant::now();
    let (pic, made) = match refs {
        References::One(r) => {
            load(r, 0)?;
            let mut done = 0;
            while done < spp {
                let n = (spp - done).min(256);
                r.render(n, false)?;
                done += n;
            }
            (r.picture()?, r.gpu().describe())
        }
        References::Devices(devices) => {
            let (rendered, _) = devices.render_work(&Work { frame: &f, load: &load }, 0, spp)?;
            (rendered.picture, rendered.device)
        }
    };
    let made = format!("rendered in {:.2} s on {made}", t.elapsed().as_secs_f64());
    eprintln!("reference {made}");
    std::fs::create_dir_all(cache).with_context(|| format!("creating {}", cache.display()))?;
    pic.save(&path)?;
    Ok(Reference {
        pixels: pic.linear(),
        path,
        made,
    })
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

fn point(pic: &Picture, reference: &[[f32; 3]], spp: u32, depth: u32, ms: f64) -> Point {
    let e = rel_mse(&pic.linear(), reference);
    Point {
        spp,
        depth,
        ms,
        rel_mse: e,
        efficiency: 1.0 / (e * ms * 1e-3),
    }
}

/// Accumulates samples up to `max_spp` in doubling steps, measuring after each.
fn convergence(
    r: &mut GpuRenderer,
    p: &Prepared,
    f: &Frame,
    max_spp: u32,
    reference: &[[f32; 3]],
) -> Result<Vec<Point>> {
    r.load(&p.data, f)?;
    let (mut spp, mut ms, mut out) = (0, 0.0, Vec::new());
    let mut next = 1;
    while next <= max_spp {
        let t = r.render(next - spp, false)?;
        ms += stage_ms(&t, "trace");
        spp = next;
        // A denoised point's time adds one run of the denoiser over all its samples (what
        // `render --denoise` does once at the end), not every run before it.
        out.push(point(&r.picture()?, reference, spp, f.max_depth, ms + denoise_ms(&t)));
        next *= 2;
    }
    Ok(out)
}

/// Median trace ms of `runs` frames of `spp` samples (BVH rebuilt before each) and the rays
/// traced per second.
fn rays_per_s(r: &mut GpuRenderer, f: &Frame, spp: u32, runs: usize) -> Result<f64> {
    let mut ms = Vec::new();
    for _ in 0..runs.max(1) + 1 {
        r.set_frame(f)?;
        ms.push(stage_ms(&r.render(spp, false)?, "trace"));
    }
    ms.remove(0);
    ms.sort_by(f64::total_cmp);
    Ok(r.rays_per_sample()? * spp as f64 / (percentile(&ms, 0.5) * 1e-3))
}

/// Median transform and build milliseconds of `runs` frames of `p` (after one discarded).
fn median_build_ms(r: &mut GpuRenderer, p: &Prepared, runs: usize) -> Result<f64> {
    r.load(&p.data, &p.frame)?;
    let mut ms = Vec::new();
    for _ in 0..runs.max(1) + 1 {
        r.set_frame(&p.frame)?;
        ms.push(build_ms(&r.render(0, true)?));
    }
    ms.remove(0);
    ms.sort_by(f64::total_cmp);
    Ok(percentile(&ms, 0.5))
}

fn bvh_rows(r: &mut GpuRenderer, p: &Prepared, o: &Options) -> Result<Vec<BvhRow>> {
    let mut rows = Vec::new();
    for (name, build) in [
        ("LBVH, 30-bit Morton codes", BuildOptions::lbvh(MortonBits::B30)),
        ("LBVH, 63-bit Morton codes", BuildOptions::lbvh(MortonBits::B63)),
        (
            "LBVH + treelets, 30-bit",
            BuildOptions {
                treelets: true,
                ..BuildOptions::lbvh(MortonBits::B30)
            },
        ),
        ("Wide (4-ary collapse), 30-bit", BuildOptions::wide(MortonBits::B30)),
    ] {
        r.set_build(build);
        let ms = median_build_ms(r, p, o.runs)?;
        let bvh = r.bvh()?;
        let (tris, spheres) = r.world()?;
        let stats = crate::bvh::validate(&bvh.nodes, &bvh.parents, &tris, &spheres)
            .map_err(|e| anyhow::anyhow!("{name}: the BVH is invalid: {e}"))?;
        let (sah, depth) = if build.wide {
            let w = crate::bvh::validate_wide(&bvh.wide, &bvh.sorted_prims, &tris, &spheres)
                .map_err(|e| anyhow::anyhow!("{name}: the wide BVH is invalid: {e}"))?;
            (sah_cost_wide(&bvh.wide), w.depth)
        } else {
            (sah_cost(&bvh.nodes), stats.depth)
        };
        rows.push(BvhRow {
            name: name.into(),
            build_ms: ms,
            sah,
            depth,
            rays_per_s: rays_per_s(r, &p.frame, o.speed_spp, o.runs)?,
        });
    }
    if o.accel == Accel::Driver {
        r.set_accel(Accel::Driver, o.driver_build)?;
        let ms = median_build_ms(r, p, o.runs)?;
        rows.push(BvhRow {
            name: format!("driver's acceleration structures ({:?})", o.driver_build),
            build_ms: ms,
            // Not known: the driver's structures are opaque.
            sah: f64::NAN,
            depth: 0,
            rays_per_s: rays_per_s(r, &p.frame, o.speed_spp, o.runs)?,
        });
        r.set_accel(Accel::Lbvh, o.driver_build)?;
    }
    r.set_build(BuildOptions::lbvh(MortonBits::B30));
    r.load(&p.data, &p.frame)?;
    let brute = with_flags(&p.frame, 0, FLAG_BVH);
    rows.push(BvhRow {
        name: "brute force (no BVH)".into(),
        build_ms: 0.0,
        sah: p.frame.n_prims as f64,
        depth: 0,
        rays_per_s: rays_per_s(r, &brute, 1, 1)?,
    });
    Ok(rows)
}

/// Rays aimed at every shared vertex and edge of the closed meshes, at every offset: the
/// leaks of each variant through the BVH and by brute force.
fn leaks(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, variants: u32) -> Result<(usize, usize, usize, Vec<usize>)> {
    let mut r = GpuRenderer::new(gpu, kernels)?;
    let (mut rays, mut bvh, mut brute, mut by_offset) = (0, 0, 0, vec![0; OFFSETS.len()]);
    for (_, mesh) in closed_meshes() {
        for (k, s) in OFFSETS.iter().enumerate() {
            let offset = Vec3::new(*s, -s, *s);
            let scene = scene_of(&mesh.triangles(offset), &[]);
            let data = scene.gpu_data(0.0);
            let mut f = scene.frame(&data);
            f.features = shared::types::FEATURES_ALL | variants;
            r.load(&data, &f)?;
            r.render(0, true)?;
            let cast: Vec<Ray> = rays_at_vertices_and_edges(&mesh, offset)
                .into_iter()
                .map(|(o, d)| Ray {
                    origin: [o.x, o.y, o.z, 0.0],
                    dir: [d.x, d.y, d.z, f32::INFINITY],
                })
                .collect();
            rays += cast.len();
            let missed = |hits: Vec<shared::types::Hit>| hits.iter().filter(|h| h.prim == INVALID).count();
            let through_bvh = missed(r.cast(&cast)?);
            bvh += through_bvh;
            by_offset[k] += through_bvh;
            r.set_frame(&with_flags(&f, 0, FLAG_BVH))?;
            brute += missed(r.cast(&cast)?);
        }
    }
    Ok((rays, bvh, brute, by_offset))
}

fn precision_rows(
    gpu: &Arc<Gpu>,
    kernels: &Arc<Kernels>,
    r: &mut GpuRenderer,
    p: &Prepared,
    o: &Options,
) -> Result<Vec<PrecisionRow>> {
    let variants = [
        ("watertight triangles, robust slabs (default)", 0),
        ("Moller-Trumbore triangles, robust slabs", VARIANT_MOLLER_TRUMBORE),
        ("watertight triangles, plain slabs", VARIANT_PLAIN_SLAB),
        (
            "Moller-Trumbore triangles, plain slabs",
            VARIANT_MOLLER_TRUMBORE | VARIANT_PLAIN_SLAB,
        ),
    ];
    // Speeds first, back to back (the GPU's clocks stay up), then the leaks.
    r.load(&p.data, &p.frame)?;
    let mut speeds = Vec::new();
    for (_, v) in variants {
        // Camera rays only: the same rays for every variant (a leak would change the paths).
        let f = Frame {
            features: p.frame.features | v,
            max_depth: 1,
            ..with_flags(&p.frame, 0, FLAG_NEE)
        };
        speeds.push(rays_per_s(r, &f, o.speed_spp, o.runs)?);
    }
    let mut rows = Vec::new();
    for ((name, v), speed) in variants.into_iter().zip(speeds) {
        let (rays, leaks_bvh, leaks_brute, leaks_by_offset) = leaks(gpu, kernels, v)?;
        rows.push(PrecisionRow {
            name: name.into(),
            rays_per_s: speed,
            rays,
            leaks_bvh,
            leaks_brute,
            leaks_by_offset,
        });
    }
    Ok(rows)
}

pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    if o.max_spp == 0 || o.reference_spp < 4 * o.max_spp {
        bail!(
            "--reference-spp ({}) must be at least 4 times --max-spp ({}): the reference's own noise would dominate",
            o.reference_spp,
            o.max_spp
        );
    }
    let p = prepare(&o.scene, o.size)?;
    let kernels = Arc::new(Kernels::new(gpu)?);
    if o.accel == Accel::Driver {
        // Refused here, before the reference, where the device cannot.
        GpuRenderer::new(gpu, &kernels)?.set_accel(Accel::Driver, o.driver_build)?;
    }
    let mut refs = References::new(gpu, &kernels, o.devices.as_deref())?;
    let made = reference(&mut refs, &p, o.reference_spp, &o.cache)?;
    drop(refs);
    let reference = made.pixels;
    let mut r = GpuRenderer::new(gpu, &kernels)?;
    let base = with_flags(&p.frame, FLAG_BVH | FLAG_RUSSIAN_ROULETTE, 0);
    let mut curves = Vec::new();
    for (name, on, off) in [
        ("path tracing (BSDF sampling only)", 0, FLAG_NEE | FLAG_MIS),
        ("next-event estimation", FLAG_NEE, FLAG_MIS),
        ("NEE + MIS", FLAG_NEE | FLAG_MIS, 0),
        (
            "NEE + MIS, no Russian roulette",
            FLAG_NEE | FLAG_MIS,
            FLAG_RUSSIAN_ROULETTE,
        ),
    ] {
        let f = with_flags(&base, on, off);
        let points = convergence(&mut r, &p, &f, o.max_spp, &reference).with_context(|| name.to_string())?;
        eprintln!("{name}: {:?}", points.last().map(|p| (p.ms, p.rel_mse)));
        curves.push(Curve {
            name: name.into(),
            points,
        });
    }
    // The denoiser's section: the same samples as NEE + MIS, denoised once at each point as
    // `render --denoise` does (moving frames, the real-time case: `bench denoise`).
    r.set_denoise(Denoise::Accumulated)?;
    let f = with_flags(&base, FLAG_NEE | FLAG_MIS, 0);
    let name = "NEE + MIS, denoised (render --denoise)";
    let points = convergence(&mut r, &p, &f, o.max_spp, &reference).with_context(|| name.to_string())?;
    r.set_denoise(Denoise::Off)?;
    eprintln!("{name}: {:?}", points.last().map(|p| (p.ms, p.rel_mse)));
    curves.push(Curve {
        name: name.into(),
        points,
    });
    let mut depth = Curve {
        name: format!("NEE + MIS, {} spp", o.depth_spp),
        points: Vec::new(),
    };
    for d in [1, 2, 3, 4, 6, 8, 12, 16]
        .into_iter()
        .filter(|&d| d <= p.frame.max_depth)
    {
        let f = Frame {
            max_depth: d,
            ..with_flags(&base, FLAG_NEE | FLAG_MIS, 0)
        };
        r.load(&p.data, &f)?;
        let ms = stage_ms(&r.render(o.depth_spp, false)?, "trace");
        depth.points.push(point(&r.picture()?, &reference, o.depth_spp, d, ms));
    }
    let fast = prepare(&o.scene, o.speed_size)?;
    let bvh = bvh_rows(&mut r, &fast, o)?;
    let precision = precision_rows(gpu, &kernels, &mut r, &fast, o)?;
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        options: o.clone(),
        max_depth: p.frame.max_depth,
        reference: made.path.display().to_string(),
        reference_made: made.made,
        convergence: curves,
        depth,
        bvh,
        precision,
    })
}

/// Writes the three plots next to the report (`STEM-convergence.png`, `-efficiency.png`,
/// `-depth.png`) and returns their file names.
pub fn plots(r: &Report, dir: &Path, stem: &str) -> Result<Vec<String>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let series = |f: fn(&Point) -> (f64, f64)| -> Vec<Series> {
        r.convergence
            .iter()
            .map(|c| Series {
                name: c.name.clone(),
                points: c.points.iter().map(f).collect(),
            })
            .collect()
    };
    let charts = [
        (
            "convergence",
            Chart {
                title: "Error against GPU time (1..max spp)",
                x_label: "trace time, ms",
                y_label: "relative MSE",
                x_scale: Scale::Log,
                y_scale: Scale::Log,
            },
            series(|p| (p.ms, p.rel_mse)),
        ),
        (
            "efficiency",
            Chart {
                title: "Efficiency 1 / (relMSE x time)",
                x_label: "samples per pixel",
                y_label: "efficiency, 1/s",
                x_scale: Scale::Log,
                y_scale: Scale::Log,
            },
            series(|p| (p.spp as f64, p.efficiency)),
        ),
        (
            "depth",
            Chart {
                title: "Maximum depth 1..16: error (bias included) against time",
                x_label: "trace time, ms",
                y_label: "relative MSE",
                x_scale: Scale::Linear,
                y_scale: Scale::Log,
            },
            vec![Series {
                name: r.depth.name.clone(),
                points: r.depth.points.iter().map(|p| (p.ms, p.rel_mse)).collect(),
            }],
        ),
    ];
    let mut names = Vec::new();
    for (what, chart, s) in charts {
        let name = format!("{stem}-{what}.png");
        line_chart(&dir.join(&name), &chart, &s, 900, 600)?;
        names.push(name);
    }
    Ok(names)
}

pub fn markdown(r: &Report, plots: &[String]) -> String {
    let o = &r.options;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# What accuracy costs in time: {}\n\n- date: {}\n- device: {}\n- command: `{}`\n\
         - {}x{}, maximum depth {}, BVH rebuilt on the GPU; times are GPU timestamps of the \
         path-tracing dispatches\n- reference: {} spp with NEE + MIS and an independent seed (`{}`, {})\n\
         - error: relative MSE, the mean over pixels and channels of (x - ref)^2 / (ref^2 + {REL_MSE_EPS})\n",
        o.scene,
        r.date,
        r.device,
        r.command,
        o.size.0,
        o.size.1,
        r.max_depth,
        o.reference_spp,
        r.reference,
        r.reference_made
    );
    let _ = writeln!(s, "## Convergence\n");
    for p in plots {
        let _ = writeln!(s, "![{p}]({p})");
    }
    let _ = writeln!(
        s,
        "\nEvery curve accumulates 1, 2, 4, ... {} samples per pixel; time is the sum of the \
         trace dispatches so far.\n",
        o.max_spp
    );
    let _ = writeln!(s, "| estimator | spp | trace ms | relative MSE | efficiency (1/s) |");
    let _ = writeln!(s, "|---|---|---|---|---|");
    for c in &r.convergence {
        for p in c
            .points
            .iter()
            .filter(|p| p.spp.is_power_of_two() && p.spp.trailing_zeros() % 2 == 0)
        {
            let _ = writeln!(
                s,
                "| {} | {} | {:.3} | {:.3e} | {:.3e} |",
                c.name, p.spp, p.ms, p.rel_mse, p.efficiency
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Maximum depth ({} spp, NEE + MIS)\n\nShallow paths miss light that arrives after \
         more bounces: their error is bias that no number of samples removes.\n\n| depth | trace ms | relative MSE | efficiency (1/s) |\n|---|---|---|---|",
        o.depth_spp
    );
    for p in &r.depth.points {
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3e} | {:.3e} |",
            p.depth, p.ms, p.rel_mse, p.efficiency
        );
    }
    let _ = writeln!(
        s,
        "\n## BVH quality\n\nBuild: median GPU time of transform + build over {} runs. SAH cost: sum \
         of every node's surface area over the root's (traversal and intersection cost 1; brute \
         force: one test per primitive). Rays per second: {}x{} frames of {} spp (median of {} runs; \
         brute force one frame of 1 spp).\n\n| tree | build ms | SAH cost | depth | rays/s |\n|---|---|---|---|---|",
        o.runs, o.speed_size.0, o.speed_size.1, o.speed_spp, o.runs
    );
    for b in &r.bvh {
        // The driver's row: its tree's cost and depth are not known.
        let (sah, depth) = if b.sah.is_finite() {
            (format!("{:.1}", b.sah), b.depth.to_string())
        } else {
            ("-".into(), "-".into())
        };
        let _ = writeln!(
            s,
            "| {} | {:.3} | {sah} | {depth} | {:.3e} |",
            b.name, b.build_ms, b.rays_per_s
        );
    }
    let _ = writeln!(
        s,
        "\n## Intersection precision\n\nRays per second of the scene's camera rays (depth 1, {}x{} \
         frames of {} spp, median of {} runs: the same rays for every variant), and rays \
         from inside closed meshes (icosphere, subdivided octahedron, cubes) aimed exactly at \
         every shared vertex and edge midpoint, the meshes at the origin and moved by {:?}: \
         every one should hit. Leaks through the BVH include rays whose box test missed.\n\n\
         | triangle and box tests | rays/s | rays | leaks (BVH) | leaks (brute force) | BVH leaks at offsets {:?} |\n|---|---|---|---|---|---|",
        o.speed_size.0, o.speed_size.1, o.speed_spp, o.runs, OFFSETS, OFFSETS
    );
    for p in &r.precision {
        let _ = writeln!(
            s,
            "| {} | {:.3e} | {} | {} | {} | {:?} |",
            p.name, p.rays_per_s, p.rays, p.leaks_bvh, p.leaks_brute, p.leaks_by_offset
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_mse_is_zero_for_the_reference_and_weighs_dark_pixels_less() {
        let reference = [[1.0, 0.5, 0.0], [0.0, 0.0, 0.0]];
        assert_eq!(rel_mse(&reference, &reference), 0.0);
        let off_by_tenth = [[1.1, 0.5, 0.0], [0.0, 0.0, 0.0]];
        let want = 0.01 / (1.0 + REL_MSE_EPS) / 6.0;
        let close = |a: f64, b: f64| (a - b).abs() < 1e-6 * b;
        assert!(close(rel_mse(&off_by_tenth, &reference), want));
        let dark = [[1.0, 0.5, 0.0], [0.1, 0.0, 0.0]];
        assert!(close(rel_mse(&dark, &reference), 0.01 / REL_MSE_EPS / 6.0));
    }

    #[test]
    fn sah_cost_sums_node_areas_over_the_root() {
        let node = |min: [f32; 3], max: [f32; 3], a: u32, b: u32| Node { min, a, max, b };
        // A unit cube root over two half boxes (leaves 1 and 2).
        let nodes = [
            node([0.0; 3], [1.0; 3], 1, 2),
            node([0.0; 3], [0.5, 1.0, 1.0], 0, INVALID),
            node([0.5, 0.0, 0.0], [1.0; 3], 1, INVALID),
        ];
        // Root 6, halves 2 (0.5 + 1 + 0.5) each: (6 + 4 + 4) / 6.
        assert!((sah_cost(&nodes) - 14.0 / 6.0).abs() < 1e-12);
        assert_eq!(sah_cost(&[]), 0.0);
    }
}
