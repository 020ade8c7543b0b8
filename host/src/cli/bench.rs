//! `raytrace bench`: the benchmarks' options, and each run with its report written (Markdown
//! and JSON, with plots where the benchmark draws them) to the results folder.
use super::Bits;
use crate::bench::build::{bench_build, standard_inputs, write_report, BuildReport};
use crate::bench::{self, slug};
use crate::bvh::BuildOptions;
use crate::gpu::{Gpu, GpuOptions};
use crate::render::{Accel, AccelChoice};
use anyhow::{Context, Result};
use clap::Subcommand;
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub(super) enum Bench {
    /// The thesis's Tables 2 and 3 and Figure 3: Cornell, Suzanne and bunny at 800x800, 32 rays
    /// per pixel, depth 16, on the CPU, the GPU by brute force and the GPU with the BVH.
    Table2 {
        /// Timed frames per configuration (after warm-up).
        #[arg(long, default_value_t = 10)]
        runs: usize,
        /// Samples per pixel actually rendered by brute force (scaled to 32).
        #[arg(long, default_value_t = 1)]
        brute_spp: u32,
        /// Samples per pixel actually rendered by the CPU executor (scaled to 32).
        #[arg(long, default_value_t = 4)]
        cpu_spp: u32,
        /// Build the plain Karras tree (no treelet restructuring).
        #[arg(long)]
        no_treelets: bool,
        /// `driver`: also render every GPU frame through the driver's acceleration structures,
        /// beside the project's BVH (on devices with VK_KHR_ray_tracing_pipeline).
        #[arg(long, value_enum, default_value_t = Accel::Lbvh)]
        accel: Accel,
        /// How the driver builds its bottom levels (with `--accel driver`).
        #[arg(long, value_enum, default_value_t = crate::gpu::driver::DriverBuild::FastBuild)]
        driver_build: crate::gpu::driver::DriverBuild,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// Rays per second through each BVH layout (primary, diffuse, shadow rays), with build
    /// time, SAH and the real-time frame split into build and trace.
    Trace {
        #[command(flatten)]
        options: bench::trace::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// The project's tracer against the driver's acceleration structures (`--accel driver`)
    /// on the built-in scenes at real-time and thesis settings: build, trace, frame, rays per
    /// second, bytes; and builds alone over random triangles. Needs a device with ray-tracing
    /// pipelines.
    Peer {
        #[command(flatten)]
        options: bench::peer::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// Rewrites README.md's performance section from the newest H100 results in
    /// bench/results (run from the repository's root).
    Readme {
        #[arg(long, default_value = "README.md")]
        readme: PathBuf,
        #[arg(long, default_value = "bench/results")]
        results: PathBuf,
    },
    /// The viewer's per-frame GPU work without a window: frame-time percentiles.
    Realtime {
        #[command(flatten)]
        options: bench::realtime::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// Per built-in scene: the path tracer with every feature against the kernel specialised
    /// to the scene (same image, checked).
    Features {
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "cornell,suzanne,bunny,spheres,instances"
        )]
        scenes: Vec<String>,
        #[arg(long, default_value = "800x800", value_parser = super::parse_size)]
        size: (u32, u32),
        /// Samples per pixel per frame.
        #[arg(long, default_value_t = 8)]
        spp: u32,
        /// Timed frames per kernel (after one warm-up).
        #[arg(long, default_value_t = 10)]
        runs: usize,
        /// What traces the rays: the project's BVH, or the driver's acceleration structures
        /// (the ray-tracing pipeline specialised alike; devices with
        /// VK_KHR_ray_tracing_pipeline).
        #[arg(long, value_enum, default_value_t = Accel::Lbvh)]
        accel: Accel,
        /// How the driver builds its bottom levels (with `--accel driver`).
        #[arg(long, value_enum, default_value_t = crate::gpu::driver::DriverBuild::FastBuild)]
        driver_build: crate::gpu::driver::DriverBuild,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// What accuracy costs in time: error against GPU time for spp, NEE, MIS, Russian
    /// roulette and depth; BVH quality (30/63-bit codes, brute force); intersection precision
    /// (watertight against Moller-Trumbore, robust against plain slabs). Markdown, JSON and
    /// PNG plots.
    Accuracy {
        #[command(flatten)]
        options: bench::accuracy::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// The real-time denoiser's error against time: along a camera path of animated frames,
    /// relative MSE against per-frame references of raw 1 spp, denoised 1 spp and raw N spp,
    /// with GPU times at 1920x1080; a still view's frame-to-frame change (flicker) and the
    /// accumulated spp from which the raw accumulation beats the denoised image. Markdown,
    /// JSON and PNG plots.
    Denoise {
        #[command(flatten)]
        options: bench::denoise::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// One render split across the first 1, 2, ... of the host's devices (`render
    /// --devices`): wall and GPU time, speed-up, efficiency, agreement with one device.
    Devices {
        #[command(flatten)]
        options: bench::devices::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// Instancing's two levels: the meshes' builds, the top level rebuilt for moving
    /// instances, memory per instance and per distinct primitive, GPU = CPU.
    Levels {
        #[command(flatten)]
        options: bench::levels::Options,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// BVH build: per-stage GPU time, throughput, memory, CPU executor time.
    Build {
        /// Timed runs per input (after warm-up).
        #[arg(long, default_value_t = 50)]
        runs: usize,
        #[arg(long, default_value_t = 5)]
        warmup: usize,
        /// Sizes (millions of random triangles) to add to 37 prims, Suzanne and the bunny.
        #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
        millions: Vec<f64>,
        /// Morton code widths to run.
        #[arg(long, value_delimiter = ',', default_value = "b30,b63")]
        bits: Vec<Bits>,
        /// Also time builds that restructure treelets for surface-area cost.
        #[arg(long)]
        treelets: bool,
        /// Folder for the Markdown and JSON reports.
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
}

impl Bench {
    /// What the benchmark may trace with: the device opens with the driver's ray tracing
    /// where it may.
    pub(super) fn accel(&self) -> AccelChoice {
        match self {
            Bench::Peer { .. } => AccelChoice::Driver,
            Bench::Realtime { options, .. } => options.accel.into(),
            Bench::Trace { options, .. } => options.accel.into(),
            Bench::Devices { options, .. } => options.accel.into(),
            Bench::Accuracy { options, .. } => options.accel.into(),
            Bench::Table2 { accel, .. } | Bench::Features { accel, .. } => (*accel).into(),
            Bench::Readme { .. } | Bench::Denoise { .. } | Bench::Levels { .. } | Bench::Build { .. } => {
                AccelChoice::Lbvh
            }
        }
    }
}

/// The kind of a benchmark's result files: `base`, or `base-driver` for the driver's tracer.
fn results_kind(base: &str, accel: Accel) -> String {
    match accel {
        Accel::Lbvh => base.to_string(),
        Accel::Driver => format!("{base}-driver"),
    }
}

/// Writes a benchmark report as `out/KIND-DATE-GPU.md` and `.json`, and prints it.
fn publish(
    out: &Path,
    kind: &str,
    date: &str,
    gpu: &Gpu,
    markdown: String,
    value: &impl serde::Serialize,
) -> Result<()> {
    let stem = format!("{kind}-{date}-{}", slug(&gpu.name));
    let md = bench::write_files(out, &stem, &markdown, value)?;
    println!("{markdown}");
    println!("wrote {}", md.display());
    Ok(())
}

/// Runs the benchmark `what` on the GPU `opts` pick (`readme` only reads results).
pub(super) fn run(what: Bench, opts: &GpuOptions) -> Result<()> {
    match what {
        Bench::Levels { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::levels::run(&gpu, &options)?;
            let kind = format!("levels-{}", options.instances);
            publish(&out, &kind, &r.date, &gpu, bench::levels::markdown(&r), &r)?;
        }
        Bench::Features {
            scenes,
            size,
            spp,
            runs,
            accel,
            driver_build,
            out,
        } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::features::run(&gpu, &scenes, size, spp.max(1), runs, accel, driver_build)?;
            let kind = results_kind("features", accel);
            publish(&out, &kind, &r.date, &gpu, bench::features::markdown(&r), &r)?;
        }
        Bench::Readme { readme, results } => {
            let text = std::fs::read_to_string(&readme).with_context(|| format!("reading {}", readme.display()))?;
            let section = bench::readme::section(&results)?;
            let new =
                bench::readme::rewrite(&text, &section).with_context(|| format!("rewriting {}", readme.display()))?;
            std::fs::write(&readme, new).with_context(|| format!("writing {}", readme.display()))?;
            println!("rewrote the performance section of {}", readme.display());
        }
        Bench::Trace { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::trace::run(&gpu, &options)?;
            let kind = results_kind("trace", options.accel);
            publish(&out, &kind, &r.date, &gpu, bench::trace::markdown(&r), &r)?;
            let plot = bench::trace::plot(&r, &out, &format!("{kind}-{}-{}", r.date, slug(&gpu.name)))?;
            println!("wrote {}", plot.display());
        }
        Bench::Peer { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::peer::run(&gpu, &options)?;
            publish(&out, "peer", &r.date, &gpu, bench::peer::markdown(&r), &r)?;
            let plot = bench::peer::plot(&r, &out, &format!("peer-{}-{}", r.date, slug(&gpu.name)))?;
            println!("wrote {}", plot.display());
        }
        Bench::Realtime { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::realtime::run(&gpu, &options)?;
            let kind = results_kind("realtime", options.accel);
            publish(&out, &kind, &r.date, &gpu, bench::realtime::markdown(&r), &r)?;
        }
        Bench::Accuracy { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::accuracy::run(&gpu, &options)?;
            let stem = format!("accuracy-{}-{}-{}", slug(&options.scene), r.date, slug(&gpu.name));
            let plots = bench::accuracy::plots(&r, &out, &stem)?;
            let md = bench::write_files(&out, &stem, &bench::accuracy::markdown(&r, &plots), &r)?;
            println!("{}", bench::accuracy::markdown(&r, &plots));
            println!("wrote {} and {} plots", md.display(), plots.len());
        }
        Bench::Denoise { options, out } => {
            let gpu = Gpu::new(opts)?;
            let r = bench::denoise::run(&gpu, &options)?;
            let stem = bench::denoise::stem(&r, &gpu.name);
            let plots = bench::denoise::plots(&r, &out, &stem)?;
            let markdown = bench::denoise::markdown(&r, &plots);
            let md = bench::write_files(&out, &stem, &markdown, &r)?;
            println!("{markdown}");
            println!("wrote {} and {} plots", md.display(), plots.len());
        }
        Bench::Devices { options, out } => {
            let r = bench::devices::run(&options, opts)?;
            let first = r.rows.first().and_then(|row| row.times.names.first());
            let name = first.map_or("no-device".to_string(), |d| d.clone());
            let kind = results_kind("devices", options.accel);
            let stem = format!("{kind}-{}-{}", r.date, slug(&name));
            let markdown = bench::devices::markdown(&r);
            let md = bench::write_files(&out, &stem, &markdown, &r)?;
            println!("{markdown}");
            println!("wrote {}", md.display());
        }
        Bench::Table2 {
            runs,
            brute_spp,
            cpu_spp,
            no_treelets,
            accel,
            driver_build,
            out,
        } => {
            let gpu = Gpu::new(opts)?;
            let driver = (accel == Accel::Driver).then_some(driver_build);
            let report = bench::table2::run(&gpu, runs, brute_spp.max(1), cpu_spp.max(1), !no_treelets, driver)?;
            let md = bench::table2::write(&report, &out, &format!("table2-{}-{}", report.date, slug(&gpu.name)))?;
            println!("{}", bench::table2::markdown(&report));
            println!("wrote {}", md.display());
        }
        Bench::Build {
            runs,
            warmup,
            millions,
            bits,
            treelets,
            out,
        } => {
            let gpu = Gpu::new(opts)?;
            let sizes: Vec<usize> = millions.iter().map(|m| (m * 1e6) as usize).collect();
            let inputs = standard_inputs(&sizes)?;
            let mut rows = Vec::new();
            for b in bits {
                let b = b.into();
                rows.extend(bench_build(&gpu, &inputs, BuildOptions::lbvh(b), runs, warmup)?);
                rows.extend(bench_build(&gpu, &inputs, BuildOptions::wide(b), runs, warmup)?);
                let ploc = BuildOptions {
                    ploc: true,
                    ..BuildOptions::lbvh(b)
                };
                rows.extend(bench_build(&gpu, &inputs, ploc, runs, warmup)?);
                if treelets {
                    let opts = BuildOptions {
                        treelets: true,
                        ..BuildOptions::lbvh(b)
                    };
                    rows.extend(bench_build(&gpu, &inputs, opts, runs, warmup)?);
                }
            }
            let date = chrono::Local::now().format("%Y-%m-%d").to_string();
            let report = BuildReport {
                date: date.clone(),
                device: gpu.describe(),
                command: std::env::args().collect::<Vec<_>>().join(" "),
                rows,
            };
            let md = write_report(&report, &out, &format!("build-{date}-{}", slug(&gpu.name)))?;
            println!("{}", bench::build::markdown(&report));
            println!("wrote {}", md.display());
        }
    }
    Ok(())
}
