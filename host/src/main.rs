//! `raytrace`: the command-line front end.
use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use raytrace::bench::build::{bench_build, standard_inputs, write_report, BuildReport};
use raytrace::bench::slug;
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cli::{compare_command, render_command, SceneArgs};
use raytrace::gpu::{Gpu, GpuOptions, Kernel};
use raytrace::render::Backend;
use raytrace::view::ViewArgs;
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(
    name = "raytrace",
    version = concat!(env!("CARGO_PKG_VERSION"), " (", env!("RAYTRACE_COMMIT"), ")"),
    about = "GPU ray tracer with a BVH rebuilt on the GPU every frame"
)]
struct Cli {
    /// Vulkan device: index or part of its name (default: first discrete GPU; env RAYTRACE_DEVICE).
    #[arg(long, global = true)]
    device: Option<String>,
    /// Enable the Khronos validation layer (if installed).
    #[arg(long, global = true)]
    validation: bool,
    #[command(subcommand)]
    cmd: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to a PNG (sRGB) or EXR (linear) file.
    Render {
        #[command(flatten)]
        scene: SceneArgs,
        /// Where the kernels run: `auto` takes the GPU, unless every Vulkan device is a CPU
        /// implementation (lavapipe, SwiftShader) or there is none: then the CPU executor.
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// Output file, .png or .exr (default: SCENE.png).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Render on the CPU and the GPU with the same random streams; write CPU | GPU |
    /// difference and compare per-stage times and BVHs. Exits non-zero when they differ.
    Compare {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output PNG.
        #[arg(long, default_value = "compare.png")]
        out: PathBuf,
        /// Largest relative RMSE of the CPU image against the GPU's accepted as equal.
        #[arg(long, default_value_t = 0.05)]
        tolerance: f64,
    },
    /// Open a window on a scene and render it live: fly around, edit objects, switch
    /// features (keys below).
    View(ViewArgs),
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: Bench,
    },
    /// Every Vulkan device and the CPU executor with a rough speed, and the backend `render`
    /// picks (with --kernels: the chosen device and its kernels' statistics).
    Info {
        /// Also print the driver's statistics of every kernel (registers, spills...), where
        /// the driver offers VK_KHR_pipeline_executable_properties.
        #[arg(long)]
        kernels: bool,
    },
}

#[derive(Copy, Clone, ValueEnum)]
enum Bits {
    B30,
    B63,
}

