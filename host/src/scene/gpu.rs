//! A scene flattened into the render buffers (descriptor set 1 of `shared::types`) for one moment
//! in time, and its camera and settings as a [`Frame`].
//!
//! Primitives are every mesh object's triangles (objects in order, each object's mesh copied),
//! then every sphere object's sphere; all in model space, placed by their object's matrix.
use super::envmap::EnvMap;
use super::texture::TextureSet;
use super::{material, Scene, SceneObject, Shape};
use crate::bvh::{MeshPrims, Placement};
use glam::Vec3;
use shared::types::{
    Camera, Frame, Material, Object, PunctualLight, Sphere, Triangle, VertexAttrs, FEATURES_ALL, FLAG_BVH, FLAG_GAMMA2,
    FLAG_MIS, FLAG_NEE, FLAG_RUSSIAN_ROULETTE, INVALID,
};
use std::sync::Arc;

/// The render buffers of a scene at one moment.
#[derive(Clone, Debug, Default)]
pub struct SceneGpu {
    /// Model-space triangles of every mesh object, in object order.
    pub model_tris: Vec<Triangle>,
    /// Model-space spheres of every sphere object, in object order: centre 0, the object's radius.
    pub model_spheres: Vec<Sphere>,
    /// The object of every primitive (triangles, then spheres).
    pub prim_object: Vec<u32>,
    pub objects: Vec<Object>,
    pub materials: Vec<Material>,
    /// The primitives whose material emits light, in primitive order.
    pub lights: Vec<u32>,
    /// The vertex attributes of every mesh that has them, each mesh once (`Object::attrs`).
    pub attrs: Vec<VertexAttrs>,
    /// Point, spot and directional lights.
    pub punctual: Vec<PunctualLight>,
    /// The environment map, if the scene has one (its turn and intensity go in the frame).
    pub env: Option<Arc<EnvMap>>,
    /// Every texture of the materials and their texels (`Material::textures` index them).
    pub textures: Arc<TextureSet>,
    /// With two levels ([`Scene::gpu_data_instanced`]): objects are instances of their
    /// meshes, but those in the world-space group. The primitives above are then the
    /// group's (model space, transformed every frame), then the meshes' in model space, each
    /// mesh once, in the levels' layout; `None`: flattened, every object's primitives copied.
    pub instancing: Option<Arc<Instancing>>,
    /// Why the scene is instanced or flattened ([`Scene::gpu_data_as`]; `--explain`).
    pub instancing_why: String,
}

/// Whether a scene's objects become instances of their meshes (two levels: but those that
/// deform or are marked `instance = false`, which form the world-space group) or are all
/// flattened into one world-space BVH (`--instancing`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum InstancingMode {
    /// Two levels where the scene marks an object `instance = true`, where the rebuild saved
    /// outweighs the cost of tracing two levels ([`auto_instances`]), or where the scene is
    /// too large to flatten.
    #[default]
    Auto,
    On,
    Off,
}

/// The most primitives [`Scene::gpu_data_as`] flattens: at [`FLAT_BYTES`] each, a build
/// of more would not fit an 80 GB GPU.
pub const MAX_FLATTENED: u64 = 200_000_000;

/// GPU bytes a flattened primitive takes to build and trace: the triangle (48), its BVH
/// nodes (64) and the builder's scratch (181).
pub const FLAT_BYTES: u64 = 293;

