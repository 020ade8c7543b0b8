//! The TOML scene format (docs/scenes.md): the file's tables as serde structs (unknown fields
//! refused), then turned into a [`Scene`] with materials resolved by name and meshes loaded once
//! per path.
use super::attrs::{self, Normals};
use super::error::object_label;
use super::{
    material, model, shapes, validate, Animation, Bob, CameraSpec, Mesh, Orbit, Scene, SceneError, SceneObject,
    Settings, Shape, Transform, Wave,
};
use glam::Vec3;
use indexmap::IndexMap;
use serde::Deserialize;
use shared::types::{Material, MaterialKind};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: Option<String>,
    camera: CameraFile,
    #[serde(default)]
    render: RenderFile,
    /// In file order.
    #[serde(default)]
    materials: IndexMap<String, MaterialFile>,
    #[serde(default)]
    objects: Vec<ObjectFile>,
    environment: Option<EnvironmentFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvironmentFile {
    /// An equirectangular `.exr` or `.hdr`, relative to the scene file's folder.
    file: String,
    #[serde(default)]
    rotation: f32,
    #[serde(default = "one")]
    intensity: f32,
}

fn one() -> f32 {
    1.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    position: [f32; 3],
    look_at: [f32; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    #[serde(default = "default_vfov")]
    vfov: f32,
    #[serde(default)]
    aperture: f32,
    focus_distance: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn default_vfov() -> f32 {
    40.0
}

#[derive(Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderFile {
    width: Option<u32>,
    height: Option<u32>,
    spp: Option<u32>,
    depth: Option<u32>,
    nee: Option<bool>,
    mis: Option<bool>,
    russian_roulette: Option<bool>,
    exposure: Option<f32>,
    gamma: Option<String>,
    sky: Option<SkyFile>,
    seed: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SkyFile {
    #[serde(default)]
    top: [f32; 3],
    #[serde(default)]
    bottom: [f32; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialFile {
    kind: String,
    albedo: Option<[f32; 3]>,
    #[serde(default)]
    emission: [f32; 3],
    roughness: Option<f32>,
    ior: Option<f32>,
    metallic: Option<f32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectFile {
    name: Option<String>,
    mesh: Option<String>,
    sphere: Option<f32>,
    /// "auto" (default), "flat" or "smooth": a mesh's shading normals.
    normals: Option<String>,
    /// Degrees between faces up to which "smooth" joins them (default 60).
    crease_angle: Option<f32>,
    material: String,
    #[serde(default)]
    translate: [f32; 3],
    #[serde(default)]
    rotate: [f32; 3],
    scale: Option<ScaleFile>,
    #[serde(default)]
    animation: AnimationFile,
    /// In a scene of two levels: an instance of its mesh (true) or in the world-space group
    /// transformed every frame (false); absent: the renderer decides.
    instance: Option<bool>,
}

#[derive(Deserialize)]
#[serde(untagged, expecting = "scale must be a number or an array of three numbers")]
enum ScaleFile {
    Uniform(f32),
    PerAxis([f32; 3]),
}

#[derive(Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct AnimationFile {
    #[serde(default)]
    spin: [f32; 3],
    orbit: Option<OrbitFile>,
    bob: Option<BobFile>,
    wave: Option<WaveFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WaveFile {
    amplitude: f32,
    wavelength: f32,
    period: f32,
    #[serde(default)]
    heading: f32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OrbitFile {
    #[serde(default)]
    center: [f32; 3],
    radius: f32,
    period: f32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BobFile {
    amplitude: f32,
    period: f32,
}

/// The scene in TOML `text` and the warnings of its mesh files; `file` names it in errors, mesh
/// paths are relative to `base_dir`.
pub(super) fn parse(text: &str, file: &str, base_dir: &Path) -> Result<(Scene, Vec<String>), SceneError> {
    let doc: SceneFile = toml::from_str(text).map_err(|e| toml_error(file, text, &e))?;
    let mut materials = Vec::with_capacity(doc.materials.len());
    for (name, m) in &doc.materials {
        materials.push((name.clone(), to_material(file, name, m)?));
    }
    let mut meshes = MeshLoader {
        file,
        base_dir,
        meshes: Vec::new(),
        by_key: HashMap::new(),
        warnings: Vec::new(),
    };
    let mut objects = Vec::with_capacity(doc.objects.len());
    for (i, o) in doc.objects.iter().enumerate() {
        objects.push(to_object(file, i, o, &materials, &mut meshes)?);
    }
    let name = doc.name.unwrap_or_else(|| {
        Path::new(file)
            .file_stem()
            .map_or(file.to_string(), |s| s.to_string_lossy().into_owned())
    });
    let environment = match &doc.environment {
        Some(e) => {
            let (env, warnings) = super::Environment::load(&base_dir.join(&e.file), e.rotation, e.intensity)?;
            meshes.warnings.extend(warnings);
            Some(env)
        }
        None => None,
    };
    let scene = Scene {
        name,
        punctual: Vec::new(),
        environment,
        textures: Default::default(),
        camera: to_camera(&doc.camera),
        settings: to_settings(file, &doc.render)?,
        materials,
        meshes: meshes.meshes,
        objects,
    };
    validate::check(&scene, file)?;
    Ok((scene, meshes.warnings))
}

/// The toml error with its position turned into a line and column.
fn toml_error(file: &str, text: &str, e: &toml::de::Error) -> SceneError {
    let location = e
        .span()
        .and_then(|span| text.get(..span.start))
        .map(|before| {
            let line = before.matches('\n').count() + 1;
            let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            format!("line {line}, column {column}: ")
        })
        .unwrap_or_default();
    SceneError::Toml {
        file: file.to_string(),
        location,
        message: e.message().trim_end().to_string(),
    }
}

fn to_material(file: &str, name: &str, m: &MaterialFile) -> Result<Material, SceneError> {
    let invalid = |problem: &str| SceneError::Invalid {
        file: file.to_string(),
        what: format!("material \"{name}\""),
        problem: problem.to_string(),
    };
    let kind = material::kind_from_name(&m.kind).ok_or_else(|| SceneError::UnknownKind {
        file: file.to_string(),
        material: name.to_string(),
        kind: m.kind.clone(),
    })?;
    let pbr = kind == MaterialKind::Pbr;
    if m.roughness.is_some() && kind != MaterialKind::Metal && !pbr {
        return Err(invalid("`roughness` applies to kinds \"metal\" and \"pbr\" only"));
    }
    if m.ior.is_some() && kind != MaterialKind::Dielectric && !pbr {
        return Err(invalid("`ior` applies to kinds \"dielectric\" and \"pbr\" only"));
    }
    if m.metallic.is_some() && !pbr {
        return Err(invalid("`metallic` applies to kind \"pbr\" only"));
    }
    let unit = |x: Option<f32>, what: &str| match x {
        Some(v) if !(0.0..=1.0).contains(&v) => Err(invalid(&format!("`{what}` must be in [0, 1]"))),
        _ => Ok(()),
    };
    unit(m.metallic, "metallic")?;
    if pbr {
        unit(m.roughness, "roughness")?;
    }
    let albedo = match (m.albedo, kind) {
        (Some(a), _) => a,
        (None, MaterialKind::Dielectric) => [1.0; 3],
        (None, MaterialKind::Emissive) => [0.0; 3],
        (None, _) => return Err(invalid("kinds \"diffuse\", \"metal\" and \"pbr\" need an `albedo`")),
    };
    let ior = match kind {
        MaterialKind::Dielectric | MaterialKind::Pbr => m.ior.unwrap_or(1.5),
        _ => 0.0,
    };
    Ok(Material {
        albedo: [albedo[0], albedo[1], albedo[2], 0.0],
        emission: [m.emission[0], m.emission[1], m.emission[2], 0.0],
        kind: kind as u32,
        roughness: m.roughness.unwrap_or(if pbr { 0.5 } else { 0.0 }),
        ior,
        metallic: m.metallic.unwrap_or(0.0),
        ..Default::default()
    })
}

/// Loads each mesh path (or `builtin:` name) once and hands out its index. A model file's
/// objects are merged into one mesh in the file's world space.
struct MeshLoader<'a> {
    file: &'a str,
    base_dir: &'a Path,
    meshes: Vec<Mesh>,
    by_key: HashMap<String, usize>,
    /// What the model files hold that the renderer ignores (their materials aside: the
    /// scene's material replaces them).
    warnings: Vec<String>,
}

impl MeshLoader<'_> {
    /// Index of mesh `spec` (a path relative to the scene's folder, or `builtin:NAME`), loaded on
    /// first use; errors name `object`, the object that wants it.
    fn get(&mut self, object: &str, spec: &str, normals: Normals) -> Result<usize, SceneError> {
        let builtin = spec.strip_prefix("builtin:");
        let path = self.base_dir.join(spec);
        let key = match builtin {
            Some(_) => spec.to_string(),
            None => format!("{} {normals:?}", path.display()),
        };
        if let Some(&i) = self.by_key.get(&key) {
            return Ok(i);
        }
        let error = |message: String| SceneError::Mesh {
            file: self.file.to_string(),
            object: object.to_string(),
            mesh: spec.to_string(),
            message,
        };
        let (tris, attrs) = match builtin {
            Some(name) => {
                let tris = shapes::by_name(name).ok_or_else(|| {
                    error(format!(
                        "no such built-in mesh (built-in meshes: builtin:{})",
                        shapes::NAMES.join(", builtin:")
                    ))
                })?;
                (tris, Vec::new())
            }
            None => {
                let loaded = model::load_with(&path, normals).map_err(|e| error(e.to_string()))?;
                self.warnings.extend(loaded.warnings.iter().cloned());
                (loaded.world_triangles(), loaded.world_attrs())
            }
        };
        self.meshes.push(Mesh {
            name: spec.to_string(),
            tris: Arc::new(tris),
            attrs: Arc::new(attrs),
        });
        self.by_key.insert(key, self.meshes.len() - 1);
        Ok(self.meshes.len() - 1)
    }
}

fn to_object(
    file: &str,
    index: usize,
    o: &ObjectFile,
    materials: &[(String, Material)],
    meshes: &mut MeshLoader,
) -> Result<SceneObject, SceneError> {
    let default_name = match (&o.mesh, o.sphere) {
        (Some(path), _) => Path::new(path.trim_start_matches("builtin:"))
            .file_stem()
            .map_or(path.clone(), |s| s.to_string_lossy().into_owned()),
        _ => "sphere".to_string(),
    };
    let name = o.name.clone().unwrap_or(default_name);
    let label = object_label(index, &name);
    let invalid = |problem: &str| SceneError::Invalid {
        file: file.to_string(),
        what: label.clone(),
        problem: problem.to_string(),
    };
    let shape = match (&o.mesh, o.sphere) {
        (Some(path), None) => {
            let normals = match (o.normals.as_deref(), o.crease_angle) {
                (None | Some("auto"), None) => Normals::Auto,
                (Some("flat"), None) => Normals::Flat,
                (Some("smooth"), crease) => {
                    let crease_deg = crease.unwrap_or(attrs::DEFAULT_CREASE_DEG);
                    if !(0.0..=180.0).contains(&crease_deg) {
                        return Err(invalid("crease_angle must be between 0 and 180 degrees"));
                    }
                    Normals::Smooth { crease_deg }
                }
                (Some(other), None) if other != "auto" && other != "flat" => {
                    return Err(invalid(&format!(
                        "normals = {other:?}: write \"auto\", \"flat\" or \"smooth\""
                    )))
                }
                _ => return Err(invalid("crease_angle goes with normals = \"smooth\"")),
            };
            Shape::Mesh(meshes.get(&label, path, normals)?)
        }
        (None, Some(radius)) => Shape::Sphere { radius },
        (Some(_), Some(_)) => return Err(invalid("give either `mesh` or `sphere`, not both")),
        (None, None) => return Err(invalid("needs a `mesh` or a `sphere`")),
    };
    let material = materials
        .iter()
        .position(|(n, _)| *n == o.material)
        .ok_or_else(|| SceneError::UnknownMaterial {
            file: file.to_string(),
            object: label.clone(),
            material: o.material.clone(),
            known: known_names(materials),
        })? as u32;
    let scale = match o.scale {
        None => Vec3::ONE,
        Some(ScaleFile::Uniform(s)) => Vec3::splat(s),
        Some(ScaleFile::PerAxis(s)) => Vec3::from(s),
    };
    let a = &o.animation;
    Ok(SceneObject {
        name,
        shape,
        transform: Transform::new(o.translate.into(), o.rotate.into(), scale),
        material,
        animation: Animation {
            spin_deg_per_s: a.spin.into(),
            orbit: a.orbit.as_ref().map(|o| Orbit {
                center: o.center.into(),
                radius: o.radius,
                period_s: o.period,
            }),
            bob: a.bob.as_ref().map(|b| Bob {
                amplitude: b.amplitude,
                period_s: b.period,
            }),
            wave: a.wave.as_ref().map(|w| Wave {
                amplitude: w.amplitude,
                wavelength: w.wavelength,
                period_s: w.period,
                heading_deg: w.heading,
            }),
        },
        instance: o.instance,
    })
}

fn known_names(materials: &[(String, Material)]) -> String {
    if materials.is_empty() {
        return "none".to_string();
    }
    let names: Vec<String> = materials.iter().map(|(n, _)| format!("\"{n}\"")).collect();
    names.join(", ")
}

fn to_camera(c: &CameraFile) -> CameraSpec {
    CameraSpec {
        position: c.position.into(),
        look_at: c.look_at.into(),
        up: c.up.into(),
        vfov_deg: c.vfov,
        aperture: c.aperture,
        focus_distance: c.focus_distance,
    }
}

fn to_settings(file: &str, r: &RenderFile) -> Result<Settings, SceneError> {
    let d = Settings::default();
    let gamma2 = match r.gamma.as_deref() {
        None | Some("srgb") => false,
        Some("2.0") => true,
        Some(other) => {
            return Err(SceneError::Invalid {
                file: file.to_string(),
                what: "render".to_string(),
                problem: format!("gamma must be \"srgb\" or \"2.0\", got \"{other}\""),
            })
        }
    };
    Ok(Settings {
        width: r.width.unwrap_or(d.width),
        height: r.height.unwrap_or(d.height),
        spp: r.spp.unwrap_or(d.spp),
        max_depth: r.depth.unwrap_or(d.max_depth),
        nee: r.nee.unwrap_or(d.nee),
        mis: r.mis.unwrap_or(d.mis),
        russian_roulette: r.russian_roulette.unwrap_or(d.russian_roulette),
        exposure: r.exposure.unwrap_or(d.exposure),
        gamma2,
        sky_top: r.sky.as_ref().map_or(d.sky_top, |s| s.top.into()),
        sky_bottom: r.sky.as_ref().map_or(d.sky_bottom, |s| s.bottom.into()),
        seed: r.seed.unwrap_or(d.seed),
    })
}

#[cfg(test)]
mod tests;
