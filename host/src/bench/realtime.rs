//! `raytrace bench realtime`: the viewer's per-frame GPU work without a window. Each frame
//! the animation advances 1/60 s, the objects' transforms are uploaded, and one submission
//! transforms every primitive, rebuilds the whole BVH, traces the frame's samples into a
//! fresh accumulation image (the scene moved) and runs the display pass. Reports frame-time
//! percentiles from GPU timestamps and from the host's clock. Each scene runs again with the
//! real-time denoiser (SVGF, Schied et al. 2017: `Denoise::EveryFrame`) in place of the
//! display pass, every frame denoised: its frame time, and the denoiser's own.
use crate::bench::percentile;
use crate::cli::SceneArgs;
use crate::gpu::{frame_timings, is_denoise, Commands, Denoise, Gpu, GpuRenderer, Kernels};
use crate::view::LiveScene;
use anyhow::{bail, Context, Result};
use std::fmt::Write;
use std::sync::Arc;
use std::time::Instant;

/// Percentiles of one series of frame times, milliseconds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
}

impl Percentiles {
    fn of(mut v: Vec<f64>) -> Percentiles {
        v.sort_by(f64::total_cmp);
        Percentiles {
            p50: percentile(&v, 0.5),
            p90: percentile(&v, 0.9),
            p99: percentile(&v, 0.99),
            max: v.last().copied().unwrap_or(f64::NAN),
        }
    }
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub scene: String,
    pub triangles: usize,
    pub spheres: usize,
    pub animated: bool,
    pub nee: bool,
    /// The BVH built and traced.
    pub bvh: crate::bvh::Layout,
    /// What traced the rays, and how the driver built its structures where it did.
    pub accel: crate::render::Accel,
    pub driver_build: crate::gpu::driver::DriverBuild,
    /// Objects as instances of their meshes: two levels, the top level rebuilt every frame
    /// instead of the whole scene.
    pub instanced: bool,
    /// Primitives the GPU holds: each mesh once where instanced.
    pub distinct: u64,
    /// Device bytes of the BVH and its primitives (`GpuRenderer::bvh_memory`): both levels
    /// where instanced, the flattened scene's builder otherwise.
    pub bvh_bytes: u64,
    /// GPU time of a whole frame (timestamps, first to last), ms.
    pub gpu_ms: Percentiles,
    /// Transform + BVH rebuild, ms.
    pub build_ms: Percentiles,
    /// Path tracing, ms.
    pub trace_ms: Percentiles,
    /// Host clock from the objects' upload to the frame's fence, ms.
    pub wall_ms: Percentiles,
    /// Frames per second at the median GPU frame time.
    pub fps: f64,
    /// Rays traced per frame (primary, bounce and shadow rays).
    pub rays_per_frame: f64,
    /// The same frames with the real-time denoiser on (absent with `--no-denoise`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub denoised: Option<DenoisedRow>,
}

/// A scene's frames with every frame denoised ([`Denoise::EveryFrame`]).
#[derive(Clone, Debug, serde::Serialize)]
pub struct DenoisedRow {
    /// GPU time of a whole frame (transform, rebuild, trace, denoise), ms.
    pub gpu_ms: Percentiles,
    /// Path tracing (with the denoiser's guides written), ms.
    pub trace_ms: Percentiles,
    /// The denoiser's passes (they replace the display pass), ms.
    pub denoise_ms: Percentiles,
    /// Frames per second at the median GPU frame time.
    pub fps: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub width: u32,
    pub height: u32,
    pub spf: u32,
    pub depth: u32,
    pub frames: usize,
    /// Frames that refit a world-space group, and the top level, between two builds of it.
    pub group_refits: u32,
    pub top_refits: u32,
    pub rows: Vec<Row>,
}

