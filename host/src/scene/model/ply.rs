//! PLY (Stanford polygon files, ASCII or binary) read with the `ply-rs-bw` crate: the `vertex`
//! element's `x`, `y`, `z` and the `face` element's `vertex_indices` (or `vertex_index`)
//! lists, polygons split into triangle fans; vertex normals (`nx`, `ny`, `nz`) and texture
//! coordinates (`u`, `v` or `s`, `t`) where present. PLY has no materials: the mesh is grey
//! diffuse. Vertex colours are ignored with a warning.
use super::{default_material, Model};
use crate::scene::{Animation, Mesh, SceneError, SceneObject, Shape, Transform};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use shared::types::Triangle;
use std::path::Path;
use std::sync::Arc;

/// The first of `keys` that vertex `v` has as a number.
fn first_number(v: &DefaultElement, keys: &[&str]) -> Option<f32> {
    keys.iter().find_map(|k| v.get(*k).and_then(number)).map(|x| x as f32)
}

/// A scalar property as a number.
fn number(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(x) => x.into(),
        Property::UChar(x) => x.into(),
        Property::Short(x) => x.into(),
        Property::UShort(x) => x.into(),
        Property::Int(x) => x.into(),
        Property::UInt(x) => x.into(),
        Property::Float(x) => x.into(),
        Property::Double(x) => x,
        _ => return None,
    })
}

/// A list property as integers.
fn indices(p: &Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUChar(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListShort(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUShort(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListInt(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUInt(v) => v.iter().map(|&x| x.into()).collect(),
        _ => return None,
    })
}

/// Reads the PLY file at `path` (named `file` in messages).
pub(super) fn load(path: &Path, file: &str) -> Result<Model, SceneError> {
    let error = |message: String| SceneError::Model {
        file: file.to_string(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|e| error(format!("cannot read the file: {e}")))?;
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut bytes.as_slice())
        .map_err(|e| error(format!("invalid PLY: {e}")))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| error("no \"vertex\" element".to_string()))?;
    let mut points = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let coordinate = |k: &str| v.get(k).and_then(number).map(|x| x as f32);
        let (Some(x), Some(y), Some(z)) = (coordinate("x"), coordinate("y"), coordinate("z")) else {
            return Err(error(format!("vertex {i} has no numeric x, y and z")));
        };
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(error(format!("vertex {i} has a non-finite coordinate ({x}, {y}, {z})")));
        }
        points.push([x, y, z, 0.0]);
    }
    let faces = ply
        .payload
        .get("face")
        .ok_or_else(|| error("no \"face\" element: point clouds cannot be rendered".to_string()))?;
    let mut tris = Vec::new();
    let mut corners = Vec::new();
    for (i, f) in faces.iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(indices)
            .ok_or_else(|| error(format!("face {i} has no vertex_indices list")))?;
        let index = |k: i64| {
            u32::try_from(k)
                .ok()
                .filter(|&k| (k as usize) < points.len())
                .ok_or_else(|| error(format!("face {i} refers to vertex {k}, which does not exist")))
        };
        for k in 2..list.len() {
            let c = [index(list[0])?, index(list[k - 1])?, index(list[k])?];
            let p = |j: usize| points[c[j] as usize];
            tris.push(Triangle {
                v0: p(0),
                v1: p(1),
                v2: p(2),
            });
            corners.push(c);
        }
    }
    let mut warnings = Vec::new();
    let has = |k: &str| vertices.first().is_some_and(|v| v.contains_key(k));
    let normals: Option<Vec<[f32; 3]>> = has("nx").then(|| {
        vertices
            .iter()
            .map(|v| [["nx"], ["ny"], ["nz"]].map(|k| first_number(v, &k).unwrap_or(f32::NAN)))
            .collect()
    });
    let uvs: Option<Vec<[f32; 2]>> = (has("u") || has("s")).then(|| {
        vertices
            .iter()
            .map(|v| [["u", "s"], ["v", "t"]].map(|k| first_number(v, &k).unwrap_or(0.0)))
            .collect()
    });
    let attrs = if normals.is_some() || uvs.is_some() {
        crate::scene::attrs::from_vertices(&corners, normals.as_deref(), uvs.as_deref())
    } else {
        Vec::new()
    };
    if has("red") || has("r") {
        warnings.push(format!(
            "{file}: vertex colours are not supported: the mesh is grey diffuse"
        ));
    }
    let name = path
        .file_stem()
        .map_or(file.to_string(), |s| s.to_string_lossy().into_owned());
    if tris.is_empty() {
        return Ok(Model {
            warnings,
            ..Model::default()
        });
    }
    Ok(Model {
        materials: vec![("default".to_string(), default_material())],
        meshes: vec![Mesh {
            name: file.to_string(),
            tris: Arc::new(tris),
            attrs: Arc::new(attrs),
        }],
        objects: vec![SceneObject {
            name,
            shape: Shape::Mesh(0),
            transform: Transform::IDENTITY,
            material: 0,
            animation: Animation::default(),
            instance: None,
        }],
        camera: None,
        punctual: Vec::new(),
        textures: Default::default(),
        warnings,
        material_warnings: Vec::new(),
    })
}
