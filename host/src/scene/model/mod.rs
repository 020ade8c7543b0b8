//! Model files users have: Wavefront OBJ (with its MTL materials), glTF 2.0 (`.gltf` with its
//! buffers, or binary `.glb`) and PLY, read into meshes, materials and objects
//! ([`Model`]). A model opened as a scene ([`Model::into_scene`]) gets what the file lacks:
//! a camera framing it, the default sky and a key light (`framing`); as a `mesh = "..."` of
//! a TOML scene its triangles are merged in the file's coordinates ([`Model::world_triangles`]).
//!
//! Vertex normals and texture coordinates come along as each mesh's `attrs`; an OBJ or PLY mesh
//! without normals gets smooth ones (`attrs::smooth` at `attrs::DEFAULT_CREASE_DEG`), a glTF
//! one stays flat as its specification asks.
//!
//! What a file holds that the renderer cannot show (textures, punctual lights,
//! primitives other than triangles, ...) is named in [`Model::warnings`], never silently dropped;
//! what makes a file unusable is a [`SceneError::Model`] naming the file and the problem.
mod framing;
mod gltf;
mod obj;
mod ply;

use super::attrs::{self, Normals};
use super::{CameraSpec, Mesh, Scene, SceneError, SceneObject, Settings, Shape};
use glam::{Mat3, Vec3};
use shared::types::{Material, MaterialKind, PunctualLight, Triangle, VertexAttrs};
use std::path::Path;
use std::sync::Arc;

/// Extensions (lower case, without the dot) of the model files [`load`] reads.
pub const EXTENSIONS: [&str; 4] = ["obj", "gltf", "glb", "ply"];

