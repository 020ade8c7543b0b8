//! `raytrace bench features`: per built-in scene, the path tracer with every feature against
//! the kernel specialised to what the scene needs (`crate::features`), same frame, same
//! random streams; the two images are compared to show the specialisation changes nothing
//! but time.
use crate::bench::{percentile, warm};
use crate::cli::{Prepared, SceneArgs};
use crate::gpu::driver::DriverBuild;
use crate::gpu::{stage_ms, Gpu, GpuRenderer, Kernels};
use crate::picture::{diff_stats, max_display_diff, Picture};
use crate::render::Accel;
use anyhow::{Context, Result};
use std::fmt::Write;
use std::sync::Arc;

#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub scene: String,
    /// Features of the specialised kernel ("+"-joined names).
    pub features: String,
    pub depth_all: u32,
    pub depth_specialised: u32,
    /// Median GPU time of the path tracing stage, ms.
    pub all_ms: f64,
    pub specialised_ms: f64,
    /// Relative RMSE of the specialised image against the all-features one.
    pub relative_rmse: f64,
    /// Largest difference of a display byte.
    pub max_display_diff: u32,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub size: (u32, u32),
    pub spp: u32,
    pub runs: usize,
    /// What traced the rays: the project's BVH, or the driver's structures.
    pub accel: Accel,
    pub rows: Vec<Row>,
}

fn prepare(scene: &str, size: (u32, u32), spp: u32, all: bool) -> Result<Prepared> {
    let size = format!("{}x{}", size.0, size.1);
    let spp = spp.to_string();
    let mut args = vec!["raytrace", scene, "--size", &size, "--spp", &spp];
    if all {
        args.extend(["--features", "all"]);
    }
    <SceneArgs as clap::Parser>::parse_from(args).prepare()
}

/// Median trace milliseconds of `runs` frames of `p.spp` samples after a warm-up
/// ([`warm`]), and the last picture.
fn time(r: &mut GpuRenderer, p: &Prepared, runs: usize) -> Result<(f64, Picture)> {
    r.set_build(p.build(p.spp));
    r.load(&p.data, &p.frame)?;
    warm(|| {
        r.set_frame(&p.frame)?;
        r.render(p.spp, true).map(|_| ())
    })?;
    let mut ms = Vec::new();
    for i in 0..runs + 1 {
        r.set_frame(&p.frame)?;
        let t = r.render(p.spp, true)?;
        if i > 0 {
            ms.push(stage_ms(&t, "trace"));
        }
    }
    ms.sort_by(f64::total_cmp);
    Ok((percentile(&ms, 0.5), r.picture()?))
}

/// Runs the benchmark; `accel` picks what traces both kernels' rays (`Accel::Driver`: the
/// ray-tracing pipeline specialised alike, its structures built `driver_build`).
pub fn run(
    gpu: &Arc<Gpu>,
    scenes: &[String],
    size: (u32, u32),
    spp: u32,
    runs: usize,
    accel: Accel,
    driver_build: DriverBuild,
) -> Result<Report> {
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut r = GpuRenderer::new(gpu, &kernels)?;
    r.set_accel(accel, driver_build)?;
    let mut rows = Vec::new();
    for scene in scenes {
        let all = prepare(scene, size, spp, true)?;
        let spec = prepare(scene, size, spp, false)?;
        let (all_ms, a) = time(&mut r, &all, runs.max(1)).with_context(|| format!("{scene}, all features"))?;
        let (spec_ms, b) = time(&mut r, &spec, runs.max(1)).with_context(|| format!("{scene}, specialised"))?;
        let d = diff_stats(&a, &b)?;
        let row = Row {
            scene: scene.clone(),
            features: spec.features.summary(),
            depth_all: all.frame.max_depth,
            depth_specialised: spec.frame.max_depth,
            all_ms,
            specialised_ms: spec_ms,
            relative_rmse: d.relative_rmse,
            max_display_diff: max_display_diff(&a, &b),
        };
        eprintln!("{}", line(&row));
        rows.push(row);
    }
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        size,
        spp,
        runs,
        accel,
        rows,
    })
}

fn line(r: &Row) -> String {
    format!(
        "| {} | {} | {} -> {} | {:.3} | {:.3} | {:.2}x | {:.1e} | {} |",
        r.scene,
        r.features,
        r.depth_all,
        r.depth_specialised,
        r.all_ms,
        r.specialised_ms,
        r.all_ms / r.specialised_ms,
        r.relative_rmse,
        r.max_display_diff
    )
}

pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Kernels specialised to the scene\n\n- date: {}\n- device: {}\n- command: `{}`\n- {}x{}, {} spp per frame, BVH rebuilt, median of {} frames after half a second of warm-up\n- rays traced by {}\n",
        r.date,
        r.device,
        r.command,
        r.size.0,
        r.size.1,
        r.spp,
        r.runs,
        match r.accel {
            Accel::Lbvh => "the project's BVH (`path_trace`, a compute kernel)",
            Accel::Driver => "the driver's acceleration structures (`--accel driver`: the ray-tracing pipeline, specialised alike)",
        }
    );
    let _ = writeln!(
        s,
        "`all` runs `path_trace` with every feature (the specialisation constant's default); \
         `specialised` runs it with only the features the scene needs (`raytrace render --explain` \
         says which and why). Same frame and random streams: the images should be the same up to \
         the last bits of floating point (the driver compiles two different programs).\n"
    );
    let _ = writeln!(
        s,
        "| scene | specialised features | depth | all ms | specialised ms | speed-up | relative RMSE | max display diff |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for row in &r.rows {
        let _ = writeln!(s, "{}", line(row));
    }
    s
}
