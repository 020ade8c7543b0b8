//! `raytrace bench devices`: one render split across the first 1, 2, ..., D devices of the
//! host (`render --devices`): wall-clock and GPU time, speed-up and efficiency against one
//! device, and each image's largest difference from the one device's (float rounding only).
use crate::cli::{render_devices, render_devices_each, DevicesTimes, Prepared, SceneArgs};
use crate::gpu::GpuOptions;
use anyhow::{ensure, Result};
use clap::Parser;
use std::fmt::Write;
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, serde::Serialize)]
pub struct Options {
    /// Scene (built-in name or file).
    #[arg(long, default_value = "bunny")]
    pub scene: String,
    #[arg(long, default_value = "3840x2160", value_parser = crate::cli::parse_size)]
    pub size: (u32, u32),
    /// Samples per pixel of the render.
    #[arg(long, default_value_t = 1024)]
    pub spp: u32,
    /// The devices, in the order they are added: `all`, or indices or names separated by
    /// commas.
    #[arg(long, default_value = "all")]
    pub devices: String,
    /// Renders per number of devices: each row is the run of median wall time.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    pub runs: u32,
    /// What traces the rays on every device: the project's BVH, or the driver's acceleration
    /// structures (on devices with VK_KHR_ray_tracing_pipeline).
    #[arg(long, value_enum, default_value_t = crate::render::Accel::Lbvh)]
    pub accel: crate::render::Accel,
    /// How the driver builds its bottom levels (with `--accel driver`).
    #[arg(long, value_enum, default_value_t = crate::gpu::driver::DriverBuild::FastBuild)]
    pub driver_build: crate::gpu::driver::DriverBuild,
}

/// The render on the first `devices` devices.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub devices: usize,
    /// Host clock from the start of the render to its image (devices opened, scene uploaded,
    /// traced, summed), the median of the runs.
    pub wall_s: f64,
    /// Every run's wall clock, in the order run.
    pub runs_s: Vec<f64>,
    /// Where the wall clock went, and each device's GPU time.
    pub times: DevicesTimes,
    /// The slowest device's GPU time.
    pub gpu_s: f64,
    /// One device's wall time over this row's.
    pub speedup: f64,
    /// Speed-up over the number of devices.
    pub efficiency: f64,
    /// Largest difference of the linear image from one device's, relative to its peak.
    pub max_rel_diff: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub date: String,
    pub command: String,
    pub options: Options,
    pub rows: Vec<Row>,
}

/// The largest difference between the linear images `a` and `b`, relative to `a`'s peak.
fn max_rel_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let flat = |v: &[[f32; 3]]| v.iter().flatten().map(|&x| x as f64).collect::<Vec<f64>>();
    let (a, b) = (flat(a), flat(b));
    let peak = a.iter().fold(0f64, |m, &x| m.max(x.abs())).max(1e-12);
    a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max) / peak
}

pub fn run(o: &Options, opts: &GpuOptions) -> Result<Report> {
    let devices = crate::cli::parse_devices(&o.devices)?;
    let size = format!("{}x{}", o.size.0, o.size.1);
    let spp = o.spp.to_string();
    let args = SceneArgs::try_parse_from(["raytrace", o.scene.as_str(), "--size", &size, "--spp", &spp])?;
    let mut p: Prepared = args.prepare()?;
    p.accel = o.accel.into();
    p.driver_build = o.driver_build;
    ensure!(
        devices.len() as u32 <= p.spp,
        "{} devices for {} samples per pixel",
        devices.len(),
        p.spp
    );
    // Warm-up: every device has rendered the first sample of the same frame (the same
    // pipelines: the driver caches those it made).
    for d in &devices {
        render_devices(&p, 0, 1, std::slice::from_ref(d), opts)?;
    }
    let mut rows: Vec<Row> = Vec::new();
    let mut one: Option<(Vec<[f32; 3]>, f64)> = None;
    for k in 1..=devices.len() {
        let mut runs = Vec::new();
        for run in 0..o.runs {
            eprintln!("{} on {k} device(s), run {}", o.scene, run + 1);
            let start = Instant::now();
            let (rendered, mut times, closing) = render_devices_each(&p, 0, p.spp, &devices[..k], opts)?;
            let wall_s = start.elapsed().as_secs_f64();
            times.close_s = closing.close();
            runs.push((wall_s, rendered, times));
        }
        let runs_s: Vec<f64> = runs.iter().map(|r| r.0).collect();
        runs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (wall_s, rendered, times) = runs.swap_remove(runs.len() / 2);
        let image = rendered.picture.linear();
        let (base, base_wall) = one.get_or_insert_with(|| (image.clone(), wall_s)).clone();
        let speedup = base_wall / wall_s;
        rows.push(Row {
            devices: k,
            gpu_s: times.gpu_s.iter().map(|s| s.1).fold(0.0, f64::max),
            times,
            wall_s,
            runs_s,
            speedup,
            efficiency: speedup / k as f64,
            max_rel_diff: max_rel_diff(&base, &image),
        });
    }
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        options: o.clone(),
        rows,
    })
}

