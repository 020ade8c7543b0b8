//! Wavefront OBJ with its MTL material libraries, parsed by tobj (polygons triangulated).
//! Faces are grouped by material (`usemtl`): one mesh and one object per material used.
//!
//! MTL materials become the renderer's kinds (docs/scenes.md, "Model files"):
//! - `Kd` is the albedo, `Ke` the emission (on any kind; emitting with a black `Kd`: emissive);
//! - glass (dielectric) when `d` < 1 (or `Tr` > 0) or `illum` is 4, 6 or 7: `Ni` is the index
//!   of refraction where above 1 (else 1.5), `Tf` the tint (else white);
//! - metal when `Pm` >= 0.5 (albedo `Kd`), `illum` is 3, or `Ks` is at least 0.5 and stronger
//!   than `Kd` (albedo `Ks`); roughness `Pr`, else from the Phong exponent `Ns` as
//!   `sqrt(2 / (Ns + 2))` (the Beckmann slope of the same highlight), else 0;
//! - everything else diffuse.
//!
//! A material library that is missing or malformed, and a `usemtl` of an undefined material,
//! is a warning: those faces get a grey diffuse. OBJ syntax errors name the line.
use super::{default_material, to_material, unique_name, Model};
use crate::scene::texture::Sampler;
use crate::scene::{attrs, Animation, Mesh, SceneError, SceneObject, Shape, Transform};
use indexmap::IndexMap;
use shared::types::{Material, Triangle, VertexAttrs, TEX_BASE_COLOR};
use std::cell::RefCell;
use std::collections::HashSet;
use std::io::{BufRead, Read};
use std::path::Path;
use std::sync::Arc;

/// A `BufRead` over bytes that hands them out a line at a time and counts the lines started,
/// so that when tobj stops at an error, `line` is the line it stopped on.
struct CountingLines<'a> {
    rest: &'a [u8],
    line: usize,
    at_line_start: bool,
}

impl<'a> CountingLines<'a> {
    fn new(bytes: &'a [u8]) -> CountingLines<'a> {
        CountingLines {
            rest: bytes,
            line: 0,
            at_line_start: true,
        }
    }
}

impl Read for CountingLines<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(buf.len());
        buf[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl BufRead for CountingLines<'_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.at_line_start && !self.rest.is_empty() {
            self.line += 1;
            self.at_line_start = false;
        }
        let end = self
            .rest
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.rest.len(), |i| i + 1);
        Ok(&self.rest[..end])
    }

    fn consume(&mut self, amount: usize) {
        let amount = amount.min(self.rest.len());
        if self.rest[..amount].ends_with(b"\n") {
            self.at_line_start = true;
        }
        self.rest = &self.rest[amount..];
    }
}

/// `line N ("text"): ` for line `n` (1-based) of `bytes`, the text cut to 60 characters.
fn at_line(bytes: &[u8], n: usize) -> String {
    let text = bytes
        .split(|&b| b == b'\n')
        .nth(n.saturating_sub(1))
        .unwrap_or_default();
    let text = String::from_utf8_lossy(text);
    let text = text.trim();
    let shown: String = text.chars().take(60).collect();
    let more = if shown.len() < text.len() { "..." } else { "" };
    format!("line {n} (\"{shown}{more}\"): ")
}

/// What tobj's error means, for people.
fn describe(e: &tobj::LoadError) -> String {
    match e {
        tobj::LoadError::ReadError => "not UTF-8 text (is this an OBJ file?)".to_string(),
        tobj::LoadError::FaceVertexOutOfBounds => "a face refers to a vertex that does not exist".to_string(),
        other => other.to_string(),
    }
}

/// The first face line of the OBJ text whose vertex, texture or normal index points nowhere:
/// OBJ indices count from 1 (negative: back from the last one read so far).
fn bad_face_line(text: &[u8]) -> Option<usize> {
    let mut counts = [0i64; 3];
    for (k, line) in text.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => counts[0] += 1,
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("f") => {
                for vertex in words {
                    for (slot, index) in vertex.split('/').enumerate().take(3) {
                        if index.is_empty() {
                            continue;
                        }
                        let ok = index
                            .parse::<i64>()
                            .is_ok_and(|i| (i > 0 && i <= counts[slot]) || (i < 0 && -i <= counts[slot]));
                        if !ok {
                            return Some(k + 1);
                        }
                    }
                }
            }
            _ => {}
        }
    }
    None
}

