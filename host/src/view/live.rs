//! A scene that changes while it renders, as in the thesis's engine: objects animate, are
//! added, moved, rotated and removed between frames, and [`LiveScene::sync`] brings the GPU
//! renderer up to date (new transforms only, or the whole scene when objects came or went).
//! The BVH is rebuilt from the current scene every frame by the renderer.
use crate::features::{self, Forced};
use crate::gpu::GpuRenderer;
use crate::render::with_bvh;
use crate::scene::{material, Animation, InstancingMode, Scene, SceneGpu, SceneObject, Shape, Transform};
use anyhow::{bail, Result};
use glam::Vec3;
use shared::types::{Frame, Ray, INVALID};

/// Materials given to added objects, in turn.
const ADDED_MATERIALS: [&str; 3] = ["live white", "live mirror", "live glass"];

pub struct LiveScene {
    /// The scene: edit its objects through [`LiveScene::add`], [`LiveScene::remove`],
    /// [`LiveScene::translate`] and [`LiveScene::rotate`] (a frame makes again the transforms
    /// of the animated objects and of those edited through them only).
    pub scene: Scene,
    /// Animation time in seconds.
    pub time: f32,
    /// Trace through the BVH (else brute force, the thesis's comparison).
    pub bvh: bool,
    /// The object picked last (index into `scene.objects`).
    pub selected: Option<usize>,
    /// Kernel features forced beyond the scene's needs (see [`crate::features`]).
    pub forced: Forced,
    /// Whether objects become instances of their meshes (`--instancing`).
    pub instancing: InstancingMode,
    data: SceneGpu,
    /// Objects moved by [`LiveScene::translate`] or [`LiveScene::rotate`] since the last
    /// sync (with the animated ones, the objects whose transforms are made again).
    edited: Vec<usize>,
    /// The features of the last frame made, and what they were derived from.
    features: Option<(Frame, Forced, Frame)>,
    /// Objects were added or removed since the renderer last saw the scene.
    reload: bool,
    added: usize,
}

impl LiveScene {
    pub fn new(scene: Scene) -> LiveScene {
        LiveScene::with_instancing(scene, InstancingMode::default())
    }

    /// A live scene instanced or flattened as `instancing` says (flattened, with a warning,
    /// where it cannot be instanced).
    pub fn with_instancing(scene: Scene, instancing: InstancingMode) -> LiveScene {
        let data = layout(&scene, 0.0, instancing);
        LiveScene {
            scene,
            time: 0.0,
            bvh: true,
            selected: None,
            forced: Forced::default(),
            instancing,
            data,
            edited: Vec::new(),
            features: None,
            reload: true,
            added: 0,
        }
    }

    /// The render buffers as the renderer has them after the last [`LiveScene::sync`].
    pub fn data(&self) -> &SceneGpu {
        &self.data
    }

    /// Camera, settings and kernel features for the current scene.
    pub fn frame(&self) -> Frame {
        let frame = with_bvh(self.scene.frame(&self.data), self.bvh);
        // Forced features that contradict the edited scene (a kind forced off, then added)
        // fall back to every feature.
        features::derive(&self.data, &frame, &self.forced).map_or(frame, |f| f.apply(&frame))
    }

    /// [`LiveScene::frame`], derived again only when the camera, settings or forced
    /// features changed (between reloads the objects' materials do not: deriving walks
    /// every object, a millisecond for the forest's 24,578).
    fn frame_cached(&mut self) -> Frame {
        let base = with_bvh(self.scene.frame(&self.data), self.bvh);
        if let Some((b, forced, frame)) = &self.features {
            if *b == base && *forced == self.forced {
                return *frame;
            }
        }
        let frame = self.frame();
        self.features = Some((base, self.forced.clone(), frame));
        frame
    }

    /// Brings `r` up to date: the whole scene after additions and removals, else the
    /// objects' transforms at `time` and the frame, each only when it changed (so a still
    /// scene keeps accumulating). Returns whether accumulation restarted.
    pub fn sync(&mut self, r: &mut GpuRenderer) -> Result<bool> {
        if self.reload {
            self.edited.clear();
            self.features = None;
            self.data = layout(&self.scene, self.time, self.instancing);
            r.load(&self.data, &self.frame())?;
            self.reload = false;
            return Ok(true);
        }
        let objects = self.scene.objects_moved(&self.data.objects, &self.edited, self.time);
        self.edited.clear();
        let mut restarted = false;
        if objects != self.data.objects {
            r.set_objects(&objects)?;
            self.data.objects = objects;
            restarted = true;
        }
        let frame = self.frame_cached();
        if frame != *r.frame() {
            r.set_frame(&frame)?;
            restarted = true;
        }
        Ok(restarted)
    }