pub fn markdown(r: &Report) -> String {
    let o = &r.options;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# One render on several devices\n\n- date: {}\n- command: `{}`\n- {} at {}x{}, {} spp, {} runs per row, traced by {}: the samples split into equal consecutive shares, one a device, each device on a thread of its own with its own renderer; the sums added in device order\n- wall: the host's clock from the start of the render to its image (devices opened, scene uploaded, BVH built, traced, sums read back and added; every device rendered the first sample of the frame once before); the median run; the devices close after that (close, below), as `render` closes them while it writes the image; GPU: the slowest device's timestamps\n",
        r.date,
        r.command,
        o.scene,
        o.size.0,
        o.size.1,
        o.spp,
        o.runs,
        match o.accel {
            crate::render::Accel::Lbvh => "the project's BVH".to_string(),
            crate::render::Accel::Driver => format!("the driver's acceleration structures ({:?})", o.driver_build),
        }
    );
    let _ = writeln!(
        s,
        "| devices | wall s (median) | runs' wall s | GPU s (slowest) | speed-up | efficiency | largest difference from one device | devices' GPU s |\n|---|---|---|---|---|---|---|---|"
    );
    for row in &r.rows {
        let each: Vec<String> = row.times.gpu_s.iter().map(|(d, t)| format!("{d}: {t:.3}")).collect();
        let _ = writeln!(
            s,
            "| {} | {:.3} | {} | {:.3} | {:.2}x | {:.0}% | {:.1e} | {} |",
            row.devices,
            row.wall_s,
            row.runs_s
                .iter()
                .map(|t| format!("{t:.3}"))
                .collect::<Vec<_>>()
                .join(", "),
            row.gpu_s,
            row.speedup,
            row.efficiency * 100.0,
            row.max_rel_diff,
            each.join(", ")
        );
    }
    let _ = writeln!(
        s,
        "\nWhere the median run's wall clock went (host seconds; of the device that took longest): the instance the devices share and opening the device (of it, instance and device; the kernels' module and layouts; the rest the renderer), loading the scene, tracing until its last submission finished (of it the first submission: pipelines made, BVH built, one sample), reading its sums back; then adding the sums and making the display image; after the image, closing the devices.\n\n| devices | open | of it: instance + device | kernels | load | trace | of it: first submission | submissions | read back | add + display | close (after) |\n|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for row in &r.rows {
        let t = &row.times;
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {:.3} | {:.3} | {:.3} |",
            row.devices,
            t.open_s,
            t.device_s,
            t.kernels_s,
            t.load_s,
            t.trace_s,
            t.first_s,
            t.submissions,
            t.read_s,
            t.merge_s,
            t.close_s
        );
    }
    let _ = writeln!(s, "\nOpening: the instance, then each device (host s):\n");
    for row in &r.rows {
        let each: Vec<String> = row.times.each_device_s.iter().map(|t| format!("{t:.3}")).collect();
        let _ = writeln!(
            s,
            "- {} device(s): instance {:.3}, devices {}",
            row.devices,
            row.times.instance_s,
            each.join(", ")
        );
    }
    let _ = writeln!(s, "\nPipelines the slowest device made (host ms each, in the order made; the path tracer's while the build was recorded):\n");
    for row in &r.rows {
        let each: Vec<String> = row
            .times
            .pipelines
            .iter()
            .map(|(k, t)| format!("{k} {:.1}", t * 1e3))
            .collect();
        let _ = writeln!(s, "- {} device(s): {}", row.devices, each.join(", "));
    }
    s
}