/// Whether [`InstancingMode::Auto`] instances a scene of `flattened` primitives, `distinct`
/// of them distinct, whose one build serves `samples` samples. Measured on the H200
/// (bench/NOTES.md, session 49; `bench realtime --instancing on|off`, 1920x1080, depth 4):
/// the sixteen bunnies' flattened rebuild costs 0.36 ms more than their top level, 0.35 ns a
/// copy saved, and their two levels trace 0.45 ms slower a one-sample frame, 0.22 ns a
/// sample, so instancing pays where the copies it saves are at least two thirds of the
/// samples (0.63 measured): a frame of 1280x720 at one sample, not of 1920x1080 (flattened
/// 2.89 against 2.99 ms) nor a still of 32 samples. The herd's flattened tree (10M
/// primitives) traces slower than its two levels at any number of samples (a real-time
/// frame 5.15 against 4.89 ms of trace, four samples 21.8 against 19.4), so above
/// [`AUTO_FLAT_SLOWER`] primitives two levels always. A scene must also repeat its meshes at
/// least twice over, and save at least [`AUTO_MIN_SAVED`] copies.
pub fn auto_instances(flattened: u64, distinct: u64, samples: u64) -> bool {
    let saved = flattened.saturating_sub(distinct);
    flattened >= 2 * distinct && saved >= AUTO_MIN_SAVED && (3 * saved >= 2 * samples || flattened >= AUTO_FLAT_SLOWER)
}

/// Flattened primitives from which [`auto_instances`] always takes two levels: between the
/// sixteen bunnies' 1.1M (their flattened tree traces faster) and the herd's 10M (slower);
/// where in between is not measured.
pub const AUTO_FLAT_SLOWER: u64 = 4_000_000;

/// Copies below which instancing never pays: their rebuild takes under 0.04 ms.
pub const AUTO_MIN_SAVED: u64 = 100_000;

/// An instanced scene's two levels: what `bvh::build_levels` and `gpu::GpuLevels` build, and
/// what the path tracer's lights need besides (object `k` is instance `k`).
#[derive(Clone, Debug, Default)]
pub struct Instancing {
    /// The meshes the objects show, each once: the scene's meshes (an unused one empty),
    /// then one mesh of one sphere for each sphere object.
    pub meshes: Vec<MeshPrims>,
    /// Every object's mesh and transform at the moment the data was made.
    pub placements: Vec<Placement>,
    /// The object showing each of `SceneGpu::lights` (the second half of the light buffer:
    /// an instance's emitter is a model-space primitive of a shared mesh).
    pub light_objects: Vec<u32>,
    /// The top level's first node (after every mesh's).
    pub top: u32,
    /// Triangles of the world-space group (mesh 0, instance 0; 0: none): the first
    /// `world_tris` of `SceneGpu::model_tris` and `prim_object`, which the transform stage
    /// takes to world space and the builder builds every frame, as a flattened scene's.
    pub world_tris: u32,
}

impl Instancing {
    /// The placements with every object's transform as `objects` (by object number) have it
    /// now (the world-space group stays where it is: in world space).
    pub fn placements_at(&self, objects: &[Object]) -> Vec<Placement> {
        self.placements
            .iter()
            .map(|p| match objects.get(p.object as usize) {
                Some(o) => Placement { rows: o.rows, ..*p },
                None => *p,
            })
            .collect()
    }

    /// Primitives counting every instance's again, and distinct primitives.
    pub fn counts(&self) -> (u64, u64) {
        let size = |m: &MeshPrims| (m.tris.len() + m.spheres.len()) as u64;
        let instanced = self.placements.iter().map(|p| size(&self.meshes[p.mesh])).sum();
        (instanced, self.meshes.iter().map(size).sum())
    }
}

impl SceneGpu {
    /// The light buffer's words: the emissive primitives, and with two levels the object
    /// showing each after them (`shared::path::World::light`).
    pub fn light_words(&self) -> Vec<u32> {
        match &self.instancing {
            Some(i) => [self.lights.as_slice(), &i.light_objects].concat(),
            None => self.lights.clone(),
        }
    }

    /// What alpha-tested triangles read (`traverse::Scene::coverage`): these buffers.
    pub fn coverage(&self) -> shared::alpha::Coverage<'_> {
        shared::alpha::Coverage {
            objects: &self.objects,
            prim_object: &self.prim_object,
            materials: &self.materials,
            attrs: &self.attrs,
            textures: &self.textures.infos,
            texels: &self.textures.texels,
        }
    }
}