/// Settings of a run.
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Scenes (built-in names or files).
    #[arg(long, value_delimiter = ',', default_value = "instances,bunny")]
    pub scenes: Vec<String>,
    #[arg(long, default_value = "1920x1080", value_parser = crate::cli::parse_size)]
    pub size: (u32, u32),
    /// Samples per pixel per frame.
    #[arg(long, default_value_t = 1)]
    pub spf: u32,
    #[arg(long, default_value_t = 4)]
    pub depth: u32,
    /// Timed frames per scene (after warm-up).
    #[arg(long, default_value_t = 300)]
    pub frames: usize,
    /// Untimed frames before them (after half a second of frames for the GPU's clocks).
    #[arg(long, default_value_t = 30)]
    pub warmup: usize,
    /// Also run every scene with next-event estimation on.
    #[arg(long = "nee")]
    pub both_nee: bool,
    /// Treelet restructuring of every frame's BVH (`auto`: from 16 samples per pixel and 32
    /// samples per primitive a frame).
    #[arg(long, value_enum, default_value = "auto")]
    pub treelets: crate::cli::Treelets,
    /// Which BVH every frame builds and traces (see `raytrace render --help`).
    #[arg(long, value_enum, default_value = "binary")]
    pub bvh: crate::bvh::Layout,
    /// How every frame's binary tree is built (see `raytrace render --help`).
    #[arg(long, value_enum, default_value = "auto")]
    pub tree: crate::cli::Tree,
    /// Whether every build writes the binary walk's pairs (see `raytrace render --help`).
    #[arg(long, value_enum, default_value = "auto")]
    pub pairs: crate::cli::Pairs,
    /// Skip the second run of every scene with the real-time denoiser.
    #[arg(long)]
    pub no_denoise: bool,
    /// Objects as instances of their meshes, or flattened (see `raytrace render --help`).
    #[arg(long, value_enum, default_value = "auto")]
    pub instancing: crate::scene::InstancingMode,
    /// What traces the rays: the project's BVH, or the driver's acceleration structures
    /// (see `raytrace render --help`; results then go to `realtime-driver-*`).
    #[arg(long, value_enum, default_value = "lbvh")]
    pub accel: crate::render::Accel,
    /// How the driver builds its bottom levels (with `--accel driver`).
    #[arg(long, value_enum, default_value = "fast-build")]
    pub driver_build: crate::gpu::driver::DriverBuild,
    /// Frames that refit a world-space group between its builds (see `raytrace render --help`).
    #[arg(long, default_value_t = crate::gpu::GROUP_REFITS)]
    pub group_refits: u32,
    /// Frames that refit the top level between its builds (see `raytrace render --help`).
    #[arg(long, default_value_t = crate::gpu::TOP_REFITS)]
    pub top_refits: u32,
}

/// Runs every scene of `o` and returns the report.
pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    if o.frames == 0 || o.spf == 0 {
        bail!("frames and samples per frame must be at least 1");
    }
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut rows = Vec::new();
    for scene in &o.scenes {
        for nee in if o.both_nee { vec![false, true] } else { vec![false] } {
            let size = format!("{}x{}", o.size.0, o.size.1);
            let depth = o.depth.to_string();
            let instancing = format!("{:?}", o.instancing).to_lowercase();
            let spf = o.spf.to_string();
            let mut args = vec![
                "raytrace",
                scene,
                "--size",
                &size,
                "--depth",
                &depth,
                "--instancing",
                &instancing,
                "--spp",
                &spf,
            ];
            if !nee {
                args.push("--no-nee");
            }
            if o.accel == crate::render::Accel::Driver {
                args.extend(["--accel", "driver"]);
            }
            let mut p = <SceneArgs as clap::Parser>::parse_from(args).prepare()?;
            p.treelets = o.treelets;
            p.layout = o.bvh;
            p.tree = o.tree;
            p.pairs = o.pairs;
            let mut r = GpuRenderer::new(gpu, &kernels)?;
            r.set_build(p.build(o.spf));
            r.set_group_refits(o.group_refits);
            r.set_top_refits(o.top_refits);
            r.set_accel(o.accel, o.driver_build)?;
            let mut live = LiveScene::with_instancing(p.scene, o.instancing);
            rows.push(run_scene(gpu, &mut r, &mut live, o, nee).with_context(|| format!("scene {scene}"))?);
            eprintln!("{}", row_line(rows.last().context("no row")?));
        }
    }
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        width: o.size.0,
        height: o.size.1,
        spf: o.spf,
        depth: o.depth,
        frames: o.frames,
        group_refits: o.group_refits,
        top_refits: o.top_refits,
        rows,
    })
}

/// GPU milliseconds of every timed frame: the whole frame, its transform and rebuild, its
/// trace and its denoising (0 where it was not denoised), and the host's wall time.
#[derive(Default)]
struct Timed {
    total: Vec<f64>,
    build: Vec<f64>,
    trace: Vec<f64>,
    denoise: Vec<f64>,
    wall: Vec<f64>,
}

/// Seconds of frames (at animation time 0) a scene renders at least before its warm-up
/// frames: the GPU's clocks rise over its first fraction of a second of work, which a count
/// of frames does not cover for a scene of fast frames (H200: the first scene of a run, the
/// bunny at 1.6 ms a frame, read p90 6.7 ms after its 20 warm-up frames; bench/NOTES.md,
/// session 42). From an idle GPU (a run's first scene after seconds of pipeline compilation)
/// half a second was not enough either: the flattened sixteen bunnies read p50 2.92, p90
/// 5.19 ms (session 49), so the frames go on until their GPU times settle
/// ([`clocks_settled`]), for at most [`CLOCK_WARMUP_MAX_S`].
const CLOCK_WARMUP_S: f64 = 0.5;

