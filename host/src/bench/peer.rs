//! `raytrace bench peer`: the project's tracer (its BVH built by its kernels every frame,
//! walked by `shared`'s traversal) against the driver's acceleration structures
//! (`--accel driver`: built by the driver every frame, fast-build, fast-trace or updated in
//! place, traced by its ray-tracing pipeline), on the same scenes with the same shading and
//! random streams: per built-in scene at the real-time settings (1080p, 1 spp, depth 4) and
//! the thesis's (800x800, 32 spp, depth 16) the build, trace and whole GPU frame, rays per
//! second and the structure's bytes, with ours divided by each; and build-only rows over
//! random triangles. Markdown, JSON and a stacked-bar plot.
use crate::bench::build::standard_inputs;
use crate::bench::plot::{stacked_bars, Bar};
use crate::bench::{percentile, warm};
use crate::bvh::{BuildOptions, MortonBits};
use crate::cli::{Prepared, SceneArgs};
use crate::gpu::driver::{DriverBuild, DriverTracer};
use crate::gpu::{stage_ms, Gpu, GpuLbvh, GpuRenderer, Kernels};
use crate::render;
use anyhow::{Context, Result};
use serde::Serialize;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Scenes (built-in names or TOML files), each laid out as `--instancing auto` chooses
    /// (flattened or in two levels), the same for both tracers; rendered with the scene's
    /// own settings (next-event estimation where it has lights).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "cornell,suzanne,bunny,spheres,instances,herd,forest"
    )]
    pub scenes: Vec<String>,
    /// Timed frames per scene, setting and tracer (the median is reported), after warm-up.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
    /// Random-triangle counts of the build-only rows (none: no build rows).
    #[arg(long, value_delimiter = ',', default_value = "1000000,4000000,16000000")]
    pub build_sizes: Vec<usize>,
}

/// A tracer of the comparison.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Tracer {
    /// The project's BVH (the default LBVH build for the frame's samples).
    Ours,
    Driver(DriverBuild),
}

impl Tracer {
    pub const ALL: [Tracer; 4] = [
        Tracer::Ours,
        Tracer::Driver(DriverBuild::FastBuild),
        Tracer::Driver(DriverBuild::FastTrace),
        Tracer::Driver(DriverBuild::Update),
    ];

    pub fn name(self) -> &'static str {
        match self {
            Tracer::Ours => "ours (LBVH)",
            Tracer::Driver(DriverBuild::FastBuild) => "driver, fast build",
            Tracer::Driver(DriverBuild::FastTrace) => "driver, fast trace",
            Tracer::Driver(DriverBuild::Update) => "driver, update",
        }
    }

    fn short(self) -> &'static str {
        match self {
            Tracer::Ours => "ours",
            Tracer::Driver(DriverBuild::FastBuild) => "fb",
            Tracer::Driver(DriverBuild::FastTrace) => "ft",
            Tracer::Driver(DriverBuild::Update) => "up",
        }
    }
}

/// A frame setting: the real-time one or the thesis's.
#[derive(Copy, Clone, Debug, Serialize)]
pub struct Setting {
    pub name: &'static str,
    pub size: (u32, u32),
    pub spp: u32,
    pub depth: u32,
}

pub const SETTINGS: [Setting; 2] = [
    Setting {
        name: "real time",
        size: (1920, 1080),
        spp: 1,
        depth: 4,
    },
    Setting {
        name: "thesis",
        size: (800, 800),
        spp: 32,
        depth: 16,
    },
];

#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub scene: String,
    pub setting: &'static str,
    pub tracer: Tracer,
    /// Primitives of the world (an instanced scene: every instance's).
    pub primitives: u64,
    /// Laid out in two levels (instances of meshes) rather than flattened.
    pub instanced: bool,
    /// Median GPU milliseconds per frame: transform and build, trace, the whole frame.
    pub build_ms: f64,
    pub trace_ms: f64,
    pub frame_ms: f64,
    /// Rays traced per second while tracing (the median frame's rays over its trace time).
    pub grays_per_s: f64,
    /// Bytes of the structure traced: the BVH's nodes, or the driver's levels.
    pub structure_bytes: u64,
}

/// A build-only row: random triangles, one build.
#[derive(Clone, Debug, Serialize)]
pub struct BuildRow {
    pub input: String,
    pub triangles: usize,
    /// Median milliseconds: ours (30-bit LBVH, no treelets), the driver's fast-build and
    /// fast-trace builds (bottom and top level).
    pub ours_ms: f64,
    pub fast_build_ms: f64,
    pub fast_trace_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub runs: usize,
    pub rows: Vec<Row>,
    pub builds: Vec<BuildRow>,
}

fn prepare(scene: &str, s: &Setting, tracer: Tracer) -> Result<Prepared> {
    let size = format!("{}x{}", s.size.0, s.size.1);
    let (spp, depth) = (s.spp.to_string(), s.depth.to_string());
    let mut args = vec!["raytrace", scene, "--size", &size, "--spp", &spp, "--depth", &depth];
    if let Tracer::Driver(b) = tracer {
        let build = match b {
            DriverBuild::FastBuild => "fast-build",
            DriverBuild::FastTrace => "fast-trace",
            DriverBuild::Update => "update",
        };
        args.extend(["--accel", "driver", "--driver-build", build]);
    } else {
        args.extend(["--accel", "lbvh"]);
    }
    <SceneArgs as clap::Parser>::parse_from(args).prepare()
}

