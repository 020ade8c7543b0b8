//! The viewer's input: the key bindings ([`KEYS`]) and what each key does, the flight by
//! held keys, and the edits, camera moves, switches and window actions that keys, the mouse
//! and `--script` (parsed by [`parse_action`]) share ([`Action`]).
use super::overlay::on;
use super::window::App;
use super::LiveScene;
use crate::scene::Shape;
use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use std::path::PathBuf;
use winit::dpi::PhysicalSize;
use winit::event_loop::ActiveEventLoop;
use winit::keyboard::KeyCode;

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
  T                  trace with the project's BVH / the driver's acceleration structures
                     (where the device has ray-tracing pipelines)
  V                  vsync on / off
  L                  denoiser on / off (on: denoised while the image moves, raw once still
                     past 96 samples per pixel)
  I                  print backend statistics (device, primitives, BVH, stage times, rays/s)
  P                  save a screenshot (PNG) of the converged image
  H                  print these keys      Esc   quit";

/// A scripted action (see `ViewArgs::script`).
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Action {
    AddSphere,
    AddMesh,
    Pick(f32, f32),
    Remove(f32, f32),
    Move(Vec3),
    Rotate(f32),
    Resize(u32, u32),
    /// Moves the camera along its (right, up, forward) axes.
    Fly(Vec3),
    Minimize,
    Restore,
    /// Denoiser on or off.
    Denoise(bool),
    /// What the I key prints.
    Stats,
    /// What traces the rays (`--accel`).
    Tracer(crate::render::Accel),
}

pub(super) fn parse_action(s: &str) -> Result<(u64, Action)> {
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
        "fly" => nums(3).map(|v| Action::Fly(Vec3::new(v[0], v[1], v[2])))?,
        "minimize" => Action::Minimize,
        "restore" => Action::Restore,
        "denoise" => Action::Denoise(switch(s, arg)?),
        "stats" => Action::Stats,
        "tracer" => Action::Tracer(match arg {
            "lbvh" => crate::render::Accel::Lbvh,
            "driver" => crate::render::Accel::Driver,
            _ => bail!("script step {s:?}: tracer=lbvh or tracer=driver"),
        }),
        other => bail!("script step {s:?}: unknown action {other:?}"),
    };
    Ok((frame, a))
}

/// `on` or `off` in script step `step`.
fn switch(step: &str, arg: &str) -> Result<bool> {
    match arg.trim() {
        "on" => Ok(true),
        "off" => Ok(false),
        other => bail!("script step {step:?}: expected on or off, got {other:?}"),
    }
}

impl App {
    /// Moves the camera by the held keys.
    pub(super) fn fly(&mut self, dt: f32) {
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

    pub(super) fn key(&mut self, el: &ActiveEventLoop, code: KeyCode) -> Result<()> {
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
            KeyCode::KeyL => self.act(&Action::Denoise(!self.denoise))?,
            KeyCode::KeyT => {
                use crate::render::Accel;
                let next = match self.renderer.accel() {
                    Accel::Lbvh => Accel::Driver,
                    Accel::Driver => Accel::Lbvh,
                };
                self.act(&Action::Tracer(next))?;
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
    pub(super) fn act(&mut self, a: &Action) -> Result<()> {
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
            Action::Fly(d) => self.camera.fly(d),
            Action::Minimize => self.resized(PhysicalSize::new(0, 0))?,
            Action::Restore => {
                let size = self.window.as_ref().map(|w| w.inner_size()).unwrap_or_default();
                self.resized(size)?
            }
            Action::Denoise(d) => {
                // Applied to the renderer before the next frame (a scene must be loaded).
                self.denoise = d;
                println!("denoiser {}", on(d));
            }
            Action::Stats => self.print_statistics()?,
            Action::Tracer(a) => {
                // A device without ray tracing keeps the tracer it has: the message says why.
                match self.renderer.set_accel(a, Default::default()) {
                    Ok(()) => println!("tracer: {a:?}"),
                    Err(e) => println!("{e:#}"),
                }
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

    pub(super) fn select(&mut self, x: f32, y: f32) -> Result<()> {
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

    fn screenshot(&mut self) -> Result<()> {
        self.shots += 1;
        let path = PathBuf::from(format!("{}-{}.png", self.live.scene.name, self.shots));
        let p = self.renderer.picture()?;
        p.save(&path)?;
        let how = if self.denoised_shown() { ", denoised" } else { "" };
        println!("wrote {} ({} spp{how})", path.display(), p.samples);
        Ok(())
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
        assert_eq!(
            parse_action("3:fly=0;0;0.5").unwrap(),
            (3, Action::Fly(Vec3::new(0.0, 0.0, 0.5)))
        );
        assert_eq!(parse_action("4:denoise=off").unwrap(), (4, Action::Denoise(false)));
        assert_eq!(parse_action("5:denoise=on").unwrap(), (5, Action::Denoise(true)));
        assert_eq!(
            parse_action("6:tracer=driver").unwrap(),
            (6, Action::Tracer(crate::render::Accel::Driver))
        );
        for bad in [
            "x:add-sphere",
            "3:fly",
            "3:remove=1",
            "3:tracer=optix",
            "3:move=a;b;c",
            "add-sphere",
            "3:denoise=maybe",
            "3:denoise",
        ] {
            let e = parse_action(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }
}