/// The longest the clocks' warm-up runs (a scene whose frame times never settle is then
/// timed as it is).
const CLOCK_WARMUP_MAX_S: f64 = 5.0;

/// Frames of the clocks' warm-up compared at a time by [`clocks_settled`].
const SETTLE_FRAMES: usize = 16;

/// Whether the GPU times of the same frame, `times` in the order run, have settled: the
/// median of the last [`SETTLE_FRAMES`] within 2% of the median of the ones before them.
fn clocks_settled(times: &[f64]) -> bool {
    if times.len() < 2 * SETTLE_FRAMES {
        return false;
    }
    let median = |t: &[f64]| {
        let mut t = t.to_vec();
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    };
    let last = median(&times[times.len() - SETTLE_FRAMES..]);
    let before = median(&times[times.len() - 2 * SETTLE_FRAMES..times.len() - SETTLE_FRAMES]);
    (last - before).abs() <= 0.02 * before
}

/// Runs [`CLOCK_WARMUP_S`] of frames or more (until [`clocks_settled`]), then `o.warmup +
/// o.frames` frames (the animation advancing 1/60 s a frame from time 0), timing the last
/// `o.frames`; returns the times and the rays of the last frame.
fn frames(gpu: &Arc<Gpu>, r: &mut GpuRenderer, live: &mut LiveScene, o: &Options) -> Result<(Timed, f64)> {
    let mut cmds = Commands::new(gpu)?;
    let mut timed = Timed::default();
    let mut rays = 0.0;
    // One frame at animation time `t`, waited for.
    let frame = |r: &mut GpuRenderer, live: &mut LiveScene, cmds: &mut Commands, t: f32| -> Result<()> {
        live.time = t;
        live.sync(r)?;
        cmds.begin()?;
        r.record(cmds, o.spf, true)?;
        cmds.submit_wait().context("rendering a frame")
    };
    let clocks = Instant::now();
    let mut warm = Vec::new();
    loop {
        let elapsed = clocks.elapsed().as_secs_f64();
        if elapsed >= CLOCK_WARMUP_MAX_S || (elapsed >= CLOCK_WARMUP_S && clocks_settled(&warm)) {
            break;
        }
        frame(r, live, &mut cmds, 0.0)?;
        warm.push(frame_timings(&cmds)?.iter().map(|(_, s)| s).sum::<f64>());
    }
    for i in 0..o.warmup + o.frames {
        let start = Instant::now();
        frame(r, live, &mut cmds, i as f32 / 60.0)?;
        let elapsed = start.elapsed().as_secs_f64();
        let t = frame_timings(&cmds)?;
        if i < o.warmup {
            continue;
        }
        let sum = |f: &dyn Fn(&str) -> bool| t.iter().filter(|(l, _)| f(l)).map(|(_, s)| s * 1e3).sum::<f64>();
        timed.total.push(sum(&|_| true));
        timed.trace.push(sum(&|l| l == "trace"));
        timed.denoise.push(sum(&is_denoise));
        timed
            .build
            .push(sum(&|l| l != "trace" && l != "display" && !is_denoise(l)));
        timed.wall.push(elapsed * 1e3);
        if i + 1 == o.warmup + o.frames {
            rays = r.rays_per_sample()? * o.spf as f64;
        }
    }
    Ok((timed, rays))
}

fn run_scene(gpu: &Arc<Gpu>, r: &mut GpuRenderer, live: &mut LiveScene, o: &Options, nee: bool) -> Result<Row> {
    let (plain, rays) = frames(gpu, r, live, o)?;
    let denoised = if o.no_denoise {
        None
    } else {
        // Every frame denoised, a still scene's too (it would show its accumulation from
        // 96 samples per pixel on).
        r.set_denoise(Denoise::EveryFrame)?;
        r.set_denoise_until(u32::MAX);
        let (d, _) = frames(gpu, r, live, o)?;
        r.set_denoise(Denoise::Off)?;
        if d.denoise.iter().any(|&ms| ms <= 0.0) {
            bail!("a frame was not denoised");
        }
        let gpu_ms = Percentiles::of(d.total);
        Some(DenoisedRow {
            fps: 1e3 / gpu_ms.p50,
            gpu_ms,
            trace_ms: Percentiles::of(d.trace),
            denoise_ms: Percentiles::of(d.denoise),
        })
    };
    let (tris, spheres) = live.scene.counts();
    let data = live.data();
    let gpu_ms = Percentiles::of(plain.total);
    Ok(Row {
        scene: live.scene.name.clone(),
        triangles: tris,
        spheres,
        animated: live.animated(),
        nee,
        bvh: if r.build_options().wide {
            crate::bvh::Layout::Wide
        } else {
            crate::bvh::Layout::Binary
        },
        accel: o.accel,
        driver_build: o.driver_build,
        instanced: data.instancing.is_some(),
        distinct: (data.model_tris.len() + data.model_spheres.len()) as u64,
        bvh_bytes: match o.accel {
            crate::render::Accel::Lbvh => r.bvh_memory(),
            crate::render::Accel::Driver => r.structure_bytes(),
        },
        fps: 1e3 / gpu_ms.p50,
        gpu_ms,
        build_ms: Percentiles::of(plain.build),
        trace_ms: Percentiles::of(plain.trace),
        wall_ms: Percentiles::of(plain.wall),
        rays_per_frame: rays,
        denoised,
    })
}