    /// Whether any object moves over time.
    pub fn animated(&self) -> bool {
        self.scene.objects.iter().any(|o| o.animation != Animation::default())
    }

    /// Adds `object`; returns its index.
    pub fn add(&mut self, object: SceneObject) -> usize {
        self.scene.objects.push(object);
        self.reload = true;
        self.scene.objects.len() - 1
    }

    /// Adds a sphere of `radius` at `at`, made of the next of a white, a mirror and a glass
    /// material.
    pub fn add_sphere(&mut self, at: Vec3, radius: f32) -> usize {
        let material = self.next_material();
        self.added += 1;
        self.add(SceneObject {
            name: format!("added sphere {}", self.added),
            shape: Shape::Sphere { radius },
            transform: Transform::at(at),
            material,
            animation: Animation::default(),
            instance: None,
        })
    }

    /// Adds mesh `mesh` of the scene, scaled to fit a ball of `radius`, centred at `at`.
    pub fn add_mesh(&mut self, mesh: usize, at: Vec3, radius: f32) -> Result<usize> {
        let Some(m) = self.scene.meshes.get(mesh) else {
            bail!("the scene has no mesh {mesh} (it has {})", self.scene.meshes.len());
        };
        let (lo, hi) = m.tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]).fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), v| {
                let p = Vec3::new(v[0], v[1], v[2]);
                (lo.min(p), hi.max(p))
            },
        );
        let half = ((hi - lo) * 0.5).length();
        if !(half.is_finite() && half > 0.0) {
            bail!("mesh {} has no extent to scale", m.name);
        }
        let scale = radius / half;
        let centre = (lo + hi) * 0.5;
        let name = format!("added {} {}", m.name, self.added + 1);
        let material = self.next_material();
        self.added += 1;
        Ok(self.add(SceneObject {
            name,
            shape: Shape::Mesh(mesh),
            transform: Transform::new(at - centre * scale, Vec3::ZERO, Vec3::splat(scale)),
            material,
            animation: Animation::default(),
            instance: None,
        }))
    }

    fn next_material(&mut self) -> u32 {
        let name = ADDED_MATERIALS[self.added % ADDED_MATERIALS.len()];
        if let Some(i) = self.scene.material_index(name) {
            return i;
        }
        let m = match self.added % ADDED_MATERIALS.len() {
            0 => material::diffuse([0.8, 0.8, 0.8]),
            1 => material::metal([0.9, 0.9, 0.9], 0.05),
            _ => material::dielectric(1.5),
        };
        self.scene.materials.push((name.to_string(), m));
        self.scene.materials.len() as u32 - 1
    }

    /// Removes object `index`. The last object stays: a scene needs at least one.
    pub fn remove(&mut self, index: usize) -> Result<SceneObject> {
        if index >= self.scene.objects.len() {
            bail!("no object {index} (the scene has {})", self.scene.objects.len());
        }
        if self.scene.objects.len() == 1 {
            bail!(
                "{} is the scene's last object and stays",
                self.scene.objects[index].name
            );
        }
        self.selected = match self.selected {
            Some(s) if s == index => None,
            Some(s) if s > index => Some(s - 1),
            s => s,
        };
        self.reload = true;
        Ok(self.scene.objects.remove(index))
    }

    /// Moves object `index` by `delta` (world units).
    pub fn translate(&mut self, index: usize, delta: Vec3) -> Result<()> {
        let Some(o) = self.scene.objects.get_mut(index) else {
            bail!("no object {index}");
        };
        o.transform.translation += delta;
        if let Some(orbit) = o.animation.orbit.as_mut() {
            orbit.center += delta;
        }
        self.edited.push(index);
        Ok(())
    }

    /// Turns object `index` by `degrees` about x, y and z.
    pub fn rotate(&mut self, index: usize, degrees: Vec3) -> Result<()> {
        let Some(o) = self.scene.objects.get_mut(index) else {
            bail!("no object {index}");
        };
        o.transform.rotation_deg += degrees;
        self.edited.push(index);
        Ok(())
    }

    /// The ray through the centre of pixel (`x`, `y`) of `frame`'s camera (the pinhole ray,
    /// no lens offset).
    pub fn pixel_ray(frame: &Frame, x: f32, y: f32) -> Ray {
        let c = &frame.camera;
        let v = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
        let s = (x + 0.5) / frame.width as f32;
        let t = 1.0 - (y + 0.5) / frame.height as f32;
        let target = v(c.lower_left) + v(c.horizontal) * s + v(c.vertical) * t;
        let origin = v(c.origin);
        let d = (target - origin).normalize();
        Ray {
            origin: [origin.x, origin.y, origin.z, 0.0],
            dir: [d.x, d.y, d.z, f32::INFINITY],
        }
    }

    /// The object seen at pixel (`x`, `y`) (through an instance, the instance's object), found
    /// by a ray cast through the renderer's current BVH (the same traversal as the path
    /// tracer), and the hit distance.
    pub fn pick(&mut self, r: &mut GpuRenderer, x: f32, y: f32) -> Result<Option<(usize, f32)>> {
        let ray = Self::pixel_ray(r.frame(), x, y);
        let hit = r.cast_objects(&[ray])?[0];
        Ok((hit.prim != INVALID).then_some((hit.prim as usize, hit.t)))
    }
}

