//! `raytrace bench trace`: rays per second through each BVH layout (`--bvh binary|wide`) for
//! primary rays, diffuse bounces to depth 4 and shadow rays (any-hit segments from the
//! primary hits to a light), with the tree's build time and surface-area cost beside them,
//! and the real-time frame (1 spp, depth 4, BVH rebuilt) split into build and trace; with
//! `--accel driver` the same through the driver's acceleration structures instead. Writes
//! Markdown, JSON and a stacked-bar plot of the frame per scene and layout.
use crate::bench::accuracy::{sah_cost, sah_cost_wide};
use crate::bench::plot::{stacked_bars, Bar};
use crate::bench::{percentile, warm};
use crate::bvh::{BuildOptions, Layout};
use crate::cli::{Prepared, SceneArgs};
use crate::gpu::driver::DriverBuild;
use crate::gpu::{stage_ms, Gpu, GpuRenderer, Kernels};
use crate::render::Accel;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use shared::glam::Vec3;
use shared::rng::Rng;
use shared::types::{
    prim_box, xyz, Frame, Ray, Sphere, Triangle, FEATURE_THIN_LENS, FLAG_NEE, FLAG_RUSSIAN_ROULETTE, INVALID,
};
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Settings of a run.
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Scenes (built-in names or files).
    #[arg(long, value_delimiter = ',', default_value = "cornell,bunny,instances,herd")]
    pub scenes: Vec<String>,
    #[arg(long, default_value = "1920x1080", value_parser = crate::cli::parse_size)]
    pub size: (u32, u32),
    /// Samples per pixel of the primary and diffuse measurements.
    #[arg(long, default_value_t = 16)]
    pub spp: u32,
    /// Timed repetitions of each measurement (medians reported), after one discarded.
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// What traces the rays: the project's BVH in both layouts, or the driver's acceleration
    /// structures (on devices with VK_KHR_ray_tracing_pipeline).
    #[arg(long, value_enum, default_value_t = Accel::Lbvh)]
    pub accel: Accel,
    /// How the driver builds its bottom levels (with `--accel driver`).
    #[arg(long, value_enum, default_value_t = DriverBuild::FastBuild)]
    pub driver_build: DriverBuild,
    /// Also trace every scene with instances in two levels (`--instancing on`), its batches
    /// the very rays of the flattened rows (with `--accel lbvh`).
    #[arg(long)]
    pub levels: bool,
}

/// What traced a row: one of the project's BVH layouts, or the driver's structures.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Tracer {
    Ours(Layout),
    /// Our binary BVHs in two levels: the meshes' and the top level over the instances.
    Levels,
    Driver(DriverBuild),
}

impl Tracer {
    /// The name a row shows: `Binary`, `Wide`, `Binary, two levels`, `Driver FastBuild`.
    pub fn name(self) -> String {
        match self {
            Tracer::Ours(layout) => format!("{layout:?}"),
            Tracer::Levels => "Binary, two levels".to_string(),
            Tracer::Driver(build) => format!("Driver {build:?}"),
        }
    }
}

/// One scene through one layout.
#[derive(Serialize)]
pub struct Row {
    pub scene: String,
    pub primitives: usize,
    /// What traced it ([`Tracer::name`]).
    pub layout: String,
    /// Transform and build of the frame, ms (median).
    pub build_ms: f64,
    /// Surface-area cost of the project's tree (`None` for the driver's structures).
    pub sah: Option<f64>,
    /// Billions of rays per second while tracing (medians).
    pub primary_grays: f64,
    pub diffuse_grays: f64,
    /// The batches (`cast_rays`; `None` where the scene's batches could not be made: the
    /// driver's row of a scene in two levels too large to flatten). Shadow: any-hit segments
    /// from every primary hit to the first light.
    pub shadow_grays: Option<f64>,
    /// Closest-hit queries alone (`cast_rays`, no shading between them): the primary rays,
    /// and one cosine-distributed bounce from every primary hit. Beside the path tracer's
    /// rates above they show what the traversal would reach without the megakernel's shading.
    pub batch_primary_grays: Option<f64>,
    pub batch_bounce_grays: Option<f64>,
    /// The real-time frame: 1 spp, depth 4, no NEE, BVH rebuilt (medians, ms).
    pub frame_build_ms: f64,
    pub frame_trace_ms: f64,
}

#[derive(Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub rows: Vec<Row>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    percentile(&v, 0.5)
}