/// Median timings of `runs` frames of `p` on a fresh renderer, each rebuilding.
fn time(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, p: &Prepared, runs: usize) -> Result<(f64, f64, f64, f64, u64)> {
    let mut r = GpuRenderer::new(gpu, kernels)?;
    r.set_build(p.build(p.spp));
    r.set_accel(p.tracer(gpu).0, p.driver_build)?;
    r.load(&p.data, &p.frame)?;
    warm(|| {
        r.set_frame(&p.frame)?;
        r.render(p.spp, true).map(|_| ())
    })?;
    let mut frames = Vec::new();
    for _ in 0..runs.max(1) {
        r.set_frame(&p.frame)?;
        let t = render::stage_totals(&r.render(p.spp, true)?);
        let build = stage_ms(&t, "transform") + stage_ms(&t, "build");
        let trace = stage_ms(&t, "trace");
        let frame: f64 = t.iter().map(|(_, s)| s * 1e3).sum();
        frames.push((frame, build, trace));
    }
    frames.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (frame, build, trace) = frames[frames.len() / 2];
    let rays = render::rays_traced(&r.picture()?) as f64;
    Ok((build, trace, frame, rays / (trace * 1e-3) * 1e-9, r.structure_bytes()))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    percentile(&v, 0.5)
}

/// Build-only rows: ours and the driver's over the same random triangles.
fn builds(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, sizes: &[usize], runs: usize) -> Result<Vec<BuildRow>> {
    let mut out = Vec::new();
    let inputs = standard_inputs(sizes)?;
    let mut driver = DriverTracer::new(gpu, kernels)?;
    for input in inputs.into_iter().filter(|i| i.name.ends_with("random")) {
        let mut lbvh = GpuLbvh::new(gpu, kernels)?;
        lbvh.upload(&input.tris, &[])?;
        let opts = BuildOptions::lbvh(MortonBits::B30);
        warm(|| lbvh.build_total(opts).map(|_| ()))?;
        let ours: Vec<f64> = (0..runs.max(1))
            .map(|_| lbvh.build_total(opts).map(|ns| ns * 1e-6))
            .collect::<Result<_>>()?;
        let n = input.tris.len() as u32;
        let tris = lbvh.buffers()?.0;
        let mut driver_ms = |b| -> Result<f64> {
            warm(|| driver.time_builds(tris, n, b, 1).map(|_| ()))?;
            Ok(median(driver.time_builds(tris, n, b, runs.max(1))?))
        };
        let row = BuildRow {
            input: input.name.clone(),
            triangles: input.tris.len(),
            ours_ms: median(ours),
            fast_build_ms: driver_ms(DriverBuild::FastBuild)?,
            fast_trace_ms: driver_ms(DriverBuild::FastTrace)?,
        };
        eprintln!(
            "build {}: ours {:.3} ms, driver fast build {:.3} ms, fast trace {:.3} ms",
            row.input, row.ours_ms, row.fast_build_ms, row.fast_trace_ms
        );
        out.push(row);
    }
    Ok(out)
}

pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    let kernels = Arc::new(Kernels::new(gpu)?);
    // Fails on a device without ray tracing, naming what it lacks.
    DriverTracer::new(gpu, &kernels)?;
    let mut rows = Vec::new();
    for scene in &o.scenes {
        for s in &SETTINGS {
            for tracer in Tracer::ALL {
                let p = prepare(scene, s, tracer).with_context(|| format!("{scene}, {}", tracer.name()))?;
                let (build_ms, trace_ms, frame_ms, grays_per_s, structure_bytes) = time(gpu, &kernels, &p, o.runs)
                    .with_context(|| format!("{scene}, {}, {}", s.name, tracer.name()))?;
                let row = Row {
                    scene: scene.clone(),
                    setting: s.name,
                    tracer,
                    primitives: {
                        let (tris, spheres) = p.scene.counts();
                        (tris + spheres) as u64
                    },
                    instanced: p.data.instancing.is_some(),
                    build_ms,
                    trace_ms,
                    frame_ms,
                    grays_per_s,
                    structure_bytes,
                };
                eprintln!(
                    "{scene}, {}, {}: build {:.3} ms, trace {:.3} ms, frame {:.3} ms",
                    s.name,
                    tracer.name(),
                    build_ms,
                    trace_ms,
                    frame_ms
                );
                rows.push(row);
            }
        }
    }
    let builds = builds(gpu, &kernels, &o.build_sizes, o.runs)?;
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        runs: o.runs,
        rows,
        builds,
    })
}