fn row_line(r: &Row) -> String {
    let denoised = r.denoised.as_ref().map_or_else(
        || "- | - | -".to_string(),
        |d| format!("{:.3} | {:.1} | {:.3}", d.gpu_ms.p50, d.fps, d.denoise_ms.p50),
    );
    format!(
        "| {} | {} | {} | {} | {} | {:.3} / {:.3} / {:.3} | {:.1} | {:.3} | {:.3} | {:.3} / {:.3} | {:.2} | {denoised} |",
        r.scene,
        r.triangles + r.spheres,
        if r.animated { "yes" } else { "no" },
        if r.nee { "on" } else { "off" },
        if r.accel == crate::render::Accel::Driver {
            let levels = if r.instanced { "two levels" } else { "flattened" };
            format!("driver's, {levels}, {:?} ({:.1} MB)", r.driver_build, r.bvh_bytes as f64 * 1e-6)
        } else if r.instanced {
            format!("two levels ({} distinct, {:.1} MB)", r.distinct, r.bvh_bytes as f64 * 1e-6)
        } else {
            format!("{:?} ({:.1} MB)", r.bvh, r.bvh_bytes as f64 * 1e-6)
        },
        r.gpu_ms.p50,
        r.gpu_ms.p90,
        r.gpu_ms.p99,
        r.fps,
        r.build_ms.p50,
        r.trace_ms.p50,
        r.wall_ms.p50,
        r.wall_ms.p99,
        r.rays_per_frame / (r.trace_ms.p50 * 1e-3) * 1e-9,
    )
}

pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Real-time frames (offscreen)\n\n- date: {}\n- device: {}\n- command: `{}`\n- {}x{}, {} sample(s) per pixel per frame, depth {}, {} frames after warm-up\n",
        r.date, r.device, r.command, r.width, r.height, r.spf, r.depth, r.frames
    );
    let _ = writeln!(
        s,
        "Every frame: objects' transforms uploaded (animation advancing 1/60 s), transform of every \
         primitive, full BVH rebuild (two levels, instanced: the top level over the objects built, \
         restructured by treelets, and refit by the {} frames after each build; each mesh's BVH kept; \
         a world-space group of waving objects built, and refit by the {} frames after each build), path tracing into a fresh accumulation image, display pass; one \
         submission, waited for. GPU times from timestamp queries; wall time is the host's clock around \
         upload, submission and wait. Denoised: the same frames again with the real-time denoiser \
         (SVGF) in place of the display pass, every frame denoised (a still scene's too, past the \
         96 samples per pixel from which the viewer shows its accumulation instead); its GPU frame \
         time, fps, and the denoiser's passes alone.\n",
        r.top_refits, r.group_refits
    );
    let _ = writeln!(
        s,
        "| scene | primitives | animated | NEE | BVH | GPU frame p50 / p90 / p99 ms | fps (p50) | rebuild p50 ms | trace p50 ms | wall p50 / p99 ms | Grays/s (trace) | denoised: GPU frame p50 ms | denoised: fps (p50) | denoise p50 ms |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for row in &r.rows {
        let _ = writeln!(s, "{}", row_line(row));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clocks_have_settled_when_the_frame_times_stop_falling() {
        let steady = vec![1.0; 2 * SETTLE_FRAMES];
        assert!(clocks_settled(&steady));
        assert!(!clocks_settled(&steady[1..]), "too few frames to compare");
        // Clocks rising: each frame 1% faster than the last.
        let rising: Vec<f64> = (0..4 * SETTLE_FRAMES).map(|i| 5.0 * 0.99f64.powi(i as i32)).collect();
        assert!(!clocks_settled(&rising));
        // A slow frame or two among settled ones leave the medians alone.
        let mut noisy = steady.clone();
        noisy[3] = 9.0;
        noisy[2 * SETTLE_FRAMES - 1] = 0.1;
        assert!(clocks_settled(&noisy));
        // A ramp that ended: times fell, then held.
        let ramp: Vec<f64> = (0..3 * SETTLE_FRAMES)
            .map(|i| if i < SETTLE_FRAMES { 5.0 } else { 2.9 })
            .collect();
        assert!(clocks_settled(&ramp));
        assert!(!clocks_settled(&ramp[..2 * SETTLE_FRAMES]));
    }
}