/// Runs every scene of `o` through both layouts.
pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    if o.runs == 0 || o.spp == 0 {
        bail!("runs and samples per pixel must be at least 1");
    }
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut rows = Vec::new();
    for scene in &o.scenes {
        let size = format!("{}x{}", o.size.0, o.size.1);
        let args = [
            "raytrace",
            scene,
            "--size",
            &size,
            "--no-nee",
            "--no-roulette",
            "--depth",
            "4",
        ];
        // Our layouts' rows trace the flattened scene (the driver's, the scene as `--instancing
        // auto` lays it out).
        let flat = [&args[..], &["--instancing", "off"]].concat();
        let p = match o.accel {
            Accel::Lbvh => <SceneArgs as clap::Parser>::try_parse_from(&flat)?.prepare()?,
            Accel::Driver => <SceneArgs as clap::Parser>::try_parse_from(args)?.prepare()?,
        };
        // The batches' rays, made by the scene's first row and cast by every row; for the
        // driver's row of a scene in two levels, made from the flattened scene as our rows'
        // are (its hits name model-space primitives, which make no world-space rays).
        let mut queries = None;
        let mut batches = true;
        if o.accel == Accel::Driver && p.data.instancing.is_some() {
            match <SceneArgs as clap::Parser>::try_parse_from(&flat)?.prepare() {
                Ok(flattened) => {
                    let mut r = GpuRenderer::new(gpu, &kernels)?;
                    queries = Some(Queries::of(&mut r, &flattened)?);
                }
                Err(e) => {
                    eprintln!("scene {scene}: no batches (they are the flattened scene's rays): {e:#}");
                    batches = false;
                }
            }
        }
        let mut tracers = match o.accel {
            Accel::Lbvh => vec![Tracer::Ours(Layout::Binary), Tracer::Ours(Layout::Wide)],
            Accel::Driver => vec![Tracer::Driver(o.driver_build)],
        };
        let levels = if o.levels && o.accel == Accel::Lbvh {
            let on = [&args[..], &["--instancing", "on"]].concat();
            let p = <SceneArgs as clap::Parser>::try_parse_from(on)?.prepare()?;
            p.data.instancing.is_some().then_some(p)
        } else {
            None
        };
        if levels.is_some() {
            tracers.push(Tracer::Levels);
        }
        for tracer in tracers {
            let mut r = GpuRenderer::new(gpu, &kernels)?;
            let p = match (tracer, &levels) {
                (Tracer::Levels, Some(levels)) => levels,
                _ => &p,
            };
            let row = measure(&mut r, p, tracer, o, batches.then_some(&mut queries))
                .with_context(|| format!("scene {scene}, {}", tracer.name()))?;
            eprintln!(
                "{} {:?}: build {:.3} ms, primary {:.2}, diffuse {:.2}, shadow {}, batch primary {}, batch bounce {} Grays/s",
                row.scene,
                row.layout,
                row.build_ms,
                row.primary_grays,
                row.diffuse_grays,
                rate_text(row.shadow_grays, 2),
                rate_text(row.batch_primary_grays, 2),
                rate_text(row.batch_bounce_grays, 2)
            );
            rows.push(row);
        }
    }
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        width: o.size.0,
        height: o.size.1,
        spp: o.spp,
        rows,
    })
}

/// `v` with `digits` decimals, `-` for none.
fn rate_text(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.digits$}"))
}