#[derive(Subcommand)]
enum Bench {
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
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// Rays per second through each BVH layout (primary, diffuse, shadow rays), with build
    /// time, SAH and the real-time frame split into build and trace.
    Trace {
        #[command(flatten)]
        options: raytrace::bench::trace::Options,
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
        options: raytrace::bench::realtime::Options,
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
        #[arg(long, default_value = "800x800", value_parser = raytrace::cli::parse_size)]
        size: (u32, u32),
        /// Samples per pixel per frame.
        #[arg(long, default_value_t = 8)]
        spp: u32,
        /// Timed frames per kernel (after one warm-up).
        #[arg(long, default_value_t = 10)]
        runs: usize,
        #[arg(long, default_value = "bench/results")]
        out: PathBuf,
    },
    /// What accuracy costs in time: error against GPU time for spp, NEE, MIS, Russian
    /// roulette and depth; BVH quality (30/63-bit codes, brute force); intersection precision
    /// (watertight against Moller-Trumbore, robust against plain slabs). Markdown, JSON and
    /// PNG plots.
    Accuracy {
        #[command(flatten)]
        options: raytrace::bench::accuracy::Options,
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
    let md = raytrace::bench::write_files(out, &stem, &markdown, value)?;
    println!("{markdown}");
    println!("wrote {}", md.display());
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let kernel_stats = matches!(cli.cmd, Some(Command::Info { kernels: true }));
    let opts = GpuOptions {
        validation: cli.validation,
        device: cli.device.clone(),
        kernel_stats,
        ..Default::default()
    };
    let Some(cmd) = cli.cmd else {
        // No arguments: the viewer on the Cornell box where a display exists, else a PNG.
        let has_display = std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some();
        if has_display {
            let args = ViewArgs::parse_from(["view", "cornell"]);
            match raytrace::view::run(&args, &opts) {
                Ok(()) => return Ok(()),
                Err(e) => eprintln!("could not open the viewer ({e:#}); rendering to a file instead"),
            }
        }
        let args = SceneArgs::parse_from(["raytrace", "cornell"]);
        let out = render_command(&args, Backend::Auto, Some(PathBuf::from("cornell.png")), &opts)?;
        println!(
            "open {} to see it; `raytrace view` opens the interactive viewer where a display exists",
            out.display()
        );
        return Ok(());
    };
    match cmd {
        Command::Render { scene, backend, out } => {
            render_command(&scene, backend, out, &opts)?;
        }
        Command::Compare { scene, out, tolerance } => compare_command(&scene, &out, tolerance, &opts)?,
        Command::View(args) => raytrace::view::run(&args, &opts)?,
        Command::Bench {
            what:
                Bench::Features {
                    scenes,
                    size,
                    spp,
                    runs,
                    out,
                },
        } => {
            let gpu = Gpu::new(&opts)?;
            let r = raytrace::bench::features::run(&gpu, &scenes, size, spp.max(1), runs)?;
            publish(
                &out,
                "features",
                &r.date,
                &gpu,
                raytrace::bench::features::markdown(&r),
                &r,
            )?;
        }
        Command::Bench {
            what: Bench::Readme { readme, results },
        } => {
            let text = std::fs::read_to_string(&readme).with_context(|| format!("reading {}", readme.display()))?;
            let section = raytrace::bench::readme::section(&results)?;
            let new = raytrace::bench::readme::rewrite(&text, &section)
                .with_context(|| format!("rewriting {}", readme.display()))?;
            std::fs::write(&readme, new).with_context(|| format!("writing {}", readme.display()))?;
            println!("rewrote the performance section of {}", readme.display());
        }
        Command::Bench {
            what: Bench::Trace { options, out },
        } => {
            let gpu = Gpu::new(&opts)?;
            let r = raytrace::bench::trace::run(&gpu, &options)?;
            publish(&out, "trace", &r.date, &gpu, raytrace::bench::trace::markdown(&r), &r)?;
            let plot = raytrace::bench::trace::plot(&r, &out, &format!("trace-{}-{}", r.date, slug(&gpu.name)))?;
            println!("wrote {}", plot.display());
        }
        Command::Bench {
            what: Bench::Realtime { options, out },
        } => {
            let gpu = Gpu::new(&opts)?;
            let r = raytrace::bench::realtime::run(&gpu, &options)?;
            publish(
                &out,
                "realtime",
                &r.date,
                &gpu,
                raytrace::bench::realtime::markdown(&r),
                &r,
            )?;
        }
        Command::Bench {
            what: Bench::Accuracy { options, out },
        } => {
            let gpu = Gpu::new(&opts)?;
            let r = raytrace::bench::accuracy::run(&gpu, &options)?;
            let stem = format!("accuracy-{}-{}-{}", slug(&options.scene), r.date, slug(&gpu.name));
            let plots = raytrace::bench::accuracy::plots(&r, &out, &stem)?;
            let md = raytrace::bench::write_files(&out, &stem, &raytrace::bench::accuracy::markdown(&r, &plots), &r)?;
            println!("{}", raytrace::bench::accuracy::markdown(&r, &plots));
            println!("wrote {} and {} plots", md.display(), plots.len());
        }
        Command::Info { kernels } => {
            if !kernels {
                return raytrace::cli::info_command(&opts);
            }
            let gpu = Gpu::new(&opts)?;
            println!("{}", gpu.describe());
            let k = raytrace::gpu::Kernels::new(&gpu)?;
            let stats = k.statistics()?;
            if stats.is_empty() {
                println!("the driver offers no pipeline statistics");
            }
            for (entry, lines) in &stats {
                println!("{entry}: {}", lines.join(", "));
            }
            // What the renders run: the path tracer specialised to each scene's features.
            let scenes = if stats.is_empty() {
                &[][..]
            } else {
                &["cornell", "bunny"][..]
            };
            for scene in scenes {
                for nee in [false, true] {
                    let args = ["raytrace", scene, if nee { "--spp=1" } else { "--no-nee" }];
                    let p = <SceneArgs as clap::Parser>::parse_from(args).prepare()?;
                    let lines = k.specialised_statistics(Kernel::PathTrace, p.frame.features)?;
                    let nee = if nee { " (NEE)" } else { "" };
                    println!("path_trace for {scene}{nee}: {}", lines.join(", "));
                }
            }
        }
        Command::Bench {
            what:
                Bench::Table2 {
                    runs,
                    brute_spp,
                    cpu_spp,
                    no_treelets,
                    out,
                },
        } => {
            let gpu = Gpu::new(&opts)?;
            let report = raytrace::bench::table2::run(&gpu, runs, brute_spp.max(1), cpu_spp.max(1), !no_treelets)?;
            let md =
                raytrace::bench::table2::write(&report, &out, &format!("table2-{}-{}", report.date, slug(&gpu.name)))?;
            println!("{}", raytrace::bench::table2::markdown(&report));
            println!("wrote {}", md.display());
        }
        Command::Bench {
            what:
                Bench::Build {
                    runs,
                    warmup,
                    millions,
                    bits,
                    treelets,
                    out,
                },
        } => {
            let gpu = Gpu::new(&opts)?;
            let sizes: Vec<usize> = millions.iter().map(|m| (m * 1e6) as usize).collect();
            let inputs = standard_inputs(&sizes)?;
            let mut rows = Vec::new();
            for b in bits {
                let b = match b {
                    Bits::B30 => MortonBits::B30,
                    Bits::B63 => MortonBits::B63,
                };
                rows.extend(bench_build(&gpu, &inputs, BuildOptions::lbvh(b), runs, warmup)?);
                rows.extend(bench_build(&gpu, &inputs, BuildOptions::wide(b), runs, warmup)?);
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
            println!("{}", raytrace::bench::build::markdown(&report));
            println!("wrote {}", md.display());
        }
    }
    Ok(())
}
