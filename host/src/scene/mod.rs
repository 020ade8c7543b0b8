//! Scenes: objects (triangle meshes and spheres, each with a transform, a material and an
//! animation), a camera and render settings. A scene comes from a TOML file (docs/scenes.md) or
//! is built in ([`Scene::BUILTINS`]); [`Scene::gpu_data`] flattens it into the render buffers
//! for one moment in time and [`Scene::frame`] gives the camera and settings.
//!
//! Meshes are stored once in model space and shared by the objects that use them; the GPU data
//! copies them per object (instances duplicate triangles) and gives every object its matrix.
pub mod attrs;
mod builtin;
pub mod envmap;
mod error;
mod format;
mod gpu;
pub mod material;
pub mod model;
pub mod shapes;
pub mod texture;
mod transform;
mod validate;

pub use error::SceneError;
pub use gpu::{auto_instances, Instancing, InstancingMode, SceneGpu, AUTO_FLAT_SLOWER, AUTO_MIN_SAVED, MAX_FLATTENED};
pub use transform::{Animation, Bob, Orbit, Transform, Wave};

use glam::Vec3;
use shared::types::{Material, PunctualLight, Triangle, VertexAttrs};
use std::path::Path;
use std::sync::Arc;

/// A scene ready to render: materials and meshes, the objects that use them, camera, settings.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub camera: CameraSpec,
    pub settings: Settings,
    /// Materials with their names; objects refer to them by index.
    pub materials: Vec<(String, Material)>,
    pub meshes: Vec<Mesh>,
    pub objects: Vec<SceneObject>,
    /// Point, spot and directional lights, in world space.
    pub punctual: Vec<PunctualLight>,
    /// An HDR environment map lighting the scene instead of the sky gradient.
    pub environment: Option<Environment>,
    /// Every texture the materials use (`Material::textures` indexes them).
    pub textures: Arc<texture::TextureSet>,
}

/// An environment map as a scene uses it.
#[derive(Clone, Debug)]
pub struct Environment {
    pub map: Arc<envmap::EnvMap>,
    /// Turn about `+y`, in degrees.
    pub rotation_deg: f32,
    /// Factor on the map's radiance.
    pub intensity: f32,
}

impl Environment {
    /// Loads the map at `path` (see [`envmap::EnvMap::load`]), turned by `rotation_deg` and
    /// scaled by `intensity` (finite; intensity at least 0), with its warnings.
    pub fn load(path: &Path, rotation_deg: f32, intensity: f32) -> Result<(Environment, Vec<String>), SceneError> {
        let invalid = |problem: &str| SceneError::Environment {
            file: path.display().to_string(),
            message: problem.to_string(),
        };
        if !rotation_deg.is_finite() {
            return Err(invalid("the rotation must be a finite number of degrees"));
        }
        if !(intensity.is_finite() && intensity >= 0.0) {
            return Err(invalid("the intensity must be a finite number at least 0"));
        }
        let (map, warnings) = envmap::EnvMap::load(path)?;
        Ok((
            Environment {
                map: Arc::new(map),
                rotation_deg,
                intensity,
            },
            warnings,
        ))
    }
}

/// A triangle mesh in model space (`w` components 0), shared by every object that shows it.
#[derive(Clone)]
pub struct Mesh {
    /// The path or `builtin:` name it was loaded from.
    pub name: String,
    pub tris: Arc<Vec<Triangle>>,
    /// Shading normals and texture coordinates, one per triangle, or empty: flat, untextured.
    pub attrs: Arc<Vec<VertexAttrs>>,
}

impl Mesh {
    /// A mesh without vertex attributes.
    pub fn flat(name: impl Into<String>, tris: Vec<Triangle>) -> Mesh {
        Mesh {
            name: name.into(),
            tris: Arc::new(tris),
            attrs: Arc::default(),
        }
    }
}

impl std::fmt::Debug for Mesh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Mesh {{ name: {:?}, tris: {} triangles }}",
            self.name,
            self.tris.len()
        )
    }
}

/// One object: a shape placed by a transform, made of a material, maybe animated.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneObject {
    pub name: String,
    pub shape: Shape,
    pub transform: Transform,
    /// Index into [`Scene::materials`].
    pub material: u32,
    pub animation: Animation,
    /// Whether a scene of two levels shows the object as an instance of its mesh
    /// (`instance = true` in TOML) or in the world-space group transformed every frame
    /// (`false`); `None`: the renderer decides (`Scene::gpu_data_for`).
    pub instance: Option<bool>,
}

impl SceneObject {
    /// The base transform with the animation applied at `time_s` seconds.
    pub fn transform_at(&self, time_s: f32) -> Transform {
        self.animation.apply(self.transform, time_s)
    }
}

/// What an object is made of.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// The mesh at this index of [`Scene::meshes`].
    Mesh(usize),
    /// A sphere of `radius` around the model-space origin.
    Sphere { radius: f32 },
}