/// Writes `o`'s transform at `time_s` into `object`: its rows, the cofactor rows that take
/// normals to world space, and the largest scale (spheres' radii).
fn place(object: &mut Object, o: &SceneObject, time_s: f32) {
    let t = o.transform_at(time_s);
    let m = t.matrix();
    let c = m.matrix3;
    let row = |r: usize| [c.x_axis[r], c.y_axis[r], c.z_axis[r], m.translation[r]];
    let n = super::attrs::cofactor(c.into());
    let normal_row = |r: usize| [n.x_axis[r], n.y_axis[r], n.z_axis[r], 0.0];
    object.rows = [row(0), row(1), row(2)];
    object.normal_rows = [normal_row(0), normal_row(1), normal_row(2)];
    object.radius_scale = t.scale.abs().max_element();
    object.wave = o.animation.wave.map_or([0.0; 4], |w| w.params(time_s));
}

/// Probability with which next-event estimation samples the environment map when the scene
/// also has other lights (1 without them).
pub const ENV_LIGHT_PROB: f32 = 0.5;

fn v4(v: Vec3) -> [f32; 4] {
    [v.x, v.y, v.z, 0.0]
}

impl Scene {
    /// Every object's transform and material at `time_s` seconds, with where its primitives
    /// and vertex attributes lie in [`Scene::gpu_data`]'s buffers.
    pub fn objects_at(&self, time_s: f32) -> Vec<Object> {
        let attr_base = self.attr_bases();
        let (n_tris, _) = self.counts();
        let (mut next_tri, mut next_sphere) = (0, n_tris as u32);
        self.objects
            .iter()
            .map(|o| {
                let (first_prim, attrs) = match o.shape {
                    Shape::Mesh(k) => {
                        let first = next_tri;
                        next_tri += self.meshes.get(k).map_or(0, |m| m.tris.len() as u32);
                        (first, attr_base.get(k).copied().unwrap_or(INVALID))
                    }
                    Shape::Sphere { .. } => {
                        next_sphere += 1;
                        (next_sphere - 1, INVALID)
                    }
                };
                let mut object = Object {
                    material: o.material,
                    first_prim,
                    attrs,
                    ..Default::default()
                };
                place(&mut object, o, time_s);
                object
            })
            .collect()
    }

    /// `objects` (as `data` lays them out) moved to `time_s`: the animated objects' and
    /// `edited`'s transforms made again, every other object's kept. What a real-time frame
    /// needs, without the work for every object of a large scene.
    pub fn objects_moved(&self, objects: &[Object], edited: &[usize], time_s: f32) -> Vec<Object> {
        self.moved(objects, time_s, |k, o| {
            o.animation != Default::default() || edited.contains(&k)
        })
    }

    /// Every object at `time_s` as `data` lays the primitives out (instanced or flattened):
    /// what `GpuRenderer::set_objects` takes for a moment of an animation.
    pub fn objects_in(&self, data: &SceneGpu, time_s: f32) -> Vec<Object> {
        self.moved(&data.objects, time_s, |_, _| true)
    }

    /// `objects` with the transforms at `time_s` of those `which` picks (by index and object).
    fn moved(&self, objects: &[Object], time_s: f32, which: impl Fn(usize, &SceneObject) -> bool) -> Vec<Object> {
        let mut moved = objects.to_vec();
        for (k, (o, m)) in self.objects.iter().zip(moved.iter_mut()).enumerate() {
            if which(k, o) {
                place(m, o, time_s);
            }
        }
        moved
    }

    /// For every mesh, the index of its first triangle's attributes in [`SceneGpu::attrs`]
    /// ([`INVALID`] for a mesh without attributes or one no object shows).
    fn attr_bases(&self) -> Vec<u32> {
        let mut used = vec![false; self.meshes.len()];
        for o in &self.objects {
            if let Shape::Mesh(k) = o.shape {
                if let Some(u) = used.get_mut(k) {
                    *u = true;
                }
            }
        }
        let mut next = 0;
        self.meshes
            .iter()
            .zip(used)
            .map(|(m, used)| {
                if !used || m.attrs.is_empty() || m.attrs.len() != m.tris.len() {
                    return INVALID;
                }
                next += m.attrs.len() as u32;
                next - m.attrs.len() as u32
            })
            .collect()
    }

