//! The viewer's window and event loop (winit): opening the window and its swapchain,
//! dispatching window and device events, and each frame's work: scripted actions, the
//! camera's flight, the denoiser's switch, then record, submit, present and wait (see
//! ARCHITECTURE.md, "The viewer").
use super::input::Action;
use super::overlay::Stats;
use super::LiveScene;
use super::{FlyCamera, ViewArgs};
use crate::gpu::{frame_timings, Buffer, Commands, Denoise, Gpu, GpuRenderer, Swapchain};
use crate::picture::{swap_red_blue, Picture};
use anyhow::{anyhow, bail, Context, Result};
use gpu_allocator::MemoryLocation;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use std::collections::HashSet;
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{DeviceEvent, DeviceId, ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

/// The viewer: its window and swapchain, the renderer and the live scene, and the state of
/// the input.
pub(super) struct App {
    pub(super) args: ViewArgs,
    pub(super) script: Vec<(u64, Action)>,
    pub(super) gpu: Arc<Gpu>,
    pub(super) cmds: Commands,
    pub(super) renderer: GpuRenderer,
    pub(super) live: LiveScene,
    pub(super) camera: FlyCamera,
    pub(super) window: Option<Window>,
    pub(super) swapchain: Option<Swapchain>,
    pub(super) minimised: bool,
    pub(super) keys: HashSet<KeyCode>,
    pub(super) looking: bool,
    pub(super) cursor: (f64, f64),
    pub(super) paused: bool,
    pub(super) spf: u32,
    /// Denoise every frame while the image moves ([`Denoise::EveryFrame`]), else show the
    /// accumulation ([`Denoise::Off`]).
    pub(super) denoise: bool,
    /// Frames begun (presented or not).
    pub(super) tick: u64,
    pub(super) last: Instant,
    pub(super) stats: Stats,
    pub(super) last_timings: Vec<(&'static str, f64)>,
    pub(super) shots: u32,
    /// Samples per pixel traced in the last frame.
    pub(super) traced: u32,
    pub(super) error: Option<anyhow::Error>,
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
    pub(super) fn new(
        args: ViewArgs,
        script: Vec<(u64, Action)>,
        gpu: Arc<Gpu>,
        renderer: GpuRenderer,
        live: LiveScene,
    ) -> Result<App> {
        let camera = FlyCamera::new(live.scene.camera);
        Ok(App {
            spf: args.spf,
            denoise: !args.no_denoise,
            args,
            script,
            cmds: Commands::new(&gpu)?,
            gpu,
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
            tick: 0,
            last: Instant::now(),
            stats: Stats::default(),
            last_timings: Vec::new(),
            shots: 0,
            traced: 0,
            error: None,
        })
    }

    /// Runs the event loop until the window closes (or `--frames` frames are done).
    pub(super) fn run(mut self, event_loop: EventLoop<()>) -> Result<()> {
        event_loop.set_control_flow(ControlFlow::Poll);
        event_loop
            .run_app(&mut self)
            .context("running the window's event loop")?;
        // Drop the swapchain (and its surface) before the window.
        self.swapchain = None;
        self.window = None;
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        let errors = self.gpu.validation_errors();
        if !errors.is_empty() {
            bail!("{} Vulkan validation errors (first: {})", errors.len(), errors[0]);
        }
        Ok(())
    }

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

    pub(super) fn resized(&mut self, size: PhysicalSize<u32>) -> Result<()> {
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
        // (A frame that traces nothing, --spp reached, shows the accumulation: `record`.)
        self.renderer.set_denoise(if self.denoise {
            Denoise::EveryFrame
        } else {
            Denoise::Off
        })?;
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
}