/// Render settings of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Bounces per path.
    pub max_depth: u32,
    /// Next-event estimation: sample a light at every bounce.
    pub nee: bool,
    /// Weight light and BSDF samples by multiple importance sampling.
    pub mis: bool,
    pub russian_roulette: bool,
    /// Radiance is multiplied by this before display.
    pub exposure: f32,
    /// Display with gamma 1/2 (the thesis) instead of the sRGB curve.
    pub gamma2: bool,
    /// Radiance of rays leaving the scene straight up and straight down (blended between).
    pub sky_top: Vec3,
    pub sky_bottom: Vec3,
    pub seed: u32,
}

impl Default for Settings {
    fn default() -> Settings {
        Settings {
            width: 800,
            height: 800,
            spp: 32,
            max_depth: 16,
            nee: true,
            mis: true,
            russian_roulette: true,
            exposure: 1.0,
            gamma2: false,
            sky_top: Vec3::ZERO,
            sky_bottom: Vec3::ZERO,
            seed: 0,
        }
    }
}

/// A thin-lens camera (a pinhole when `aperture` is 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    pub position: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees, in `(0, 180)`.
    pub vfov_deg: f32,
    /// Lens diameter.
    pub aperture: f32,
    /// Distance of the plane in focus; `None`: the distance to `look_at`.
    pub focus_distance: Option<f32>,
}

impl Scene {
    /// Names accepted by [`Scene::builtin`].
    pub const BUILTINS: [&'static str; 7] = ["cornell", "suzanne", "bunny", "spheres", "instances", "herd", "forest"];

    /// The built-in scene `name`; meshes come from [`crate::inputs::assets_dir`].
    pub fn builtin(name: &str) -> Result<Scene, SceneError> {
        builtin::build(name)
    }

    /// Reads a TOML scene file; mesh paths are relative to the file's folder. Warnings (what a
    /// mesh file holds that the renderer ignores) are printed to stderr.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Scene::load_with_warnings(path).map(print_warnings)
    }

    /// [`Scene::load`], returning the warnings instead of printing them.
    pub fn load_with_warnings(path: &Path) -> Result<(Scene, Vec<String>), SceneError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|error| SceneError::Read {
            file: file.clone(),
            error,
        })?;
        let base_dir = path.parent().unwrap_or(Path::new(""));
        format::parse(&text, &file, base_dir)
    }

    /// Parses TOML scene text; errors name `file_label`, mesh paths are relative to `base_dir`.
    /// Warnings are printed to stderr.
    pub fn from_toml_str(text: &str, file_label: &str, base_dir: &Path) -> Result<Scene, SceneError> {
        format::parse(text, file_label, base_dir).map(print_warnings)
    }

    /// Opens a model file ([`model::EXTENSIONS`]) as a scene: the file's objects, materials and
    /// camera, with a camera framing the model if the file has none, the default sky, and a
    /// key light if nothing in it emits. The warnings say what was ignored or assumed.
    pub fn from_model(path: &Path) -> Result<(Scene, Vec<String>), SceneError> {
        let file = path.display().to_string();
        let name = path
            .file_stem()
            .map_or(file.clone(), |s| s.to_string_lossy().into_owned());
        let (scene, warnings) = model::load(path)?.into_scene(&name, &file);
        validate::check(&scene, &file)?;
        Ok((scene, warnings))
    }

    /// A built-in scene if `name_or_path` is one of [`Scene::BUILTINS`], else a model file (by
    /// its extension, [`model::EXTENSIONS`]) or a TOML scene file. Warnings are printed to
    /// stderr.
    pub fn open(name_or_path: &str) -> Result<Scene, SceneError> {
        Scene::open_with_warnings(name_or_path).map(print_warnings)
    }

    /// [`Scene::open`], returning the warnings instead of printing them.
    pub fn open_with_warnings(name_or_path: &str) -> Result<(Scene, Vec<String>), SceneError> {
        if Scene::BUILTINS.contains(&name_or_path) {
            return Ok((Scene::builtin(name_or_path)?, Vec::new()));
        }
        let path = Path::new(name_or_path);
        if !path.exists() {
            return Err(SceneError::NotFound {
                name: name_or_path.to_string(),
            });
        }
        if model::is_model(path) {
            return Scene::from_model(path);
        }
        Scene::load_with_warnings(path)
    }

    /// Number of triangles (every mesh object's, instances counted again) and of spheres.
    pub fn counts(&self) -> (usize, usize) {
        let mut tris = 0;
        let mut spheres = 0;
        for o in &self.objects {
            match o.shape {
                Shape::Mesh(m) => tris += self.meshes.get(m).map_or(0, |m| m.tris.len()),
                Shape::Sphere { .. } => spheres += 1,
            }
        }
        (tris, spheres)
    }

    /// Index of the material called `name`.
    pub fn material_index(&self, name: &str) -> Option<u32> {
        self.materials.iter().position(|(n, _)| n == name).map(|i| i as u32)
    }
}

/// Prints each warning to stderr and hands the scene on.
fn print_warnings((scene, warnings): (Scene, Vec<String>)) -> Scene {
    for w in warnings {
        eprintln!("warning: {w}");
    }
    scene
}