/// The first `v` line with a NaN or infinite coordinate.
fn non_finite_vertex_line(text: &[u8]) -> Option<usize> {
    text.split(|&b| b == b'\n')
        .position(|line| {
            let line = String::from_utf8_lossy(line);
            let mut words = line.split_whitespace();
            words.next() == Some("v") && words.take(3).any(|w| w.parse::<f32>().is_ok_and(|x| !x.is_finite()))
        })
        .map(|k| k + 1)
}

/// The names after `usemtl` in the OBJ text, in order of first use.
fn used_material_names(text: &[u8]) -> Vec<String> {
    let mut seen = HashSet::new();
    let mut names = Vec::new();
    for line in text.split(|&b| b == b'\n') {
        let line = String::from_utf8_lossy(line);
        if let Some(name) = line.trim().strip_prefix("usemtl") {
            let name = name.trim().to_string();
            if !name.is_empty() && seen.insert(name.clone()) {
                names.push(name);
            }
        }
    }
    names
}

/// The renderer's material for MTL material `m` (mapping in the module header).
fn mtl_material(m: &tobj::Material) -> Material {
    let kd = m.diffuse.unwrap_or([0.8; 3]);
    let ks = m.specular.unwrap_or([0.0; 3]);
    let ke = m.emissive.unwrap_or([0.0; 3]);
    let number = |key: &str| m.unknown_param.get(key).and_then(|v| v.trim().parse::<f32>().ok());
    let tf = m.unknown_param.get("Tf").and_then(|v| {
        let c: Vec<f32> = v.split_whitespace().filter_map(|w| w.parse().ok()).collect();
        match c[..] {
            [r, g, b] => Some([r, g, b]),
            [x] => Some([x; 3]),
            _ => None,
        }
    });
    let dissolve = m.dissolve.or_else(|| number("Tr").map(|t| 1.0 - t));
    let illum = m.illumination_model;
    let glass = dissolve.is_some_and(|d| d < 1.0) || matches!(illum, Some(4 | 6 | 7));
    let strongest = |c: [f32; 3]| c.into_iter().fold(0.0f32, f32::max);
    let pbr_metal = number("Pm").is_some_and(|p| p >= 0.5);
    let specular_metal = strongest(ks) >= 0.5 && strongest(ks) > strongest(kd);
    let metal = !glass && (pbr_metal || illum == Some(3) || specular_metal);
    let roughness = number("Pr")
        .or(m.shininess.map(|ns| (2.0 / (ns.max(0.0) + 2.0)).sqrt()))
        .unwrap_or(0.0);
    let ior = m.optical_density.filter(|&n| n > 1.0 && n.is_finite()).unwrap_or(1.5);
    if glass {
        to_material(tf.unwrap_or([1.0; 3]), ke, None, Some(ior))
    } else if metal {
        let albedo = if pbr_metal || strongest(ks) == 0.0 { kd } else { ks };
        to_material(albedo, ke, Some(roughness), None)
    } else {
        to_material(kd, ke, None, None)
    }
}