/// Ours divided by `row`'s value (`f`) for the same scene and setting: above 1, the driver
/// is faster.
fn ratio(r: &Report, row: &Row, f: impl Fn(&Row) -> f64) -> f64 {
    r.rows
        .iter()
        .find(|o| o.tracer == Tracer::Ours && o.scene == row.scene && o.setting == row.setting)
        .map_or(f64::NAN, |o| f(o) / f(row))
}

pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Our tracer against the driver's acceleration structures\n\n- date: {}\n- device: {}\n- command: `{}`\n- median of {} frames after half a second of warm-up; every frame transforms the scene and builds its structure again\n",
        r.date, r.device, r.command, r.runs
    );
    let _ = writeln!(
        s,
        "Both tracers run the same `shared` path loop, shading, sampling and random streams; \
         `ours` builds the project's LBVH with its kernels and walks it with `shared::traverse` \
         in a compute kernel, `driver` has the driver build bottom levels over the same \
         primitives (a flattened scene's world every frame; an instanced scene's meshes once and \
         its world-space group every frame) and a top level over them every frame, and traces \
         through a ray-tracing pipeline whose ray generation runs the path loop \
         (`--accel driver`). Each scene is laid out as `--instancing auto` chooses, the same for \
         both. `ours ÷ this`: above 1 the driver is faster.\n"
    );
    for setting in SETTINGS {
        let _ = writeln!(
            s,
            "## {} ({}x{}, {} spp, depth {})\n",
            setting.name, setting.size.0, setting.size.1, setting.spp, setting.depth
        );
        let _ = writeln!(
            s,
            "| scene | primitives | layout | tracer | build ms | trace ms | frame ms | Grays/s | structure MB | ours ÷ this, frame | ours ÷ this, trace |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
        for row in r.rows.iter().filter(|x| x.setting == setting.name) {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.1} | {:.2} | {:.2} |",
                row.scene,
                row.primitives,
                if row.instanced { "two levels" } else { "flattened" },
                row.tracer.name(),
                row.build_ms,
                row.trace_ms,
                row.frame_ms,
                row.grays_per_s,
                row.structure_bytes as f64 / 1e6,
                ratio(r, row, |x| x.frame_ms),
                ratio(r, row, |x| x.trace_ms)
            );
        }
        let _ = writeln!(s);
    }
    if !r.builds.is_empty() {
        let _ = writeln!(
            s,
            "## Builds alone (random triangles)\n\n| input | ours ms (LBVH, 30-bit) | driver fast build ms | driver fast trace ms | fast build ÷ ours | fast trace ÷ ours |\n|---|---|---|---|---|---|"
        );
        for b in &r.builds {
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} |",
                b.input,
                b.ours_ms,
                b.fast_build_ms,
                b.fast_trace_ms,
                b.fast_build_ms / b.ours_ms,
                b.fast_trace_ms / b.ours_ms
            );
        }
    }
    s
}

/// The real-time setting's frames as stacked bars (build, trace) per scene and tracer, at
/// `dir/stem.png`.
pub fn plot(r: &Report, dir: &Path, stem: &str) -> Result<PathBuf> {
    let path = dir.join(format!("{stem}.png"));
    let bars: Vec<Bar> = r
        .rows
        .iter()
        .filter(|x| x.setting == SETTINGS[0].name)
        .map(|x| Bar {
            label: format!("{} {}", x.scene, x.tracer.short()),
            parts: vec![x.build_ms, x.trace_ms],
        })
        .collect();
    let title = format!(
        "1080p, 1 spp, depth 4: ours against the driver (fb: fast build, ft: fast trace, up: update), {}",
        r.device
    );
    stacked_bars(&path, &title, "GPU ms per frame", &["build", "trace"], &bars, 2000, 600)?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_compare_each_row_with_ours_for_the_same_scene_and_setting() {
        let row = |scene: &str, setting, tracer, frame_ms| Row {
            scene: scene.into(),
            setting,
            tracer,
            primitives: 1,
            instanced: false,
            build_ms: 0.0,
            trace_ms: frame_ms,
            frame_ms,
            grays_per_s: 1.0,
            structure_bytes: 0,
        };
        let fb = Tracer::Driver(DriverBuild::FastBuild);
        let r = Report {
            date: String::new(),
            device: String::new(),
            command: String::new(),
            runs: 1,
            rows: vec![
                row("a", "real time", Tracer::Ours, 2.0),
                row("a", "real time", fb, 4.0),
                row("a", "thesis", Tracer::Ours, 30.0),
                row("a", "thesis", fb, 20.0),
            ],
            builds: vec![],
        };
        assert_eq!(ratio(&r, &r.rows[1], |x| x.frame_ms), 0.5);
        assert_eq!(ratio(&r, &r.rows[3], |x| x.frame_ms), 1.5);
        let md = markdown(&r);
        assert!(
            md.contains(
                "| a | 1 | flattened | driver, fast build | 0.000 | 4.000 | 4.000 | 1.00 | 0.0 | 0.50 | 0.50 |"
            ),
            "{md}"
        );
        let dir = std::env::temp_dir().join(format!("peer-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let png = plot(&r, &dir, "peer").expect("plot");
        assert!(png.exists());
    }
}