/// The render buffers of `scene` at `time` as `mode` says, for frames of one sample a pixel
/// (a moving scene's); where that fails, with a warning, the other layout (a scene too large
/// to flatten is instanced, one that cannot be instanced is flattened).
fn layout(scene: &Scene, time: f32, mode: InstancingMode) -> SceneGpu {
    let pixels = scene.settings.width as u64 * scene.settings.height as u64;
    scene.gpu_data_for(time, mode, pixels).unwrap_or_else(|e| {
        let other = match mode {
            InstancingMode::Off => InstancingMode::On,
            _ => InstancingMode::Off,
        };
        eprintln!("warning: {e}; trying --instancing {other:?}");
        scene.gpu_data_for(time, other, pixels).unwrap_or_else(|e| {
            eprintln!("warning: {e}");
            SceneGpu::default()
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cornell() -> LiveScene {
        LiveScene::new(Scene::builtin("cornell").unwrap())
    }

    #[test]
    fn adding_and_removing_keeps_the_selection_on_the_same_object() {
        let mut l = cornell();
        let n = l.scene.objects.len();
        let a = l.add_sphere(Vec3::ZERO, 0.1);
        assert_eq!(a, n);
        l.selected = Some(a);
        l.remove(0).unwrap();
        assert_eq!(l.selected, Some(a - 1));
        assert_eq!(l.scene.objects[a - 1].name, "added sphere 1");
        l.remove(a - 1).unwrap();
        assert_eq!(l.selected, None);
    }

    #[test]
    fn added_objects_cycle_through_three_materials_made_once() {
        let mut l = cornell();
        let before = l.scene.materials.len();
        let ids: Vec<u32> = (0..4)
            .map(|_| {
                let i = l.add_sphere(Vec3::ZERO, 0.1);
                l.scene.objects[i].material
            })
            .collect();
        assert_eq!(l.scene.materials.len(), before + 3);
        assert_eq!(ids[0], ids[3]);
        assert!(ids[0] != ids[1] && ids[1] != ids[2]);
    }

    #[test]
    fn the_last_object_cannot_be_removed() {
        let mut l = cornell();
        while l.scene.objects.len() > 1 {
            l.remove(0).unwrap();
        }
        let e = l.remove(0).unwrap_err().to_string();
        assert!(e.contains("last object"), "{e}");
        assert!(l.remove(5).is_err());
        assert_eq!(l.scene.objects.len(), 1);
    }

    #[test]
    fn an_added_mesh_fits_the_asked_ball() {
        let mut l = LiveScene::new(Scene::builtin("suzanne").unwrap());
        let mesh = (0..l.scene.meshes.len())
            .max_by_key(|&m| l.scene.meshes[m].tris.len())
            .unwrap();
        let at = Vec3::new(1.0, 2.0, 3.0);
        let i = l.add_mesh(mesh, at, 0.5).unwrap();
        let m = l.scene.objects[i].transform.matrix();
        let far = l.scene.meshes[mesh]
            .tris
            .iter()
            .flat_map(|t| [t.v0, t.v1, t.v2])
            .map(|v| (m.transform_point3(Vec3::new(v[0], v[1], v[2])) - at).length())
            .fold(0.0f32, f32::max);
        assert!(far <= 0.5 + 1e-4 && far > 0.25, "farthest vertex {far}");
        assert!(l.add_mesh(99, at, 0.5).is_err());
    }

    #[test]
    fn the_centre_pixel_ray_looks_at_the_camera_target() {
        let l = cornell();
        let f = l.frame();
        let r = LiveScene::pixel_ray(&f, f.width as f32 / 2.0 - 0.5, f.height as f32 / 2.0 - 0.5);
        let c = l.scene.camera;
        let want = (c.look_at - c.position).normalize();
        let got = Vec3::new(r.dir[0], r.dir[1], r.dir[2]);
        assert!((got - want).length() < 1e-5, "{got} vs {want}");
    }
}