    /// The render buffers at `time_s` seconds.
    pub fn gpu_data(&self, time_s: f32) -> SceneGpu {
        let (n_tris, n_spheres) = self.counts();
        let mut model_tris = Vec::with_capacity(n_tris);
        let mut model_spheres = Vec::with_capacity(n_spheres);
        let mut prim_object = Vec::with_capacity(n_tris + n_spheres);
        for (k, o) in self.objects.iter().enumerate() {
            if let Shape::Mesh(m) = o.shape {
                let tris = &self.meshes[m].tris;
                model_tris.extend_from_slice(tris);
                prim_object.extend(std::iter::repeat_n(k as u32, tris.len()));
            }
        }
        for (k, o) in self.objects.iter().enumerate() {
            if let Shape::Sphere { radius } = o.shape {
                model_spheres.push(Sphere {
                    center_radius: [0.0, 0.0, 0.0, radius],
                });
                prim_object.push(k as u32);
            }
        }
        let emissive: Vec<bool> = self
            .objects
            .iter()
            .map(|o| {
                self.materials
                    .get(o.material as usize)
                    .is_some_and(|(_, m)| material::emits(m))
            })
            .collect();
        let lights = (0..prim_object.len() as u32)
            .filter(|&i| emissive[prim_object[i as usize] as usize])
            .collect();
        SceneGpu {
            model_tris,
            model_spheres,
            prim_object,
            lights,
            ..self.gpu_common(time_s)
        }
    }

    /// What both layouts share: the objects at `time_s` (as flattened), materials, vertex
    /// attributes, lights, environment and textures; no primitives.
    fn gpu_common(&self, time_s: f32) -> SceneGpu {
        let bases = self.attr_bases();
        let mut attrs = Vec::new();
        for (m, base) in self.meshes.iter().zip(bases) {
            if base != INVALID {
                attrs.extend_from_slice(&m.attrs);
            }
        }
        SceneGpu {
            objects: self.objects_at(time_s),
            materials: self.materials.iter().map(|(_, m)| *m).collect(),
            attrs,
            punctual: self.punctual.clone(),
            env: self.environment.as_ref().map(|e| e.map.clone()),
            textures: self.textures.clone(),
            ..Default::default()
        }
    }

    /// The render buffers at `time_s`, instanced or flattened as `mode` says, for a render
    /// whose one build serves the scene's settings' samples (width x height x spp): see
    /// [`Scene::gpu_data_for`].
    pub fn gpu_data_as(&self, time_s: f32, mode: InstancingMode) -> Result<SceneGpu, String> {
        let s = &self.settings;
        self.gpu_data_for(time_s, mode, s.width as u64 * s.height as u64 * s.spp as u64)
    }