/// One row; `queries`, the batches' rays, are made from this row's hits where none are yet
/// (a flattened scene's: the hits of two levels name model-space triangles), and not
/// measured where `None`.
fn measure(
    r: &mut GpuRenderer,
    p: &Prepared,
    tracer: Tracer,
    o: &Options,
    queries: Option<&mut Option<Queries>>,
) -> Result<Row> {
    let build = BuildOptions {
        wide: tracer == Tracer::Ours(Layout::Wide),
        ..BuildOptions::lbvh(p.bits)
    };
    r.set_build(build);
    match tracer {
        Tracer::Ours(_) | Tracer::Levels => r.set_accel(Accel::Lbvh, o.driver_build)?,
        Tracer::Driver(b) => r.set_accel(Accel::Driver, b)?,
    }
    r.load(&p.data, &p.frame)?;
    let depth = |d: u32| Frame {
        max_depth: d,
        flags: p.frame.flags & !(FLAG_NEE | FLAG_RUSSIAN_ROULETTE),
        ..p.frame
    };
    // Rays per second of `spp` samples of `frame` (the build before them not counted), after
    // half a second of such frames: the GPU's clocks drop within a fraction of a second of
    // idling, and short submissions each followed by a wait do not raise them again.
    let grays = |r: &mut GpuRenderer, frame: &Frame, spp: u32| -> Result<(f64, f64, f64)> {
        r.set_frame(frame)?;
        warm(|| r.render(spp, true).map(|_| ()))?;
        let (mut rates, mut builds, mut traces) = (Vec::new(), Vec::new(), Vec::new());
        for run in 0..=o.runs {
            r.set_frame(frame)?;
            let t = r.render(spp, true)?;
            let trace = stage_ms(&t, "trace");
            let rays = r.rays_per_sample()? * spp as f64;
            if run > 0 {
                rates.push(rays / (trace * 1e-3) * 1e-9);
                builds.push(
                    t.iter()
                        .filter(|(l, _)| *l != "trace" && *l != "display")
                        .map(|(_, s)| s * 1e3)
                        .sum(),
                );
                traces.push(trace);
            }
        }
        Ok((median(rates), median(builds), median(traces)))
    };
    let (primary, build_ms, _) = grays(r, &depth(1), o.spp)?;
    let (diffuse, _, _) = grays(r, &depth(4), o.spp)?;
    let (_, frame_build_ms, frame_trace_ms) = grays(r, &depth(4), 1)?;
    let sah = match tracer {
        Tracer::Driver(_) | Tracer::Levels => None,
        Tracer::Ours(_) => {
            let bvh = r.bvh()?;
            Some(if build.wide {
                sah_cost_wide(&bvh.wide)
            } else {
                sah_cost(&bvh.nodes)
            })
        }
    };
    let (shadow, batch_primary, batch_bounce) = match queries {
        None => (None, None, None),
        Some(queries) => {
            let queries = match queries {
                Some(q) => q,
                None if tracer == Tracer::Levels => bail!("two levels' batches need a flattened row's rays first"),
                None => queries.insert(Queries::new(r, &depth(1), &p.data.lights)?),
            };
            (
                Some(rate(r, &queries.segments, true, o.runs)?),
                Some(rate(r, &queries.primaries, false, o.runs)?),
                Some(rate(r, &queries.bounces, false, o.runs)?),
            )
        }
    };
    Ok(Row {
        scene: p.scene.name.clone(),
        primitives: p.data.prim_object.len(),
        layout: tracer.name(),
        build_ms,
        sah,
        primary_grays: primary,
        diffuse_grays: diffuse,
        shadow_grays: shadow,
        batch_primary_grays: batch_primary,
        batch_bounce_grays: batch_bounce,
        frame_build_ms,
        frame_trace_ms,
    })
}

/// The batches of rays cast without the path tracer: every pixel's primary ray; from every
/// primary hit, a segment to a point on the first light (the top of the scene's bounds where
/// none emits; [`light_point`]), as next-event estimation casts them, and a
/// cosine-distributed bounce about the geometric normal (facing the ray), as a diffuse
/// surface scatters.
struct Queries {
    primaries: Vec<Ray>,
    segments: Vec<Ray>,
    bounces: Vec<Ray>,
}

impl Queries {
    /// The batches of the flattened scene `p`, through our binary BVH.
    fn of(r: &mut GpuRenderer, p: &Prepared) -> Result<Queries> {
        r.set_build(BuildOptions::lbvh(p.bits));
        r.set_accel(Accel::Lbvh, DriverBuild::default())?;
        r.load(&p.data, &p.frame)?;
        let frame = Frame {
            max_depth: 1,
            flags: p.frame.flags & !(FLAG_NEE | FLAG_RUSSIAN_ROULETTE),
            ..p.frame
        };
        Queries::new(r, &frame, &p.data.lights)
    }

