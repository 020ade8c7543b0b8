//! The command line: `raytrace` and its subcommands, a file each where there is more than a
//! call to make. `render` renders a scene to a file, and holds what every command that opens
//! a scene shares: the scene options ([`SceneArgs`]), preparing the scene, rendering on
//! either backend with progress, the summary line. `compare` renders on both backends and
//! compares them, `info` lists the devices (and with `--kernels` the driver's statistics of
//! the kernels), `bench` runs the benchmarks of `crate::bench`; `view` is `crate::view`'s;
//! `merge` adds up the shards of a frame (`crate::shard`).
mod bench;
mod compare;
mod info;
mod render;
mod scene;

pub use compare::{compare, Comparison};
pub use render::{
    frame_path, open_devices_on, parse_devices, render_devices, render_devices_each, DevicesTimes, FrameRange,
    OpenDevices, RenderJob, Rendered, Work,
};
pub use scene::{parse_size, Bits, Pairs, Prepared, SceneArgs, Tree, Treelets};

use crate::gpu::GpuOptions;
use crate::render::{AccelChoice, Backend};
use crate::shard::Shard;
use crate::view::ViewArgs;
use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

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
        /// Output file, .png or .exr (default: SCENE.png; with --shard SCENE.shard-I-of-N.exr).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Render only shard I of N of the frame's samples (samples I*S/N up to (I+1)*S/N of
        /// --spp S), into an EXR of radiance sums that `raytrace merge` adds up with the
        /// other shards into the image one render makes. For render farms: docs/cluster.md.
        #[arg(long, value_name = "I/N")]
        shard: Option<Shard>,
        /// Render on several GPUs at once: `all`, or device indices or names separated by
        /// commas; each traces an equal share of the samples and their sums are added in
        /// device order.
        #[arg(long, value_name = "all|0,1,...")]
        devices: Option<String>,
        /// Render frames A up to B - 1 of the animation, frame k at time --time + k / --fps,
        /// each to --out with its last run of # replaced by the frame number (default
        /// SCENE-####.png).
        #[arg(long, value_name = "A..B")]
        frames: Option<FrameRange>,
        /// Frames per second of --frames.
        #[arg(long, default_value_t = 30.0)]
        fps: f32,
    },
    /// Add up the shards of one frame (`render --shard I/N`, each exactly once, any order) into
    /// the image a single render makes.
    Merge {
        /// Shard files (.exr).
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Output file, .png or .exr.
        #[arg(long)]
        out: PathBuf,
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
        what: bench::Bench,
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

/// Runs `raytrace` with the process's arguments. Without a subcommand: the viewer on the
/// Cornell box where a display exists, else the Cornell box rendered to `cornell.png`.
pub fn run() -> Result<()> {
    let cli = Cli::parse();
    let kernel_stats = matches!(cli.cmd, Some(Command::Info { kernels: true }));
    // The device opens with the driver's ray tracing only where a command may trace with it.
    let accel = match &cli.cmd {
        Some(Command::Render { scene, .. } | Command::Compare { scene, .. }) => scene.accel,
        Some(Command::View(args)) => args.scene.accel,
        Some(Command::Bench { what }) => what.accel(),
        _ => AccelChoice::Lbvh,
    };
    let opts = GpuOptions {
        validation: cli.validation,
        device: cli.device.clone(),
        kernel_stats,
        ray_tracing: accel != AccelChoice::Lbvh,
        ..Default::default()
    };
    let Some(cmd) = cli.cmd else {
        return first_run(&opts);
    };
    match cmd {
        Command::Render {
            scene,
            backend,
            out,
            shard,
            devices,
            frames,
            fps,
        } => {
            let job = RenderJob {
                backend,
                out,
                shard,
                devices: devices.as_deref(),
                frames,
                fps,
            };
            render::render_command(&scene, &job, &opts)?;
        }
        Command::Merge { shards, out } => {
            let picture = crate::shard::merge(&shards)?;
            picture.save(&out)?;
            println!(
                "merged {} shards: {}x{}, {} spp, mean luminance {:.4}",
                shards.len(),
                picture.width,
                picture.height,
                picture.samples,
                picture.mean_luminance()
            );
            println!("wrote {}", out.display());
        }
        Command::Compare { scene, out, tolerance } => compare::compare_command(&scene, &out, tolerance, &opts)?,
        Command::View(args) => crate::view::run(&args, &opts)?,
        Command::Bench { what } => bench::run(what, &opts)?,
        Command::Info { kernels: false } => info::info_command(&opts)?,
        Command::Info { kernels: true } => info::kernels_command(&opts)?,
    }
    Ok(())
}

/// `raytrace` without arguments: the viewer on the Cornell box where a display exists, else a
/// PNG.
fn first_run(opts: &GpuOptions) -> Result<()> {
    let has_display = std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some();
    if has_display {
        let args = ViewArgs::parse_from(["view", "cornell"]);
        match crate::view::run(&args, opts) {
            Ok(()) => return Ok(()),
            Err(e) => eprintln!("could not open the viewer ({e:#}); rendering to a file instead"),
        }
    }
    let args = SceneArgs::parse_from(["raytrace", "cornell"]);
    let out = render::render_command(&args, &RenderJob::to(Some(PathBuf::from("cornell.png"))), opts)?;
    println!(
        "open {} to see it; `raytrace view` opens the interactive viewer where a display exists",
        out.display()
    );
    Ok(())
}
