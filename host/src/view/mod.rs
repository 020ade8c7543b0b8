//! `raytrace view`: a window presented through a Vulkan swapchain. Every frame, on the GPU and
//! in one submission: transform the objects, rebuild the BVH, trace samples into the float
//! accumulation image, run the display pass (or, while the image moves, the denoiser: SVGF,
//! Schied et al. 2017), copy its pixels into the swapchain image. The scene is live
//! ([`LiveScene`]): it animates, and keys add, move, rotate and remove objects.
//!
//! This file holds the entry point and its options; `window` the event loop and the frame,
//! `input` the key bindings and the actions they and `--script` take, `overlay` what the
//! viewer reports besides the picture (the title bar, the statistics `I` prints), `camera`
//! the fly camera, `live` the scene being edited ([`LiveScene`], which `bench realtime` and the
//! tests drive without a window).
mod camera;
mod input;
mod live;
mod overlay;
mod window;

pub use camera::FlyCamera;
pub use input::KEYS;
pub use live::LiveScene;

use crate::cli::SceneArgs;
use crate::gpu::{Gpu, GpuOptions, GpuRenderer, Kernels};
use anyhow::{anyhow, bail, Context, Result};
use raw_window_handle::HasDisplayHandle;
use std::ffi::CStr;
use std::path::PathBuf;
use std::sync::Arc;
use window::App;
use winit::event_loop::EventLoop;

/// `raytrace view` options.
#[derive(clap::Parser, Clone, Debug)]
#[command(after_help = KEYS)]
pub struct ViewArgs {
    /// Scene and settings; here `--spp` stops accumulating at that many samples per pixel
    /// (default: never; the frames after show the accumulation, not denoised) and `--time` is
    /// where the animation starts.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Samples per pixel traced each frame.
    #[arg(long, default_value_t = 1)]
    pub spf: u32,
    /// Present without waiting for the display's refresh (MAILBOX or IMMEDIATE).
    #[arg(long)]
    pub no_vsync: bool,
    /// Render this many frames (animation advancing 1/60 s each), then exit.
    #[arg(long)]
    pub frames: Option<u64>,
    /// With --frames: save the last presented frame (read back from the swapchain) here.
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// Start with the denoiser off (the L key switches it). By default (and with --denoise)
    /// every frame is denoised while the image moves, and a still image, once past 96 samples
    /// per pixel, shows the accumulation itself.
    #[arg(long, conflicts_with = "denoise")]
    pub no_denoise: bool,
    /// Actions at given frames, for tests and demos: `FRAME:ACTION,...` with ACTION one of
    /// add-sphere, add-mesh, pick=X;Y, remove=X;Y, move=DX;DY;DZ, rotate=DEG, resize=WxH,
    /// fly=RIGHT;UP;FORWARD (the camera, world units), minimize, restore, denoise=on|off, stats
    /// (what the I key prints), tracer=lbvh|driver (the T key).
    #[arg(long, value_delimiter = ',')]
    pub script: Vec<String>,
}

/// Runs the viewer until its window closes (or `--frames` frames are done).
pub fn run(args: &ViewArgs, opts: &GpuOptions) -> Result<()> {
    if args.spf == 0 {
        bail!("--spf must be at least 1");
    }
    if args.screenshot.is_some() && args.frames.is_none() {
        bail!("--screenshot needs --frames N (the P key saves screenshots interactively)");
    }
    let mut script = args
        .script
        .iter()
        .map(|s| input::parse_action(s))
        .collect::<Result<Vec<_>>>()?;
    script.sort_by_key(|(f, _)| *f);
    // The scene's frame as the viewer starts: with the denoiser's guides unless --no-denoise
    // (what --explain reports).
    let mut scene_args = args.scene.clone();
    scene_args.denoise = !args.no_denoise;
    let prepared = scene_args.prepare()?;
    let event_loop = EventLoop::new().context("opening the window system (is a display available?)")?;
    let display = event_loop
        .display_handle()
        .map_err(|e| anyhow!("no display handle: {e}"))?
        .as_raw();
    let exts =
        ash_window::enumerate_required_extensions(display).context("asking Vulkan which window extensions it needs")?;
    let mut opts = opts.clone();
    // Ray tracing where the device has it, so that the T key can switch tracers.
    opts.ray_tracing = true;
    // SAFETY: ash_window returns pointers to static, NUL-terminated extension names.
    opts.window_extensions = exts.iter().map(|&p| unsafe { CStr::from_ptr(p) }).collect();
    let gpu = Gpu::new(&opts)?;
    let kernels = Arc::new(Kernels::new(&gpu)?);
    let mut renderer = GpuRenderer::new(&gpu, &kernels)?;
    renderer.set_build(prepared.build(1));
    renderer.set_group_refits(prepared.group_refits);
    renderer.set_top_refits(prepared.top_refits);
    // `--accel auto` decides for the scene as it opens (the T key switches later).
    let (tracer, why) = prepared.tracer(&gpu);
    renderer.set_accel(tracer, prepared.driver_build)?;
    let mut live = LiveScene::with_instancing(prepared.scene, args.scene.instancing);
    live.bvh = !args.scene.no_bvh;
    live.time = args.scene.time;
    live.forced = crate::features::Forced::parse(&args.scene.features)?;
    if args.scene.explain {
        println!(
            "kernel features for {}:\n{}",
            live.scene.name,
            prepared.features.explain()
        );
        println!("rays traced by {tracer:?} ({why})");
    }
    App::new(args.clone(), script, gpu, renderer, live)?.run(event_loop)
}