    fn new(r: &mut GpuRenderer, frame: &Frame, lights: &[u32]) -> Result<Queries> {
        r.set_frame(frame)?;
        r.render(0, true)?;
        let (tris, spheres) = r.world()?;
        let (w, h) = (frame.width, frame.height);
        let primaries: Vec<Ray> = (0..w * h)
            .map(|i| {
                let mut rng = Rng::new(i, 0, 0x5ead);
                let features = frame.features & !FEATURE_THIN_LENS;
                let (o, d) = shared::path::camera_ray(&frame.camera, w, h, i % w, i / w, features, &mut rng);
                Ray {
                    origin: [o.x, o.y, o.z, 0.0],
                    dir: [d.x, d.y, d.z, f32::INFINITY],
                }
            })
            .collect();
        let hits = r.cast(&primaries)?;
        let light = light_point(&tris, &spheres, lights, frame);
        let (mut segments, mut bounces) = (Vec::new(), Vec::new());
        for (i, (ray, hit)) in primaries.iter().zip(&hits).enumerate() {
            if hit.prim == INVALID {
                continue;
            }
            let (dir, p) = (xyz(ray.dir), xyz(ray.origin) + xyz(ray.dir) * hit.t);
            let n = if hit.prim < frame.n_tris {
                let t = &tris[hit.prim as usize];
                (xyz(t.v1) - xyz(t.v0)).cross(xyz(t.v2) - xyz(t.v0))
            } else {
                p - xyz(spheres[(hit.prim - frame.n_tris) as usize].center_radius)
            }
            .normalize_or_zero();
            if n == Vec3::ZERO {
                continue;
            }
            let n = if n.dot(dir) > 0.0 { -n } else { n };
            // Rays leave the surface by a relative 1e-5 of the hit's magnitude (or of 1 near
            // the origin) on their own side, as paths leave it: a segment started on the
            // surface would hit it about half the time and measure nothing.
            let lift = 1e-5 * p.abs().max_element().max(1.0);
            let target = light.seen_from(p);
            let s = p + if n.dot(target - p) < 0.0 { -n } else { n } * lift;
            let d = target - s;
            segments.push(Ray {
                origin: [s.x, s.y, s.z, 0.0],
                dir: [d.x, d.y, d.z, 1.0 - 1e-4],
            });
            let mut rng = Rng::new(i as u32, 1, 0xb0b);
            let b = shared::sampling::cosine_hemisphere(n, rng.next_f32(), rng.next_f32());
            let o = p + n * lift;
            bounces.push(Ray {
                origin: [o.x, o.y, o.z, 0.0],
                dir: [b.x, b.y, b.z, f32::INFINITY],
            });
        }
        Ok(Queries {
            primaries,
            segments,
            bounces,
        })
    }
}

/// Billions of `rays` per second through `cast_rays` (any-hit queries where `any`): the
/// median of `runs` submissions of 32 back-to-back dispatches each, after a warm-up.
fn rate(r: &mut GpuRenderer, rays: &[Ray], any: bool, runs: usize) -> Result<f64> {
    if rays.is_empty() {
        return Ok(0.0);
    }
    warm(|| r.time_casts(rays, any, 32).map(|_| ()))?;
    let mut rates = Vec::new();
    for run in 0..=runs {
        let s = r.time_casts(rays, any, 32)?;
        if run > 0 {
            rates.push(rays.len() as f64 / s * 1e-9);
        }
    }
    Ok(median(rates))
}

/// Where the shadow segments end, seen from a point: a point of the first light primitive
/// (its centre; on a sphere, its point nearest the one seen from, so the segment stops short
/// of the light instead of entering it, as next-event estimation's do), or the top centre of
/// the scene's bounds where none emits.
enum LightPoint {
    At(Vec3),
    Sphere(Vec3, f32),
}

impl LightPoint {
    fn seen_from(&self, p: Vec3) -> Vec3 {
        match *self {
            LightPoint::At(q) => q,
            LightPoint::Sphere(c, r) => c + (p - c).normalize_or_zero() * r,
        }
    }
}

fn light_point(tris: &[Triangle], spheres: &[Sphere], lights: &[u32], f: &Frame) -> LightPoint {
    let n_tris = f.n_tris;
    if let Some(&l) = lights.first() {
        if l >= n_tris {
            let s = spheres[(l - n_tris) as usize].center_radius;
            return LightPoint::Sphere(xyz(s), s[3]);
        }
        let (lo, hi) = prim_box(l, n_tris, tris, spheres);
        return LightPoint::At((lo + hi) * 0.5);
    }
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for i in 0..f.n_prims {
        let (l, h) = prim_box(i, n_tris, tris, spheres);
        lo = lo.min(l);
        hi = hi.max(h);
    }
    LightPoint::At(Vec3::new((lo.x + hi.x) * 0.5, hi.y, (lo.z + hi.z) * 0.5))
}

pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Trace throughput per BVH layout\n\n- date: {}\n- device: {}\n- command: `{}`\n- {}x{}, {} spp per measurement, medians after half a second of warm-up and one discarded run\n",
        r.date, r.device, r.command, r.width, r.height, r.spp
    );
    let _ = writeln!(
        s,
        "Primary: depth 1; diffuse: bounces to depth 4 (no next-event estimation, no Russian \
         roulette); shadow: any-hit segments from every primary hit to the first light (its \
         centre; a sphere's near side). Grays/s over the trace stage's GPU time. Build: \
         transform and BVH build of a frame (the driver's: its structures' builds). SAH: \
         surface-area cost of the tree traced (not known for the driver's). Frame: 1 spp, \
         depth 4, BVH rebuilt. \
         Batch: closest-hit queries alone (`cast_rays`, no shading): every primary ray, and one \
         cosine-distributed bounce from every primary hit, the same rays for every row of a scene \
         (made from the flattened scene's hits; `-` where it cannot be flattened). \
         Binary and Wide trace the scene flattened, Binary, two levels its meshes' BVHs under a \
         top level over the instances (`--levels`).\n"
    );
    let _ = writeln!(
        s,
        "| scene | primitives | BVH | build ms | SAH | primary Grays/s | diffuse Grays/s | shadow Grays/s | batch primary | batch bounce | frame ms (build + trace) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for row in &r.rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {} | {:.3} | {:.3} | {} | {} | {} | {:.3} ({:.3} + {:.3}) |",
            row.scene,
            row.primitives,
            row.layout,
            row.build_ms,
            row.sah.map_or("-".to_string(), |c| format!("{c:.1}")),
            row.primary_grays,
            row.diffuse_grays,
            rate_text(row.shadow_grays, 3),
            rate_text(row.batch_primary_grays, 3),
            rate_text(row.batch_bounce_grays, 3),
            row.frame_build_ms + row.frame_trace_ms,
            row.frame_build_ms,
            row.frame_trace_ms,
        );
    }
    s
}

/// The plot of the real-time frame per scene and layout, split into build and trace; returns
/// its path.
pub fn plot(r: &Report, dir: &Path, stem: &str) -> Result<PathBuf> {
    let path = dir.join(format!("{stem}-frame.png"));
    let bars: Vec<Bar> = r
        .rows
        .iter()
        .map(|row| Bar {
            label: format!("{} {}", row.scene, row.layout).to_lowercase(),
            parts: vec![row.frame_build_ms, row.frame_trace_ms],
        })
        .collect();
    let title = format!("Frame (1 spp, depth 4, BVH rebuilt), {}", r.device);
    stacked_bars(&path, &title, "GPU ms per frame", &["build", "trace"], &bars, 1100, 600)?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frame_plot_draws_every_row() {
        let row = |scene: &str, tracer: Tracer, build, trace| Row {
            scene: scene.into(),
            primitives: 1,
            layout: tracer.name(),
            build_ms: build,
            sah: matches!(tracer, Tracer::Ours(_)).then_some(1.0),
            primary_grays: 1.0,
            diffuse_grays: 1.0,
            shadow_grays: Some(1.0),
            batch_primary_grays: Some(1.0),
            batch_bounce_grays: Some(1.0),
            frame_build_ms: build,
            frame_trace_ms: trace,
        };
        let mut r = Report {
            date: "today".into(),
            device: "test".into(),
            command: "test".into(),
            width: 1,
            height: 1,
            spp: 1,
            rows: vec![
                row("bunny", Tracer::Ours(Layout::Binary), 0.1, 1.7),
                row("bunny", Tracer::Ours(Layout::Wide), 0.2, 1.6),
                row("bunny", Tracer::Driver(DriverBuild::FastBuild), 0.3, 1.2),
            ],
        };
        // A row without batches (the driver's of a scene that cannot be flattened).
        let driver = &mut r.rows[2];
        (
            driver.shadow_grays,
            driver.batch_primary_grays,
            driver.batch_bounce_grays,
        ) = (None, None, None);
        let dir = std::env::temp_dir().join(format!("raytrace-trace-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = plot(&r, &dir, "t").unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1100, 600));
        let md = markdown(&r);
        assert!(md.contains("| bunny | 1 | Wide | 0.200 | 1.0 |"), "{md}");
        assert!(md.contains("| bunny | 1 | Driver FastBuild | 0.300 | - |"), "{md}");
        assert!(
            md.contains("| 1.000 | 1.000 | - | - | - | 1.500 (0.300 + 1.200) |"),
            "{md}"
        );
        let json = serde_json::to_value(&r.rows[2]).unwrap();
        assert!(
            json["shadow_grays"].is_null() && json["batch_bounce_grays"].is_null(),
            "{json}"
        );
    }
}