    /// The render buffers at `time_s`, instanced or flattened as `mode` says (see
    /// [`InstancingMode`]), where one build of the BVH serves `samples` samples (a still: every
    /// pixel's samples; a real-time frame: one a pixel), with the reason in `instancing_why`.
    /// `Auto` takes two levels where an object is marked `instance = true`, or by
    /// [`auto_instances`]. `On` fails where the scene cannot be instanced (see
    /// [`Scene::gpu_data_instanced`]); `Auto` then flattens it. Neither flattens more than
    /// [`MAX_FLATTENED`] primitives.
    pub fn gpu_data_for(&self, time_s: f32, mode: InstancingMode, samples: u64) -> Result<SceneGpu, String> {
        let (tris, spheres) = self.counts();
        let flattened = (tris + spheres) as u64;
        let mut used = vec![false; self.meshes.len()];
        for o in &self.objects {
            if let Shape::Mesh(m) = o.shape {
                used[m] = true;
            }
        }
        let distinct = spheres as u64
            + self
                .meshes
                .iter()
                .zip(&used)
                .filter(|(_, &u)| u)
                .map(|(m, _)| m.tris.len() as u64)
                .sum::<u64>();
        let reuse = format!(
            "{} objects show {flattened} primitives, {distinct} distinct",
            self.objects.len()
        );
        let grouped = self
            .objects
            .iter()
            .filter(|o| matches!(o.shape, Shape::Mesh(_)) && Self::in_world_group(o))
            .count();
        let group = match grouped {
            0 => String::new(),
            n => {
                format!("; {n} in the world-space group transformed every frame (they wave or are marked instance = false), its BVH built, then refit between builds")
            }
        };
        let instanced = |why: String| {
            self.gpu_data_instanced(time_s).map(|mut d| {
                d.instancing_why = format!("{why}{group}");
                d
            })
        };
        let asked = self.objects.iter().filter(|o| o.instance == Some(true)).count();
        let too_many = flattened > MAX_FLATTENED;
        let flat = |why: String| {
            if too_many {
                return Err(format!(
                    "flattened, the scene would hold {flattened} primitives (a GPU needs about {} GB \
                     to build it); its objects share meshes: instance them (--instancing on)",
                    flattened * FLAT_BYTES / 1_000_000_000
                ));
            }
            let mut d = self.gpu_data(time_s);
            d.instancing_why = why;
            Ok(d)
        };
        match mode {
            InstancingMode::Off => flat(format!("flattened (--instancing off); {reuse}")),
            InstancingMode::On => instanced(format!("objects are instances (--instancing on); {reuse}")),
            InstancingMode::Auto if asked > 0 || too_many || auto_instances(flattened, distinct, samples) => {
                let why = if asked > 0 {
                    format!("objects are instances: the scene marks {asked} instance = true; {reuse}")
                } else if too_many {
                    format!("objects are instances: {reuse}, too many to flatten")
                } else {
                    format!(
                        "objects are instances: {reuse}; for {samples} samples a build the two levels \
                         trace faster than the flattened rebuild and trace (auto)"
                    )
                };
                match instanced(why) {
                    Ok(d) => Ok(d),
                    Err(e) => flat(format!("flattened: {e}")),
                }
            }
            InstancingMode::Auto => flat(format!(
                "flattened: {reuse}; for {samples} samples a build one BVH traces faster than two levels \
                 by more than the rebuild costs (auto)"
            )),
        }
    }

    /// Whether object `o` must be in the world-space group of a two-level scene: its shape
    /// changes every frame (a wave), or the scene says so (`instance = false`).
    fn in_world_group(o: &SceneObject) -> bool {
        o.animation.wave.is_some() || o.instance == Some(false)
    }

