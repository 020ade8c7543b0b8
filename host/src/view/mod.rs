//! `raytrace view`: a window presented through a Vulkan swapchain. Every frame, on the GPU and
//! in one submission: transform the objects, rebuild the BVH, trace samples into the float
//! accumulation image, run the display pass, copy its pixels into the swapchain image. The
//! scene is live ([`LiveScene`]): it animates, and keys add, move, rotate and remove objects.
mod camera;

pub use camera::FlyCamera;

use crate::cli::SceneArgs;
use crate::live::LiveScene;
use crate::picture::{swap_red_blue, Picture};
use crate::render::{frame_timings, stage_totals, GpuRenderer};
use crate::scene::Shape;
use crate::vk::{Buffer, Commands, Gpu, GpuOptions, Kernels, Swapchain};
use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use std::collections::HashSet;
use std::ffi::CStr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{DeviceEvent, DeviceId, ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

/// The key bindings, as `raytrace view --help` and the `H` key print them.
pub const KEYS: &str = "\
Keys and mouse:
  W A S D / Q E      fly forward, left, back, right / down, up (Shift: 4x faster)
  right mouse drag   look around          mouse wheel   flying speed
  Z / X              narrower / wider field of view     R   reset the camera
  left click         select the object under the cursor
  Delete             remove the object under the cursor
  F / G              add a sphere / a mesh of the scene in front of the camera
  arrows, PgUp PgDn  move the selected object (camera-relative; up, down)
  , / .              rotate the selected object about y
  Space              pause or resume the animation
  1 / 2              halve / double the samples per pixel per frame
  3 / 4              lower / raise the maximum depth
  N                  next-event estimation on / off
  B                  BVH on / off (off: brute force, the thesis's comparison)
  V                  vsync on / off
  I                  print backend statistics (device, primitives, BVH, stage times, rays/s)
  P                  save a screenshot (PNG) of the converged image
  H                  print these keys      Esc   quit";

/// `raytrace view` options.
#[derive(clap::Parser, Clone, Debug)]
#[command(after_help = KEYS)]
pub struct ViewArgs {
    /// Scene and settings; here `--spp` stops accumulating at that many samples per pixel
    /// (default: never) and `--time` is where the animation starts.
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
    /// Actions at given frames, for tests and demos: `FRAME:ACTION,...` with ACTION one of
    /// add-sphere, add-mesh, pick=X;Y, remove=X;Y, move=DX;DY;DZ, rotate=DEG, resize=WxH,
    /// minimize, restore.
    #[arg(long, value_delimiter = ',')]
    pub script: Vec<String>,
}

/// A scripted action (see `ViewArgs::script`).
#[derive(Clone, Debug, PartialEq)]
enum Action {
    AddSphere,
    AddMesh,
    Pick(f32, f32),
    Remove(f32, f32),
    Move(Vec3),
    Rotate(f32),
    Resize(u32, u32),
    Minimize,
    Restore,
}

fn parse_action(s: &str) -> Result<(u64, Action)> {
    let (frame, act) = s
        .split_once(':')
        .with_context(|| format!("script step {s:?} is not FRAME:ACTION"))?;
    let frame = frame
        .trim()
        .parse::<u64>()
        .with_context(|| format!("script step {s:?}: bad frame number"))?;
    let (name, arg) = act.split_once('=').unwrap_or((act, ""));
    let nums = |n: usize| -> Result<Vec<f32>> {
        let v: Vec<f32> = arg
            .split([';', 'x'])
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("script step {s:?}: bad numbers {arg:?}"))?;
        if v.len() != n || v.iter().any(|x| !x.is_finite()) {
            bail!("script step {s:?}: expected {n} finite numbers, got {arg:?}");
        }
        Ok(v)
    };
    let a = match name.trim() {
        "add-sphere" => Action::AddSphere,
        "add-mesh" => Action::AddMesh,
        "pick" => nums(2).map(|v| Action::Pick(v[0], v[1]))?,
        "remove" => nums(2).map(|v| Action::Remove(v[0], v[1]))?,
        "move" => nums(3).map(|v| Action::Move(Vec3::new(v[0], v[1], v[2])))?,
        "rotate" => nums(1).map(|v| Action::Rotate(v[0]))?,
        "resize" => nums(2).map(|v| Action::Resize(v[0] as u32, v[1] as u32))?,
        "minimize" => Action::Minimize,
        "restore" => Action::Restore,
        other => bail!("script step {s:?}: unknown action {other:?}"),
    };
    Ok((frame, a))
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
        .map(|s| parse_action(s))
        .collect::<Result<Vec<_>>>()?;
    script.sort_by_key(|(f, _)| *f);
    let prepared = args.scene.prepare()?;
    let event_loop = EventLoop::new().context("opening the window system (is a display available?)")?;
    let display = event_loop
        .display_handle()
        .map_err(|e| anyhow!("no display handle: {e}"))?
        .as_raw();
    let exts =
        ash_window::enumerate_required_extensions(display).context("asking Vulkan which window extensions it needs")?;
    let mut opts = opts.clone();
    // SAFETY: ash_window returns pointers to static, NUL-terminated extension names.
    opts.window_extensions = exts.iter().map(|&p| unsafe { CStr::from_ptr(p) }).collect();
    let gpu = Gpu::new(&opts)?;
    let kernels = Arc::new(Kernels::new(&gpu)?);
    let mut renderer = GpuRenderer::new(&gpu, &kernels)?;
    renderer.set_build(prepared.build(1));
    let mut live = LiveScene::new(prepared.scene);
    live.bvh = !args.scene.no_bvh;
    live.time = args.scene.time;
    live.forced = crate::features::Forced::parse(&args.scene.features)?;
    if args.scene.explain {
        println!(
            "kernel features for {}:\n{}",
            live.scene.name,
            prepared.features.explain()
        );
    }
    let camera = FlyCamera::new(live.scene.camera);
    let mut app = App {
        args: args.clone(),
        script,
        gpu: gpu.clone(),
        cmds: Commands::new(&gpu)?,
        renderer,
        live,
        camera,
        window: None,
        swapchain: None,
        minimised: false,
        keys: HashSet::new(),
        looking: false,
        cursor: (0.0, 0.0),
        paused: false,
        spf: args.spf,
        tick: 0,
        last: Instant::now(),
        stats: Stats::default(),
        last_timings: Vec::new(),
        shots: 0,
        traced: 0,
        error: None,
    };
    event_loop.set_control_flow(ControlFlow::Poll);
    event_loop
        .run_app(&mut app)
        .context("running the window's event loop")?;
    // Drop the swapchain (and its surface) before the window.
    app.swapchain = None;
    app.window = None;
    if let Some(e) = app.error {
        return Err(e);
    }
    let errors = gpu.validation_errors();
    if !errors.is_empty() {
        bail!("{} Vulkan validation errors (first: {})", errors.len(), errors[0]);
    }
    Ok(())
}

/// Frame statistics since the title was last updated.
#[derive(Default)]
struct Stats {
    since: Option<Instant>,
    frames: u32,
    stages: Vec<(&'static str, f64)>,
}

struct App {
    args: ViewArgs,
    script: Vec<(u64, Action)>,
    gpu: Arc<Gpu>,
    cmds: Commands,
    renderer: GpuRenderer,
    live: LiveScene,
    camera: FlyCamera,
    window: Option<Window>,
    swapchain: Option<Swapchain>,
    minimised: bool,
    keys: HashSet<KeyCode>,
    looking: bool,
    cursor: (f64, f64),
    paused: bool,
    spf: u32,
    /// Frames begun (presented or not).
    tick: u64,
    last: Instant,
    stats: Stats,
    last_timings: Vec<(&'static str, f64)>,
    shots: u32,
    /// Samples per pixel traced in the last frame.
    traced: u32,
    error: Option<anyhow::Error>,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        if let Err(e) = self.open_window(el) {
            self.fail(el, e);
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let r = match event {
            WindowEvent::CloseRequested => {
                el.exit();
                Ok(())
            }
            WindowEvent::Resized(size) => self.resized(size),
            WindowEvent::RedrawRequested => self.redraw(el),
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    if event.state == ElementState::Pressed {
                        self.keys.insert(code);
                        if !event.repeat {
                            self.key(el, code)
                        } else {
                            Ok(())
                        }
                    } else {
                        self.keys.remove(&code);
                        Ok(())
                    }
                } else {
                    Ok(())
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                Ok(())
            }
            WindowEvent::MouseInput { state, button, .. } => match button {
                MouseButton::Right => {
                    self.looking = state == ElementState::Pressed;
                    Ok(())
                }
                MouseButton::Left if state == ElementState::Pressed => {
                    let (x, y) = self.cursor;
                    self.select(x as f32, y as f32)
                }
                _ => Ok(()),
            },
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.camera.speed *= 1.25f32.powf(steps);
                Ok(())
            }
            _ => Ok(()),
        };
        if let Err(e) = r {
            self.fail(el, e);
        }
    }

    fn device_event(&mut self, _el: &ActiveEventLoop, _id: DeviceId, event: DeviceEvent) {
        if let DeviceEvent::MouseMotion { delta } = event {
            if self.looking {
                self.camera.turn(delta.0 as f32 * 0.003, -delta.1 as f32 * 0.003);
            }
        }
    }

    fn about_to_wait(&mut self, _el: &ActiveEventLoop) {
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }
}

impl App {
    fn fail(&mut self, el: &ActiveEventLoop, e: anyhow::Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        el.exit();
    }

    fn open_window(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let s = &self.live.scene.settings;
        let attrs = Window::default_attributes()
            .with_title(format!("raytrace · {}", self.live.scene.name))
            .with_inner_size(PhysicalSize::new(s.width, s.height));
        let window = el.create_window(attrs).context("creating the window")?;
        let size = window.inner_size();
        let display = window.display_handle().map_err(|e| anyhow!("{e}"))?.as_raw();
        let handle = window.window_handle().map_err(|e| anyhow!("{e}"))?.as_raw();
        let swapchain = Swapchain::new(
            &self.gpu,
            display,
            handle,
            (size.width, size.height),
            !self.args.no_vsync,
        )?;
        self.renderer.set_bgra(swapchain.bgra);
        self.swapchain = Some(swapchain);
        self.window = Some(window);
        println!(
            "{} on {}: {} (H prints the keys)",
            self.live.scene.name,
            self.gpu.describe(),
            if self.args.frames.is_some() {
                "scripted run"
            } else {
                "interactive"
            }
        );
        self.last = Instant::now();
        Ok(())
    }

    fn resized(&mut self, size: PhysicalSize<u32>) -> Result<()> {
        self.minimised = size.width == 0 || size.height == 0;
        if let Some(sc) = self.swapchain.as_mut() {
            sc.resize((size.width, size.height))?;
            self.renderer.set_bgra(sc.bgra);
        }
        Ok(())
    }

    fn redraw(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let now = Instant::now();
        let dt = if self.args.frames.is_some() {
            1.0 / 60.0
        } else {
            (now - self.last).as_secs_f32().min(0.25)
        };
        self.last = now;
        while self.script.first().is_some_and(|(f, _)| *f <= self.tick) {
            let (_, a) = self.script.remove(0);
            self.act(&a)?;
        }
        self.tick += 1;
        self.fly(dt);
        if !self.paused {
            self.live.time += dt;
        }
        let last_frame = self.args.frames.is_some_and(|n| self.tick >= n);
        let presented = self.draw(last_frame)?;
        if last_frame {
            if self.args.screenshot.is_some() && presented.is_none() {
                bail!("nothing was presented in the last frame (window minimised?): no screenshot");
            }
            if let (Some(path), Some(pixels)) = (self.args.screenshot.clone(), presented) {
                pixels.save(&path)?;
                println!("wrote {} ({} frames)", path.display(), self.tick);
            }
            el.exit();
        }
        Ok(())
    }

    /// Moves the camera by the held keys.
    fn fly(&mut self, dt: f32) {
        let k = |c| if self.keys.contains(&c) { 1.0 } else { 0.0 };
        let dir = Vec3::new(
            k(KeyCode::KeyD) - k(KeyCode::KeyA),
            k(KeyCode::KeyE) - k(KeyCode::KeyQ),
            k(KeyCode::KeyW) - k(KeyCode::KeyS),
        );
        let fast = if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) {
            4.0
        } else {
            1.0
        };
        self.camera.fly(dir * self.camera.speed * fast * dt);
    }

    /// Renders and presents one frame; returns the presented image when `read` (and the
    /// swapchain can be read back).
    fn draw(&mut self, read: bool) -> Result<Option<Picture>> {
        let Some(sc) = self.swapchain.as_mut() else {
            return Ok(None);
        };
        if self.minimised {
            std::thread::sleep(Duration::from_millis(10));
            return Ok(None);
        }
        if sc.stale {
            let size = self.window.as_ref().map(|w| w.inner_size()).unwrap_or_default();
            sc.resize((size.width, size.height))?;
            self.renderer.set_bgra(sc.bgra);
        }
        if sc.extent.width == 0 {
            std::thread::sleep(Duration::from_millis(10));
            return Ok(None);
        }
        let s = &mut self.live.scene.settings;
        (s.width, s.height) = (sc.extent.width, sc.extent.height);
        self.live.scene.camera = self.camera.spec();
        self.live.sync(&mut self.renderer)?;
        let Some((index, acquired)) = sc.acquire()? else {
            return Ok(None);
        };
        let (w, h) = (sc.extent.width, sc.extent.height);
        let readback = if read && sc.readable {
            Some(Buffer::new(
                &self.gpu,
                "screenshot",
                (w * h * 4) as u64,
                MemoryLocation::GpuToCpu,
            )?)
        } else {
            None
        };
        // With --spp, accumulation stops there; the BVH is still rebuilt every frame.
        let samples = match self.args.scene.spp {
            Some(cap) => self.spf.min(cap.saturating_sub(self.renderer.samples())),
            None => self.spf,
        };
        self.cmds.begin()?;
        self.renderer.record(&mut self.cmds, samples, true)?;
        self.traced = samples;
        sc.record_copy(&self.cmds, self.renderer.display_buffer()?, index, readback.as_ref());
        self.cmds.submit(&[acquired], &[sc.presentable(index)])?;
        let presented = sc.present(index);
        self.cmds.wait()?;
        presented?;
        let bgra = sc.bgra;
        self.last_timings = frame_timings(&self.cmds)?;
        self.count_frame()?;
        if !read {
            return Ok(None);
        }
        let pixels = match readback {
            Some(rb) => {
                let mut p: Vec<u32> = rb.read((w * h) as usize)?;
                if bgra {
                    p.iter_mut().for_each(|v| *v = swap_red_blue(*v));
                }
                p
            }
            None => self.renderer.picture()?.display,
        };
        Ok(Some(Picture {
            width: w,
            height: h,
            display: pixels,
            ..Picture::default()
        }))
    }

    fn count_frame(&mut self) -> Result<()> {
        let st = &mut self.stats;
        let since = *st.since.get_or_insert_with(Instant::now);
        st.frames += 1;
        for &(label, t) in &stage_totals(&self.last_timings) {
            match st.stages.iter_mut().find(|(l, _)| *l == label) {
                Some(e) => e.1 += t,
                None => st.stages.push((label, t)),
            }
        }
        let elapsed = since.elapsed().as_secs_f64();
        if elapsed < 0.5 {
            return Ok(());
        }
        let n = st.frames as f64;
        let gpu: f64 = st.stages.iter().map(|(_, t)| t).sum::<f64>() / n;
        let stage = |name: &str| st.stages.iter().find(|(l, _)| *l == name).map_or(0.0, |(_, t)| t / n);
        let (transform, trace, display) = (stage("transform"), stage("trace"), stage("display"));
        let build = gpu - transform - trace - display;
        // Twice a second: one read of the accumulation image's ray counts.
        let rays = self.renderer.rays_per_sample()? * self.traced as f64;
        let title = format!(
            "raytrace · {} · {:.1} fps · GPU {:.2} ms (transform {:.2}, build {:.2}, trace {:.2}, display {:.2}) · {:.2} Grays/s · {} spp/frame, {} spp · depth {} · NEE {} · BVH {}{}",
            self.live.scene.name,
            n / elapsed,
            gpu * 1e3,
            transform * 1e3,
            build * 1e3,
            trace * 1e3,
            display * 1e3,
            rays / trace.max(1e-9) * 1e-9,
            self.spf,
            self.renderer.samples(),
            self.live.scene.settings.max_depth,
            on(self.live.scene.settings.nee),
            on(self.live.bvh),
            if self.paused { " · paused" } else { "" },
        );
        if let Some(w) = &self.window {
            w.set_title(&title);
        }
        self.stats = Stats::default();
        Ok(())
    }

    fn key(&mut self, el: &ActiveEventLoop, code: KeyCode) -> Result<()> {
        let s = &mut self.live.scene.settings;
        match code {
            KeyCode::Escape => el.exit(),
            KeyCode::KeyH => println!("{KEYS}"),
            KeyCode::KeyR => self.camera.reset(),
            KeyCode::KeyZ => self.camera.zoom(-5.0),
            KeyCode::KeyX => self.camera.zoom(5.0),
            KeyCode::Space => self.paused = !self.paused,
            KeyCode::Digit1 => self.spf = (self.spf / 2).max(1),
            KeyCode::Digit2 => self.spf = (self.spf * 2).min(64),
            KeyCode::Digit3 => s.max_depth = (s.max_depth - 1).max(1),
            KeyCode::Digit4 => s.max_depth = (s.max_depth + 1).min(64),
            KeyCode::KeyN => s.nee = !s.nee,
            KeyCode::KeyB => self.live.bvh = !self.live.bvh,
            KeyCode::KeyV => {
                if let Some(sc) = self.swapchain.as_mut() {
                    sc.vsync = !sc.vsync;
                    sc.stale = true;
                    println!("vsync {}", on(sc.vsync));
                }
            }
            KeyCode::KeyI => self.print_statistics()?,
            KeyCode::KeyP => self.screenshot()?,
            KeyCode::KeyF => self.act(&Action::AddSphere)?,
            KeyCode::KeyG => self.act(&Action::AddMesh)?,
            KeyCode::Delete | KeyCode::Backspace => {
                let (x, y) = self.cursor;
                self.act(&Action::Remove(x as f32, y as f32))?
            }
            KeyCode::ArrowLeft | KeyCode::ArrowRight | KeyCode::ArrowUp | KeyCode::ArrowDown => {
                let step = 0.1 * self.camera.speed;
                let fwd = self.camera.forward();
                let fwd = Vec3::new(fwd.x, 0.0, fwd.z).normalize_or(Vec3::NEG_Z);
                let right = fwd.cross(Vec3::Y);
                let d = match code {
                    KeyCode::ArrowLeft => -right,
                    KeyCode::ArrowRight => right,
                    KeyCode::ArrowUp => fwd,
                    _ => -fwd,
                };
                self.act(&Action::Move(d * step))?
            }
            KeyCode::PageUp => self.act(&Action::Move(Vec3::Y * 0.1 * self.camera.speed))?,
            KeyCode::PageDown => self.act(&Action::Move(Vec3::NEG_Y * 0.1 * self.camera.speed))?,
            KeyCode::Comma => self.act(&Action::Rotate(-15.0))?,
            KeyCode::Period => self.act(&Action::Rotate(15.0))?,
            _ => {}
        }
        Ok(())
    }

    /// Carries out an edit or window action. Edits that cannot be done (nothing under the
    /// cursor, the last object, nothing selected) are reported and change nothing; only
    /// device failures are errors.
    fn act(&mut self, a: &Action) -> Result<()> {
        match *a {
            Action::AddSphere | Action::AddMesh => self.add(a == &Action::AddMesh)?,
            Action::Pick(x, y) => self.select(x, y)?,
            Action::Remove(x, y) => self.remove_at(x, y)?,
            Action::Move(d) => self.edit_selected(|l, i| l.translate(i, d)),
            Action::Rotate(deg) => self.edit_selected(|l, i| l.rotate(i, Vec3::new(0.0, deg, 0.0))),
            Action::Resize(w, h) => {
                if let Some(win) = &self.window {
                    let _ = win.request_inner_size(PhysicalSize::new(w, h));
                }
            }
            Action::Minimize => self.resized(PhysicalSize::new(0, 0))?,
            Action::Restore => {
                let size = self.window.as_ref().map(|w| w.inner_size()).unwrap_or_default();
                self.resized(size)?
            }
        }
        Ok(())
    }

    fn edit_selected(&mut self, f: impl FnOnce(&mut LiveScene, usize) -> Result<()>) {
        match self.live.selected {
            None => eprintln!("no object selected (left-click one first)"),
            Some(i) => {
                if let Err(e) = f(&mut self.live, i) {
                    eprintln!("{e:#}");
                }
            }
        }
    }

    /// The object under pixel (`x`, `y`) of the last frame.
    fn picked(&mut self, x: f32, y: f32) -> Result<Option<(usize, f32)>> {
        if self.renderer.samples() == 0 {
            return Ok(None); // nothing rendered yet, or the scene just changed
        }
        self.live.pick(&mut self.renderer, x, y)
    }

    fn select(&mut self, x: f32, y: f32) -> Result<()> {
        match self.picked(x, y)? {
            Some((i, _)) => {
                self.live.selected = Some(i);
                println!("selected {}", self.live.scene.objects[i].name);
            }
            None => {
                self.live.selected = None;
                println!("nothing there: selection cleared");
            }
        }
        Ok(())
    }

    fn remove_at(&mut self, x: f32, y: f32) -> Result<()> {
        match self.picked(x, y)? {
            None => eprintln!("no object under pixel ({x}, {y}) to remove"),
            Some((i, _)) => match self.live.remove(i) {
                Ok(o) => println!("removed {}", o.name),
                Err(e) => eprintln!("{e:#}"),
            },
        }
        Ok(())
    }

    /// Adds a sphere or (`mesh`) the next mesh of the scene in front of the camera, 70% of
    /// the way to what the centre of the view sees.
    fn add(&mut self, mesh: bool) -> Result<()> {
        let f = *self.renderer.frame();
        let (cx, cy) = (f.width as f32 / 2.0, f.height as f32 / 2.0);
        let fwd = self.camera.forward();
        let spec = self.camera.spec();
        let dist = 0.7
            * match self.picked(cx, cy)? {
                Some((_, t)) => t,
                None => (spec.look_at - spec.position).length(),
            };
        let at = spec.position + fwd * dist;
        let radius = 0.08 * dist;
        let added = if mesh {
            let n = self.live.scene.meshes.len();
            let used = self
                .live
                .scene
                .objects
                .iter()
                .filter(|o| matches!(o.shape, Shape::Mesh(_)))
                .count();
            if n == 0 {
                Err(anyhow!("the scene has no meshes to add"))
            } else {
                self.live.add_mesh(used % n, at, radius)
            }
        } else {
            Ok(self.live.add_sphere(at, radius))
        };
        match added {
            Ok(i) => {
                self.live.selected = Some(i);
                println!("new object {} (selected)", self.live.scene.objects[i].name);
            }
            Err(e) => eprintln!("{e:#}"),
        }
        Ok(())
    }

    fn print_statistics(&mut self) -> Result<()> {
        let f = *self.renderer.frame();
        let d = self.live.data();
        println!("device: {}", self.gpu.describe());
        println!(
            "scene {}: {} objects, {} triangles, {} spheres, {} emissive primitives; {}x{}, {} spp accumulated",
            self.live.scene.name,
            self.live.scene.objects.len(),
            d.model_tris.len(),
            d.model_spheres.len(),
            d.lights.len(),
            f.width,
            f.height,
            self.renderer.samples()
        );
        for (label, t) in stage_totals(&self.last_timings) {
            println!("  {label:<10} {:8.3} ms", t * 1e3);
        }
        let bvh = self.renderer.bvh()?;
        let (tris, spheres) = self.renderer.world()?;
        match crate::validate::validate(&bvh.nodes, &bvh.parents, &tris, &spheres) {
            Ok(s) => println!("BVH valid: {s:?}"),
            Err(e) => println!("BVH INVALID: {e}"),
        }
        let trace_ms = crate::render::stage_ms(&self.last_timings, "trace");
        let rays = self.renderer.rays_per_sample()? * self.traced as f64;
        println!(
            "last frame: {:.0} rays in {trace_ms:.3} ms of tracing = {:.2} Grays/s",
            rays,
            rays / trace_ms.max(1e-6) * 1e-6
        );
        Ok(())
    }

    fn screenshot(&mut self) -> Result<()> {
        self.shots += 1;
        let path = PathBuf::from(format!("{}-{}.png", self.live.scene.name, self.shots));
        let p = self.renderer.picture()?;
        p.save(&path)?;
        println!("wrote {} ({} spp)", path.display(), p.samples);
        Ok(())
    }
}

fn on(b: bool) -> &'static str {
    if b {
        "on"
    } else {
        "off"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_steps_parse_and_bad_ones_are_named() {
        assert_eq!(parse_action("3:add-sphere").unwrap(), (3, Action::AddSphere));
        assert_eq!(parse_action("7:remove=10;20").unwrap(), (7, Action::Remove(10.0, 20.0)));
        assert_eq!(parse_action("1:resize=64x48").unwrap(), (1, Action::Resize(64, 48)));
        assert_eq!(
            parse_action("2:move=1;0;-1").unwrap(),
            (2, Action::Move(Vec3::new(1.0, 0.0, -1.0)))
        );
        for bad in ["x:add-sphere", "3:fly", "3:remove=1", "3:move=a;b;c", "add-sphere"] {
            let e = parse_action(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }
}
