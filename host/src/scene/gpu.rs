//! A scene flattened into the render buffers (descriptor set 1 of `shared::types`) for one moment
//! in time, and its camera and settings as a [`Frame`].
//!
//! Primitives are every mesh object's triangles (objects in order, each object's mesh copied),
//! then every sphere object's sphere; all in model space, placed by their object's matrix.
use super::envmap::EnvMap;
use super::texture::TextureSet;
use super::{material, Scene, Shape};
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
}

impl SceneGpu {
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
                let t = o.transform_at(time_s);
                let m = t.matrix();
                let c = m.matrix3;
                let row = |r: usize| [c.x_axis[r], c.y_axis[r], c.z_axis[r], m.translation[r]];
                let n = super::attrs::cofactor(c.into());
                let normal_row = |r: usize| [n.x_axis[r], n.y_axis[r], n.z_axis[r], 0.0];
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
                Object {
                    rows: [row(0), row(1), row(2)],
                    normal_rows: [normal_row(0), normal_row(1), normal_row(2)],
                    radius_scale: t.scale.abs().max_element(),
                    material: o.material,
                    first_prim,
                    attrs,
                }
            })
            .collect()
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
        let bases = self.attr_bases();
        let mut attrs = Vec::new();
        for (m, base) in self.meshes.iter().zip(bases) {
            if base != INVALID {
                attrs.extend_from_slice(&m.attrs);
            }
        }
        SceneGpu {
            model_tris,
            model_spheres,
            prim_object,
            objects: self.objects_at(time_s),
            materials: self.materials.iter().map(|(_, m)| *m).collect(),
            lights,
            attrs,
            punctual: self.punctual.clone(),
            env: self.environment.as_ref().map(|e| e.map.clone()),
            textures: self.textures.clone(),
        }
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
            n_instances: 0,
            top_nodes: 0,
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