    /// The render buffers at `time_s` seconds with two levels: every object an instance of
    /// its mesh (each mesh's primitives once, in model space; a sphere object shows a mesh
    /// of one sphere), but those that wave or that the scene marks `instance = false`: their
    /// triangles form the world-space group (mesh 0, instance 0: what a flattened scene
    /// would hold of them, transformed every frame and its BVH built or refit, placed by the identity).
    /// Errors name the object that cannot be instanced: a sphere scaled unevenly (an
    /// instance's sphere is hit as the ellipsoid its transform makes, a flattened one as a
    /// sphere of the largest scale), a transform that cannot be inverted.
    pub fn gpu_data_instanced(&self, time_s: f32) -> Result<SceneGpu, String> {
        let common = self.gpu_common(time_s);
        let mut objects = common.objects.clone();
        // Mesh 0: the world-space group; scene mesh m: mesh m + 1; then one mesh of one
        // sphere for each sphere object.
        let mut meshes: Vec<MeshPrims> = vec![MeshPrims::default(); self.meshes.len() + 1];
        let mut group_tris = Vec::new();
        let mut group_objects = Vec::new();
        let mut placements = Vec::with_capacity(self.objects.len() + 1);
        for (k, o) in self.objects.iter().enumerate() {
            let mesh = match o.shape {
                Shape::Mesh(m) if Self::in_world_group(o) => {
                    objects[k].first_prim = group_tris.len() as u32;
                    group_tris.extend_from_slice(&self.meshes[m].tris);
                    group_objects.extend(std::iter::repeat_n(k as u32, self.meshes[m].tris.len()));
                    continue;
                }
                Shape::Mesh(m) => {
                    if meshes[m + 1].tris.is_empty() {
                        meshes[m + 1].tris = self.meshes[m].tris.to_vec();
                    }
                    m + 1
                }
                Shape::Sphere { radius } => {
                    let s = o.transform_at(time_s).scale.abs();
                    if s.x != s.y || s.y != s.z {
                        return Err(format!(
                            "object {k} ({}) is a sphere scaled unevenly ({}): it cannot be instanced",
                            o.name, o.transform.scale
                        ));
                    }
                    meshes.push(MeshPrims {
                        tris: Vec::new(),
                        spheres: vec![Sphere {
                            center_radius: [0.0, 0.0, 0.0, radius],
                        }],
                    });
                    meshes.len() - 1
                }
            };
            placements.push(Placement {
                mesh,
                object: k as u32,
                rows: objects[k].rows,
            });
        }
        let world_tris = group_tris.len() as u32;
        if world_tris > 0 {
            // The group as the transform stage makes it at `time_s` (the GPU's first frame
            // makes it again; the CPU executor's levels take it from here).
            let n = group_tris.len();
            meshes[0].tris = crate::cpu::transformed(&objects, &group_objects, &group_tris, &[], n, 0).0;
            placements.insert(0, Placement::world(0));
        }
        // Errors name the object (an instance's object).
        let layout = crate::bvh::layout(&meshes, &placements).map_err(|e| {
            let k = placements[e.instance].object as usize;
            let name = self.objects.get(k).map_or("", |o| o.name.as_str());
            format!("object {k} ({name}): {}", e.problem)
        })?;
        let (n_tris, n_spheres) = (layout.n_tris, layout.n_spheres);
        // What the tracers' primitives' numbers index: the group's model-space triangles
        // (what the transform stage reads) where its world-space ones lie, then the meshes'.
        let mut model_tris = Vec::with_capacity(n_tris as usize);
        let mut model_spheres = Vec::with_capacity(n_spheres as usize);
        model_tris.extend_from_slice(&group_tris);
        for m in &meshes[1..] {
            model_tris.extend_from_slice(&m.tris);
            model_spheres.extend_from_slice(&m.spheres);
        }
        // A primitive's object: the group's own; a mesh's, the first object showing it (read
        // only where no instance names one).
        let mut prim_object = vec![INVALID; (n_tris + n_spheres) as usize];
        prim_object[..group_objects.len()].copy_from_slice(&group_objects);
        let emits = |o: &Object| {
            self.materials
                .get(o.material as usize)
                .is_some_and(|(_, m)| material::emits(m))
        };
        let (mut lights, mut light_objects) = (Vec::new(), Vec::new());
        for (i, &k) in group_objects.iter().enumerate() {
            if emits(&objects[k as usize]) {
                lights.push(i as u32);
                light_objects.push(INVALID);
            }
        }
        for p in placements.iter().filter(|p| p.object != INVALID) {
            let k = p.object as usize;
            let m = &meshes[p.mesh];
            let (tri0, sphere0) = (layout.mesh_tris[p.mesh], n_tris + layout.mesh_spheres[p.mesh]);
            let prims = (tri0..tri0 + m.tris.len() as u32).chain(sphere0..sphere0 + m.spheres.len() as u32);
            let emits = emits(&objects[k]);
            for prim in prims {
                let owner = &mut prim_object[prim as usize];
                if *owner == INVALID {
                    *owner = k as u32;
                }
                if emits {
                    lights.push(prim);
                    light_objects.push(k as u32);
                }
            }
            objects[k].first_prim = if m.tris.is_empty() { sphere0 } else { tri0 };
        }
        Ok(SceneGpu {
            model_tris,
            model_spheres,
            prim_object,
            objects,
            lights,
            instancing: Some(Arc::new(Instancing {
                meshes,
                placements,
                light_objects,
                top: layout.top,
                world_tris,
            })),
            ..common
        })
    }