/// Whether `path` names a model file by its extension (any case).
pub fn is_model(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// What a model file holds, in the renderer's terms.
#[derive(Clone, Debug, Default)]
pub struct Model {
    /// Materials with their names; objects refer to them by index.
    pub materials: Vec<(String, Material)>,
    /// Model-space meshes; one may be shown by several objects.
    pub meshes: Vec<Mesh>,
    /// Every mesh object (`Shape::Mesh`), placed by its transform.
    pub objects: Vec<SceneObject>,
    /// The file's camera, if it has one the renderer can use.
    pub camera: Option<CameraSpec>,
    /// Its punctual lights in the file's world space.
    pub punctual: Vec<PunctualLight>,
    /// The textures its materials use.
    pub textures: super::texture::TextureSet,
    /// What was ignored, approximated or assumed, each naming the file.
    pub warnings: Vec<String>,
    /// The same about the file's materials (textures, missing material libraries), apart
    /// because a TOML scene replaces the materials of its mesh files.
    pub material_warnings: Vec<String>,
}

/// Reads the model file at `path`, chosen by its extension (see [`EXTENSIONS`]), with the
/// shading normals [`Normals::Auto`] gives.
pub fn load(path: &Path) -> Result<Model, SceneError> {
    load_with(path, Normals::Auto)
}

/// Reads the model file at `path` with the shading normals `normals` asks for.
pub fn load_with(path: &Path, normals: Normals) -> Result<Model, SceneError> {
    let file = path.display().to_string();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let mut model = match ext.as_str() {
        "obj" => obj::load(path, &file)?,
        "gltf" | "glb" => gltf::load(path, &file)?,
        "ply" => ply::load(path, &file)?,
        _ => {
            return Err(SceneError::Model {
                file,
                message: format!("not a model file (model files end in .{})", EXTENSIONS.join(", .")),
            })
        }
    };
    if model.objects.is_empty() {
        return Err(SceneError::Model {
            file,
            message: "the file has no triangles".to_string(),
        });
    }
    let crease = match normals {
        Normals::Auto if ext != "obj" && ext != "ply" => None,
        Normals::Auto => Some(attrs::DEFAULT_CREASE_DEG),
        Normals::Smooth { crease_deg } => Some(crease_deg),
        Normals::Flat => None,
    };
    for mesh in &mut model.meshes {
        let own = attrs::has_normals(&mesh.attrs);
        let computed = match crease {
            Some(c) if !own || normals != Normals::Auto => attrs::smooth(&mesh.tris, &mesh.attrs, c),
            _ if normals == Normals::Flat => mesh.attrs.iter().map(attrs::without_normals).collect(),
            _ => continue,
        };
        mesh.attrs = Arc::new(computed);
    }
    Ok(model)
}

impl Model {
    /// Every object's triangles moved to the file's world space, in object order.
    pub fn world_triangles(&self) -> Vec<Triangle> {
        let mut out = Vec::new();
        for o in &self.objects {
            if let Shape::Mesh(m) = o.shape {
                let matrix = o.transform.matrix();
                let p = |v: [f32; 4]| {
                    let w = matrix.transform_point3(Vec3::new(v[0], v[1], v[2]));
                    [w.x, w.y, w.z, 0.0]
                };
                out.extend(self.meshes[m].tris.iter().map(|t| Triangle {
                    v0: p(t.v0),
                    v1: p(t.v1),
                    v2: p(t.v2),
                }));
            }
        }
        out
    }

    /// The vertex attributes of [`Model::world_triangles`], in the same order (empty where
    /// no mesh has any).
    pub fn world_attrs(&self) -> Vec<VertexAttrs> {
        let shown = |o: &&SceneObject| matches!(o.shape, Shape::Mesh(m) if !self.meshes[m].attrs.is_empty());
        if !self.objects.iter().any(|o| shown(&o)) {
            return Vec::new();
        }
        let mut out = Vec::new();
        for o in &self.objects {
            if let Shape::Mesh(m) = o.shape {
                let mesh = &self.meshes[m];
                if mesh.attrs.len() == mesh.tris.len() {
                    let linear = Mat3::from(o.transform.matrix().matrix3);
                    out.extend(attrs::transformed(&mesh.attrs, linear, false));
                } else {
                    out.extend(std::iter::repeat_n(VertexAttrs::default(), mesh.tris.len()));
                }
            }
        }
        out
    }

    /// The model as a scene called `name`: its own camera or one framing it, the default sky,
    /// and a key light if nothing in it emits; what was assumed is added to the warnings.
    pub fn into_scene(self, name: &str, file: &str) -> (Scene, Vec<String>) {
        let settings = Settings {
            sky_top: framing::SKY_TOP,
            sky_bottom: framing::SKY_BOTTOM,
            ..Settings::default()
        };
        let mut scene = Scene {
            name: name.to_string(),
            punctual: self.punctual,
            environment: None,
            textures: Arc::new(self.textures),
            camera: self.camera.unwrap_or(framing::NO_CAMERA),
            settings,
            materials: self.materials,
            meshes: self.meshes,
            objects: self.objects,
        };
        let mut warnings = self.material_warnings;
        warnings.extend(self.warnings);
        framing::complete(&mut scene, self.camera.is_some(), file, &mut warnings);
        (scene, warnings)
    }
}

/// How file materials become the renderer's four kinds: `emission` on any kind; glass when
/// `glass_ior` is given, metal when `metal_roughness` is, else diffuse; a material that emits
/// and reflects nothing is `Emissive`. Colours are clamped to be finite and not negative.
pub(crate) fn to_material(
    albedo: [f32; 3],
    emission: [f32; 3],
    metal_roughness: Option<f32>,
    glass_ior: Option<f32>,
) -> Material {
    let clean = |c: [f32; 3]| c.map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 });
    let (albedo, emission) = (clean(albedo), clean(emission));
    let emits = emission.iter().any(|&e| e > 0.0);
    let mut m = if let Some(ior) = glass_ior {
        Material {
            albedo: [albedo[0], albedo[1], albedo[2], 0.0],
            ..super::material::dielectric(ior)
        }
    } else if let Some(r) = metal_roughness {
        super::material::metal(albedo, if r.is_finite() { r.clamp(0.0, 1.0) } else { 0.0 })
    } else if emits && albedo.iter().all(|&a| a == 0.0) {
        super::material::emissive(emission)
    } else {
        super::material::diffuse(albedo)
    };
    m.emission = [emission[0], emission[1], emission[2], 0.0];
    if m.kind != MaterialKind::Dielectric as u32 {
        m.ior = 0.0;
    }
    m
}

/// The grey diffuse that faces without a (usable) material get.
pub(crate) fn default_material() -> Material {
    super::material::diffuse([0.8, 0.8, 0.8])
}

/// `name`, or `name (2)`, `name (3)`, ... if `taken` already has it.
pub(crate) fn unique_name(taken: &[(String, Material)], name: &str) -> String {
    let free = |n: &str| !taken.iter().any(|(t, _)| t == n);
    if free(name) {
        return name.to_string();
    }
    (2..)
        .map(|k| format!("{name} ({k})"))
        .find(|n| free(n))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests;
