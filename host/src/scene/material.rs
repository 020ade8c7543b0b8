//! Material constructors, one per [`MaterialKind`], and the kinds' names in scene files.
use shared::types::{Material, MaterialKind};

fn rgb(c: [f32; 3]) -> [f32; 4] {
    [c[0], c[1], c[2], 0.0]
}

/// A Lambertian reflector.
pub fn diffuse(albedo: [f32; 3]) -> Material {
    Material {
        albedo: rgb(albedo),
        kind: MaterialKind::Diffuse as u32,
        ..Default::default()
    }
}

/// A mirror tinted by `albedo`, blurred by `roughness` in `[0, 1]`.
pub fn metal(albedo: [f32; 3], roughness: f32) -> Material {
    Material {
        albedo: rgb(albedo),
        kind: MaterialKind::Metal as u32,
        roughness,
        ..Default::default()
    }
}

/// Clear glass with index of refraction `ior`.
pub fn dielectric(ior: f32) -> Material {
    Material {
        albedo: [1.0, 1.0, 1.0, 0.0],
        kind: MaterialKind::Dielectric as u32,
        ior,
        ..Default::default()
    }
}

/// A light that emits `emission` and scatters nothing.
pub fn emissive(emission: [f32; 3]) -> Material {
    Material {
        emission: rgb(emission),
        kind: MaterialKind::Emissive as u32,
        ..Default::default()
    }
}

/// glTF's metallic-roughness material: base colour, metallic in `[0, 1]`, perceptual
/// roughness in `[0, 1]`, and the dielectric's index of refraction (1.5 in glTF).
pub fn pbr(base_color: [f32; 3], metallic: f32, roughness: f32, ior: f32) -> Material {
    Material {
        albedo: rgb(base_color),
        kind: MaterialKind::Pbr as u32,
        metallic,
        roughness,
        ior,
        alpha: 1.0,
        normal_scale: 1.0,
        ..Default::default()
    }
}

/// The kind called `name` in scene files: "diffuse", "metal", "dielectric", "emissive" or
/// "pbr".
pub fn kind_from_name(name: &str) -> Option<MaterialKind> {
    match name {
        "pbr" => Some(MaterialKind::Pbr),
        "diffuse" => Some(MaterialKind::Diffuse),
        "metal" => Some(MaterialKind::Metal),
        "dielectric" => Some(MaterialKind::Dielectric),
        "emissive" => Some(MaterialKind::Emissive),
        _ => None,
    }
}

/// Whether `m` emits light (any emission component above zero).
pub fn emits(m: &Material) -> bool {
    m.emission[..3].iter().any(|&e| e > 0.0)
}