/// Reads the OBJ file at `path` (named `file` in messages) and its material libraries.
pub(super) fn load(path: &Path, file: &str) -> Result<Model, SceneError> {
    let error = |message: String| SceneError::Model {
        file: file.to_string(),
        message,
    };
    let text = std::fs::read(path).map_err(|e| error(format!("cannot read the file: {e}")))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let warnings = RefCell::new(Vec::new());
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let mut reader = CountingLines::new(&text);
    let loaded = tobj::load_obj_buf(&mut reader, &options, |library: &Path| {
        let mtl = dir.join(library);
        let bytes = std::fs::read(&mtl).map_err(|e| {
            warnings.borrow_mut().push(format!(
                "{file}: cannot read the material library {}: {e}; its materials are grey diffuse",
                mtl.display()
            ));
            tobj::LoadError::OpenFileFailed
        })?;
        let mut lines = CountingLines::new(&bytes);
        tobj::load_mtl_buf(&mut lines).inspect_err(|e| {
            warnings.borrow_mut().push(format!(
                "{file}: material library {}: {}{}; its materials are grey diffuse",
                mtl.display(),
                at_line(&bytes, lines.line),
                describe(e)
            ));
        })
    });
    let (models, libraries) = loaded.map_err(|e| {
        let line = match e {
            tobj::LoadError::FaceVertexOutOfBounds => bad_face_line(&text).unwrap_or(reader.line),
            _ => reader.line,
        };
        error(format!("{}{}", at_line(&text, line), describe(&e)))
    })?;
    let libraries = libraries.unwrap_or_default();
    let mut warnings = warnings.into_inner();
    let libraries_read = warnings.is_empty();
    for name in used_material_names(&text).into_iter().filter(|_| libraries_read) {
        if !libraries.iter().any(|m| m.name == name) {
            warnings.push(format!(
                "{file}: usemtl {name}: no material library defines it; its faces are grey diffuse"
            ));
        }
    }
    let textured: Vec<&str> = libraries
        .iter()
        .filter(|m| {
            m.ambient_texture.is_some()
                || m.specular_texture.is_some()
                || m.normal_texture.is_some()
                || m.shininess_texture.is_some()
                || m.dissolve_texture.is_some()
        })
        .map(|m| m.name.as_str())
        .collect();
    if !textured.is_empty() {
        warnings.push(format!(
            "{file}: textures other than map_Kd are not supported and are ignored (materials {})",
            textured.join(", ")
        ));
    }

    // Triangles grouped by material, in order of first use.
    let mut groups: IndexMap<Option<usize>, (Vec<Triangle>, Vec<VertexAttrs>)> = IndexMap::new();
    for m in &models {
        let pos = &m.mesh.positions;
        if pos.iter().any(|x| !x.is_finite()) {
            let line = non_finite_vertex_line(&text)
                .map(|n| at_line(&text, n))
                .unwrap_or_default();
            return Err(error(format!(
                "{line}a vertex has a non-finite coordinate (NaN or infinite)"
            )));
        }
        let vertex = |i: u32| {
            let i = i as usize * 3;
            pos.get(i..i + 3).map(|p| [p[0], p[1], p[2], 0.0])
        };
        let material = m.mesh.material_id.filter(|&i| i < libraries.len());
        let (tris, attrs) = groups.entry(material).or_default();
        let faces = m.mesh.indices.as_chunks::<3>().0;
        for f in faces {
            match (vertex(f[0]), vertex(f[1]), vertex(f[2])) {
                (Some(v0), Some(v1), Some(v2)) => tris.push(Triangle { v0, v1, v2 }),
                _ => return Err(error("a face refers to a vertex that does not exist".to_string())),
            }
        }
        // With one index per vertex, normals and texture coordinates follow the positions'.
        let normals = m.mesh.normals.as_chunks::<3>().0;
        let uvs = m.mesh.texcoords.as_chunks::<2>().0;
        let per_vertex = |n: usize| n * 3 == pos.len();
        let normals = per_vertex(normals.len()).then_some(normals);
        // OBJ's v points up the image; the renderer's (glTF's) down from its top row.
        let flipped: Vec<[f32; 2]> = uvs.iter().map(|t| [t[0], 1.0 - t[1]]).collect();
        let uvs = per_vertex(uvs.len()).then_some(flipped.as_slice());
        attrs.extend(attrs::from_vertices(faces, normals, uvs));
    }

    let mut model = Model {
        material_warnings: warnings,
        ..Model::default()
    };
    let stem = path
        .file_stem()
        .map_or(file.to_string(), |s| s.to_string_lossy().into_owned());
    for (material, (tris, attrs)) in groups {
        if tris.is_empty() {
            continue;
        }
        let (name, m) = match material {
            Some(i) => {
                let mut m = mtl_material(&libraries[i]);
                if let Some(map) = &libraries[i].diffuse_texture {
                    let t =
                        model
                            .textures
                            .add_file(&dir.join(map), true, Sampler::default(), &mut model.material_warnings);
                    m.textures[TEX_BASE_COLOR] = t.map_or(0, |t| t + 1);
                }
                (libraries[i].name.clone(), m)
            }
            None => ("default".to_string(), default_material()),
        };
        let name = unique_name(&model.materials, &name);
        model.materials.push((name.clone(), m));
        let attrs = if attrs::has_normals(&attrs) || attrs::has_uvs(&attrs) {
            attrs
        } else {
            Vec::new()
        };
        model.meshes.push(Mesh {
            name: format!("{file}#{name}"),
            tris: Arc::new(tris),
            attrs: Arc::new(attrs),
        });
        model.objects.push(SceneObject {
            name: format!("{stem}: {name}"),
            shape: Shape::Mesh(model.meshes.len() - 1),
            transform: Transform::IDENTITY,
            material: model.materials.len() as u32 - 1,
            animation: Animation::default(),
            instance: None,
        });
    }
    Ok(model)
}