    /// Camera (thin lens, as in Ray Tracing in One Weekend) and settings for rendering `gpu`
    /// at the size in [`Scene::settings`], with every kernel feature on (see
    /// [`crate::features`] for the ones the scene needs).
    pub fn frame(&self, gpu: &SceneGpu) -> Frame {
        let c = &self.camera;
        let s = &self.settings;
        let aspect = s.width as f32 / s.height as f32;
        let viewport_h = 2.0 * (c.vfov_deg.to_radians() / 2.0).tan();
        let viewport_w = aspect * viewport_h;
        let w = (c.position - c.look_at).normalize();
        let u = c.up.cross(w).normalize();
        let v = w.cross(u);
        let focus = c.focus_distance.unwrap_or((c.position - c.look_at).length());
        let horizontal = focus * viewport_w * u;
        let vertical = focus * viewport_h * v;
        let lower_left = c.position - horizontal / 2.0 - vertical / 2.0 - focus * w;
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let env = self.environment.as_ref();
        let rotation = env.map_or(0.0, |e| e.rotation_deg).to_radians().sin_cos();
        let camera = Camera {
            origin: v4(c.position),
            lower_left: v4(lower_left),
            horizontal: v4(horizontal),
            vertical: v4(vertical),
            u: [u.x, u.y, u.z, c.aperture / 2.0],
            v: v4(v),
        };
        Frame {
            camera,
            prev_camera: camera,
            sky_top: v4(s.sky_top),
            sky_bottom: v4(s.sky_bottom),
            width: s.width,
            height: s.height,
            max_depth: s.max_depth,
            flags: flag(s.nee, FLAG_NEE)
                | flag(s.mis, FLAG_MIS)
                | flag(s.russian_roulette, FLAG_RUSSIAN_ROULETTE)
                | FLAG_BVH
                | flag(s.gamma2, FLAG_GAMMA2),
            n_tris: gpu.model_tris.len() as u32,
            n_prims: (gpu.model_tris.len() + gpu.model_spheres.len()) as u32,
            n_lights: gpu.lights.len() as u32,
            seed: s.seed,
            exposure: s.exposure,
            features: FEATURES_ALL,
            n_punctual: gpu.punctual.len() as u32,
            env_width: env.map_or(0, |e| e.map.width),
            env_height: env.map_or(0, |e| e.map.height),
            env_rotation: [rotation.1, rotation.0],
            env_intensity: env.map_or(0.0, |e| e.intensity),
            env_prob: match env {
                None => 0.0,
                Some(_) if gpu.lights.is_empty() && gpu.punctual.is_empty() => 1.0,
                Some(_) => ENV_LIGHT_PROB,
            },
            // A pixel's angular size at the image centre.
            pixel_spread: (viewport_h / s.height as f32).atan(),
            prev_objects: 0,
            n_instances: gpu.instancing.as_ref().map_or(0, |i| i.placements.len() as u32),
            top_nodes: gpu.instancing.as_ref().map_or(0, |i| i.top),
            _pad: [0; 3],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{material, Animation, CameraSpec, Mesh, SceneObject, Settings, Shape, Transform};
    use super::*;

    fn small_scene() -> Scene {
        let object = |name: &str, shape, translation, material| SceneObject {
            name: name.into(),
            shape,
            transform: Transform::new(translation, Vec3::ZERO, Vec3::splat(2.0)),
            material,
            animation: Animation {
                spin_deg_per_s: Vec3::new(0.0, 90.0, 0.0),
                ..Default::default()
            },
            instance: None,
        };
        Scene {
            name: "small".into(),
            punctual: Vec::new(),
            environment: None,
            textures: Default::default(),
            camera: CameraSpec {
                position: Vec3::new(0.0, 0.0, 5.0),
                look_at: Vec3::ZERO,
                up: Vec3::Y,
                vfov_deg: 90.0,
                aperture: 0.5,
                focus_distance: None,
            },
            settings: Settings {
                width: 200,
                height: 100,
                nee: false,
                gamma2: true,
                ..Default::default()
            },
            materials: vec![
                ("white".into(), material::diffuse([0.5; 3])),
                ("lamp".into(), material::emissive([4.0; 3])),
            ],
            meshes: vec![Mesh::flat("builtin:cube", super::super::shapes::cube())],
            objects: vec![
                object("ball", Shape::Sphere { radius: 0.5 }, Vec3::X, 1),
                object("box", Shape::Mesh(0), Vec3::Y, 0),
                object("lamp box", Shape::Mesh(0), Vec3::Z, 1),
            ],
        }
    }

    #[test]
    fn triangles_come_first_then_spheres_with_their_objects() {
        let scene = small_scene();
        let gpu = scene.gpu_data(1.0);
        assert_eq!(scene.counts(), (24, 1));
        assert_eq!(gpu.model_tris.len(), 24);
        assert_eq!(
            gpu.model_spheres,
            vec![Sphere {
                center_radius: [0.0, 0.0, 0.0, 0.5]
            }]
        );
        let mut owners = vec![1; 12];
        owners.extend([2; 12]);
        owners.push(0);
        assert_eq!(gpu.prim_object, owners);
        // The light box's triangles and the light sphere.
        let lights: Vec<u32> = (12..25).collect();
        assert_eq!(gpu.lights, lights);
        assert_eq!(gpu.materials.len(), 2);
        // After one second the spin has turned every object 90 degrees about y.
        let o = gpu.objects[0];
        let want = [[0.0, 0.0, 2.0, 1.0], [0.0, 2.0, 0.0, 0.0], [-2.0, 0.0, 0.0, 0.0]];
        for (row, want) in o.rows.iter().zip(want) {
            for (a, b) in row.iter().zip(want) {
                assert!((a - b).abs() < 1e-6, "{:?}", o.rows);
            }
        }
        assert_eq!((o.radius_scale, o.material), (2.0, 1));
    }

    #[test]
    fn moving_objects_makes_again_only_the_animated_and_the_edited() {
        let mut scene = small_scene();
        scene.objects[1].animation = Animation::default();
        let data = scene.gpu_data(0.0);
        // From time 0 to 1: the spinning objects turn, the still one stays.
        let moved = scene.objects_moved(&data.objects, &[], 1.0);
        assert_eq!(moved, scene.objects_in(&data, 1.0));
        assert_ne!(moved[0], data.objects[0]);
        assert_eq!(moved[1], data.objects[1]);
        // The still object edited: made again only when named.
        scene.objects[1].transform.translation.x += 1.0;
        assert_ne!(
            scene.objects_moved(&data.objects, &[], 1.0),
            scene.objects_in(&data, 1.0)
        );
        assert_eq!(
            scene.objects_moved(&data.objects, &[1], 1.0),
            scene.objects_in(&data, 1.0)
        );
    }

    #[test]
    fn frame_follows_the_thin_lens_camera() {
        let scene = small_scene();
        let gpu = scene.gpu_data(0.0);
        let f = scene.frame(&gpu);
        let c = f.camera;
        // vfov 90 at focus distance 5: the image plane is 10 high and 20 wide, centred on look_at.
        assert_eq!(c.origin, [0.0, 0.0, 5.0, 0.0]);
        assert!((Vec3::from_slice(&c.horizontal[..3]) - Vec3::new(20.0, 0.0, 0.0)).length() < 1e-4);
        assert!((Vec3::from_slice(&c.vertical[..3]) - Vec3::new(0.0, 10.0, 0.0)).length() < 1e-4);
        assert!((Vec3::from_slice(&c.lower_left[..3]) - Vec3::new(-10.0, -5.0, 0.0)).length() < 1e-4);
        assert_eq!(c.u, [1.0, 0.0, 0.0, 0.25]);
        assert_eq!(c.v, [0.0, 1.0, 0.0, 0.0]);
        assert_eq!(
            (f.width, f.height, f.max_depth, f.seed, f.exposure),
            (200, 100, 16, 0, 1.0)
        );
        assert_eq!(f.flags, FLAG_MIS | FLAG_RUSSIAN_ROULETTE | FLAG_BVH | FLAG_GAMMA2);
        assert_eq!((f.n_tris, f.n_prims, f.n_lights), (24, 25, 13));
    }
}
