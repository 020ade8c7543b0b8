//! glTF 2.0 (`.gltf` JSON with its buffers, or binary `.glb`) read with the `gltf` crate.
//!
//! The default scene (else the first) is walked from its root nodes, each node's local matrix
//! composed with its parents'. Every mesh is parsed once, each primitive in TRIANGLES mode
//! (indexed or not) becoming one model-space mesh; a node that shows it adds one object per
//! primitive. Where the node's world matrix is a translation, rotation and positive scale, the
//! object shares the mesh and carries that transform; otherwise (shear from a non-uniform scale
//! above a rotation, or a mirror) the world matrix is baked into a copy of the triangles, the
//! winding reversed under a mirror so that the front face stays the front face.
//!
//! Materials become the renderer's metallic-roughness kind (`MaterialKind::Pbr`, docs/scenes.md,
//! "Model files"): `baseColorFactor`, `metallicFactor`, `roughnessFactor`, the
//! `KHR_materials_ior` index (else 1.5), `emissiveFactor` times
//! `KHR_materials_emissive_strength` the emission; `KHR_materials_transmission` of at least 0.5
//! makes smooth glass; a material that only emits is `Emissive`; a primitive without a material
//! is grey diffuse. `alphaMode` MASK (with `alphaCutoff`) and BLEND keep the base colour's
//! alpha factor and texture for `shared::alpha`: rays pass through the holes (BLEND as
//! stochastic transparency).
//! The first perspective camera met in the walk is the scene's camera.
//!
//! Vertex normals (NORMAL) and texture coordinates (TEXCOORD_0) are read; a primitive
//! without normals is shaded flat, as the specification asks.
//!
//! Warnings, each once a file: missing texture images, other primitive modes, unusable
//! punctual lights, skins, animations, morph targets and extensions that are ignored. Required extensions the renderer does not understand, unreadable
//! buffers, accessors that point outside their data and out-of-range indices are errors.
use super::{default_material, to_material, unique_name, Model};
use crate::scene::texture::Sampler;
use crate::scene::{attrs, material, Animation, CameraSpec, Mesh, SceneError, SceneObject, Shape, Transform};
use base64::Engine;
use glam::{EulerRot, Mat3, Mat4, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};
use gltf::{Accessor, Document, Gltf};
use shared::types::{
    Material, MaterialKind, PunctualLight, Triangle, VertexAttrs, LIGHT_DIRECTIONAL, LIGHT_POINT, LIGHT_SPOT,
};
use shared::types::{ALPHA_BLEND, ALPHA_MASK, ALPHA_OPAQUE, TEX_BASE_COLOR, TEX_EMISSIVE, TEX_METAL_ROUGH, TEX_NORMAL};
use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use std::sync::Arc;

/// Extensions whose data the importer uses.
const SUPPORTED: [&str; 5] = [
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_texture_transform",
    "KHR_lights_punctual",
];

/// Extensions a file may require whose absence costs only textures: images in these formats
/// are not decoded, each a warning and a material without that texture.
const REQUIRED_OK: [&str; 3] = ["KHR_texture_basisu", "EXT_texture_webp", "MSFT_texture_dds"];

/// Reads the glTF or GLB file at `path` (named `file` in messages).
pub(super) fn load(path: &Path, file: &str) -> Result<Model, SceneError> {
    let error = |message: String| SceneError::Model {
        file: file.to_string(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|e| error(format!("cannot read the file: {e}")))?;
    let gltf = Gltf::from_slice_without_validation(&bytes).map_err(|e| error(parse_error(&bytes, &e)))?;
    let unknown: Vec<&str> = gltf
        .document
        .extensions_required()
        .filter(|e| !SUPPORTED.contains(e) && !REQUIRED_OK.contains(e))
        .collect();
    if !unknown.is_empty() {
        return Err(error(format!(
            "the file requires glTF extensions the renderer does not support: {}",
            unknown.join(", ")
        )));
    }
    let Gltf { document, blob } = gltf;
    let document = Document::from_json(document.into_json()).map_err(|e| error(format!("{e}")))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let buffers = load_buffers(&document, blob, dir).map_err(error)?;
    let mut walk = Walk {
        file,
        dir,
        buffers: &buffers,
        model: Model::default(),
        parsed: HashMap::new(),
        materials: HashMap::new(),
        skipped_modes: BTreeSet::new(),
        morph_targets: false,
        unusable_lights: 0,
        other_uv_sets: false,
    };
    document_warnings(&document, file, &mut walk.model);
    walk.scene(&document).map_err(error)?;
    Ok(walk.finish())
}

/// The parser's error, with where it happened: JSON errors carry their line and column.
fn parse_error(bytes: &[u8], e: &gltf::Error) -> String {
    match e {
        gltf::Error::Deserialize(json) => format!("invalid glTF JSON: {json}"),
        gltf::Error::Binary(_) => format!("invalid binary glTF (GLB) of {} bytes: {e}", bytes.len()),
        _ => format!("{e}"),
    }
}

/// Every buffer's bytes: the GLB's binary chunk, a base64 `data:` URI or a file beside the
/// model; each at least as long as the file says.
fn load_buffers(document: &Document, mut blob: Option<Vec<u8>>, dir: &Path) -> Result<Vec<Vec<u8>>, String> {
    let mut out = Vec::new();
    for buffer in document.buffers() {
        let label = match buffer.name() {
            Some(n) => format!("buffer {} (\"{n}\")", buffer.index()),
            None => format!("buffer {}", buffer.index()),
        };
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob
                .take()
                .ok_or_else(|| format!("{label} is the binary chunk, which the file does not have"))?,
            gltf::buffer::Source::Uri(uri) => read_uri(uri, dir).map_err(|e| format!("{label}: {e}"))?,
        };
        if data.len() < buffer.length() {
            return Err(format!(
                "{label} holds {} bytes but the file says {} (truncated?)",
                data.len(),
                buffer.length()
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// The bytes of a glTF URI: a base64 `data:` URI, or a relative path (percent-encoded).
fn read_uri(uri: &str, dir: &Path) -> Result<Vec<u8>, String> {
    if let Some(data) = uri.strip_prefix("data:") {
        let (_, payload) = data
            .split_once(";base64,")
            .ok_or_else(|| "a data: URI that is not base64".to_string())?;
        return base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| format!("bad base64 in the data: URI: {e}"));
    }
    let path = uri_path(uri, dir)?;
    std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// The file a relative URI names, beside the model.
fn uri_path(uri: &str, dir: &Path) -> Result<std::path::PathBuf, String> {
    if uri.contains("://") {
        return Err(format!(
            "\"{uri}\": only files beside the model and data: URIs are read"
        ));
    }
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| format!("\"{uri}\" is not valid UTF-8 once percent-decoded"))?;
    Ok(dir.join(decoded.as_ref()))
}

/// Warnings about what the document holds that the renderer ignores.
fn document_warnings(document: &Document, file: &str, model: &mut Model) {
    let warnings = &mut model.warnings;
    let ignored: Vec<&str> = document.extensions_used().filter(|e| !SUPPORTED.contains(e)).collect();
    if !ignored.is_empty() {
        warnings.push(format!(
            "{file}: glTF extensions not supported, ignored: {}",
            ignored.join(", ")
        ));
    }
    let warnings = &mut model.warnings;
    if document.skins().len() > 0 {
        warnings.push(format!(
            "{file}: skins are not supported: skinned meshes are shown as their nodes place them"
        ));
    }
    if document.animations().len() > 0 {
        warnings.push(format!(
            "{file}: animations are not supported: the scene is shown at rest"
        ));
    }
}

/// The renderer's material for glTF material `m` (mapping in the module header).
fn material_of(m: &gltf::Material) -> Material {
    let pbr = m.pbr_metallic_roughness();
    let [r, g, b, a] = pbr.base_color_factor();
    let strength = m.emissive_strength().unwrap_or(1.0);
    let emission = m.emissive_factor().map(|e| e * strength);
    let transmission = m.transmission().map_or(0.0, |t| t.transmission_factor());
    let ior = m.ior().filter(|&n| n >= 1.0 && n.is_finite()).unwrap_or(1.5);
    if transmission >= 0.5 {
        return to_material([r, g, b], emission, None, Some(ior));
    }
    let base = to_material([r, g, b], emission, None, None);
    if base.kind == MaterialKind::Emissive as u32 {
        return base;
    }
    let unit = |x: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
    let (alpha_mode, alpha_cutoff) = match m.alpha_mode() {
        gltf::material::AlphaMode::Opaque => (ALPHA_OPAQUE, 0.0),
        gltf::material::AlphaMode::Mask => (ALPHA_MASK, m.alpha_cutoff().unwrap_or(0.5)),
        gltf::material::AlphaMode::Blend => (ALPHA_BLEND, 0.0),
    };
    Material {
        emission: base.emission,
        alpha_mode,
        alpha_cutoff,
        alpha: unit(a),
        ..material::pbr(
            [base.albedo[0], base.albedo[1], base.albedo[2]],
            unit(pbr.metallic_factor()),
            unit(pbr.roughness_factor()),
            ior,
        )
    }
}

/// Checks that `accessor` holds `count` items of one of `types` with `dims`, densely readable
/// from its buffer view, which lies inside its buffer.
fn check_accessor(
    accessor: &Accessor,
    types: &[DataType],
    dims: Dimensions,
    buffers: &[Vec<u8>],
) -> Result<(), String> {
    let label = format!("accessor {}", accessor.index());
    if accessor.sparse().is_some() {
        return Err(format!("{label}: sparse accessors are not supported"));
    }
    if !types.contains(&accessor.data_type()) || accessor.dimensions() != dims {
        return Err(format!(
            "{label} holds {:?} {:?}, expected {dims:?} of {types:?}",
            accessor.dimensions(),
            accessor.data_type()
        ));
    }
    if accessor.count() == 0 {
        return Err(format!("{label} holds no items"));
    }
    let view = accessor.view().ok_or_else(|| format!("{label} has no buffer view"))?;
    let size = accessor.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(format!(
            "{label}: byte stride {stride} is smaller than an item ({size} bytes)"
        ));
    }
    let end = stride
        .checked_mul(accessor.count() - 1)
        .and_then(|x| x.checked_add(size))
        .and_then(|x| x.checked_add(accessor.offset()));
    if end.is_none_or(|end| end > view.length()) {
        return Err(format!(
            "{label}: {} items from byte {} reach past the end of buffer view {} ({} bytes)",
            accessor.count(),
            accessor.offset(),
            view.index(),
            view.length()
        ));
    }
    let data = buffers.get(view.buffer().index()).map_or(0, |b| b.len());
    if view.offset().checked_add(view.length()).is_none_or(|end| end > data) {
        return Err(format!(
            "buffer view {} reaches past the end of buffer {} ({data} bytes)",
            view.index(),
            view.buffer().index()
        ));
    }
    Ok(())
}

/// The triangles of a TRIANGLES-mode primitive in model space.
/// The triangles of `primitive` and their vertex attributes (NORMAL, TEXCOORD_0; empty where
/// it has neither).
fn triangles(primitive: &gltf::Primitive, buffers: &[Vec<u8>]) -> Result<(Vec<Triangle>, Vec<VertexAttrs>), String> {
    let positions = primitive
        .get(&Semantic::Positions)
        .ok_or_else(|| "has no POSITION attribute".to_string())?;
    check_accessor(&positions, &[DataType::F32], Dimensions::Vec3, buffers)
        .map_err(|e| format!("POSITION: {e} (quantised positions, KHR_mesh_quantization, are not supported)"))?;
    if let Some(indices) = primitive.indices() {
        check_accessor(
            &indices,
            &[DataType::U8, DataType::U16, DataType::U32],
            Dimensions::Scalar,
            buffers,
        )
        .map_err(|e| format!("indices: {e}"))?;
    }
    if let Some(normals) = primitive.get(&Semantic::Normals) {
        check_accessor(&normals, &[DataType::F32], Dimensions::Vec3, buffers).map_err(|e| format!("NORMAL: {e}"))?;
    }
    if let Some(uvs) = primitive.get(&Semantic::TexCoords(0)) {
        check_accessor(
            &uvs,
            &[DataType::F32, DataType::U8, DataType::U16],
            Dimensions::Vec2,
            buffers,
        )
        .map_err(|e| format!("TEXCOORD_0: {e}"))?;
    }
    let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let points: Vec<[f32; 3]> = reader
        .read_positions()
        .ok_or_else(|| "POSITION cannot be read".to_string())?
        .collect();
    if let Some(k) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(format!("vertex {k} has a non-finite coordinate ({:?})", points[k]));
    }
    let indices: Vec<u32> = match reader.read_indices() {
        Some(i) => i.into_u32().collect(),
        None if primitive.indices().is_some() => return Err("indices cannot be read".to_string()),
        None => (0..points.len() as u32).collect(),
    };
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= points.len()) {
        return Err(format!("index {bad} refers past the last of {} vertices", points.len()));
    }
    let corner = |i: u32| {
        let p = points[i as usize];
        [p[0], p[1], p[2], 0.0]
    };
    let faces = indices.as_chunks::<3>().0;
    let tris = faces
        .iter()
        .map(|f| Triangle {
            v0: corner(f[0]),
            v1: corner(f[1]),
            v2: corner(f[2]),
        })
        .collect();
    // Attributes of another length than POSITION's are unusable: the triangles shade flat.
    let n = points.len();
    let normals: Option<Vec<[f32; 3]>> = reader
        .read_normals()
        .map(|v| v.collect::<Vec<_>>())
        .filter(|v| v.len() == n);
    let uvs: Option<Vec<[f32; 2]>> = reader
        .read_tex_coords(0)
        .map(|t| t.into_f32().collect::<Vec<_>>())
        .filter(|v| v.len() == n);
    let attrs = match (&normals, &uvs) {
        (None, None) => Vec::new(),
        _ => attrs::from_vertices(faces, normals.as_deref(), uvs.as_deref()),
    };
    Ok((tris, attrs))
}

/// The transform equal to `world` (translation, rotation, positive scale), if there is one.
pub(super) fn as_transform(world: Mat4) -> Option<Transform> {
    let (scale, rotation, translation) = world.to_scale_rotation_translation();
    if !(scale.is_finite() && scale.min_element() > 0.0 && translation.is_finite()) {
        return None;
    }
    let (y, x, z) = rotation.to_euler(EulerRot::YXZ);
    let t = Transform::new(translation, Vec3::new(x, y, z).map(f32::to_degrees), scale);
    let again = Mat4::from(t.matrix());
    let tolerance = 1e-5 * world.abs().to_cols_array().iter().fold(1.0f32, |m, &x| m.max(x));
    let same = (again - world).abs().to_cols_array().iter().all(|&d| d <= tolerance);
    same.then_some(t)
}

/// A primitive parsed once, shown by every node that uses its mesh.
struct Parsed {
    name: String,
    tris: Arc<Vec<Triangle>>,
    attrs: Arc<Vec<VertexAttrs>>,
    material: u32,
    /// Its index in the model's meshes, once an object shares it.
    mesh: Option<usize>,
}

/// The walk over the scene's nodes, collecting the model.
struct Walk<'a> {
    file: &'a str,
    /// The folder of the file (for images beside it).
    dir: &'a Path,
    buffers: &'a [Vec<u8>],
    model: Model,
    /// Parsed primitives by mesh index.
    parsed: HashMap<usize, Vec<Parsed>>,
    /// The model's material index by glTF material index (`None`: the default material).
    materials: HashMap<Option<usize>, u32>,
    skipped_modes: BTreeSet<String>,
    morph_targets: bool,
    unusable_lights: usize,
    /// A texture read texture coordinates other than TEXCOORD_0.
    other_uv_sets: bool,
}

impl Walk<'_> {
    /// Walks the default scene (else the first, else every root node).
    fn scene(&mut self, document: &Document) -> Result<(), String> {
        let roots: Vec<gltf::Node> = match document.default_scene().or_else(|| document.scenes().next()) {
            Some(scene) => scene.nodes().collect(),
            None => {
                let children: BTreeSet<usize> =
                    document.nodes().flat_map(|n| n.children().map(|c| c.index())).collect();
                self.model
                    .warnings
                    .push(format!("{}: the file has no scene: showing every root node", self.file));
                document.nodes().filter(|n| !children.contains(&n.index())).collect()
            }
        };
        let mut visited = vec![false; document.nodes().len()];
        let mut stack: Vec<(gltf::Node, Mat4)> = roots.into_iter().rev().map(|n| (n, Mat4::IDENTITY)).collect();
        while let Some((node, parent)) = stack.pop() {
            if std::mem::replace(&mut visited[node.index()], true) {
                return Err(format!(
                    "node {} is reached twice: the node hierarchy is not a tree",
                    node.index()
                ));
            }
            let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                self.instance(&node, &mesh, world)?;
            }
            if let Some(camera) = node.camera() {
                self.camera(&camera, world);
            }
            if let Some(light) = node.light() {
                self.light(&light, world);
            }
            stack.extend(
                node.children()
                    .collect::<Vec<_>>()
                    .into_iter()
                    .rev()
                    .map(|c| (c, world)),
            );
        }
        Ok(())
    }

    /// The model's index of the material of `primitive`, added on first use.
    fn material(&mut self, primitive: &gltf::Primitive) -> u32 {
        let m = primitive.material();
        if let Some(&i) = self.materials.get(&m.index()) {
            return i;
        }
        let (name, material) = match m.index() {
            Some(i) => {
                let mut material = material_of(&m);
                self.textures_of(&m, &mut material);
                (m.name().map_or(format!("material {i}"), str::to_string), material)
            }
            None => ("default".to_string(), default_material()),
        };
        let name = unique_name(&self.model.materials, &name);
        self.model.materials.push((name, material));
        let index = self.model.materials.len() as u32 - 1;
        self.materials.insert(m.index(), index);
        index
    }

    /// Gives `material` the textures of glTF material `m`: base colour and emissive (sRGB),
    /// metallic-roughness and normal (linear), and the base colour's `KHR_texture_transform`
    /// for all of them. Occlusion is not read: the path tracer finds occlusion itself.
    fn textures_of(&mut self, m: &gltf::Material, material: &mut Material) {
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_texture();
        if let Some(info) = &base {
            if let Some(t) = info.texture_transform() {
                let (s, c) = t.rotation().sin_cos();
                let ([ox, oy], [sx, sy]) = (t.offset(), t.scale());
                material.uv_delta = [[sx * c - 1.0, -sy * s, ox, 0.0], [sx * s, sy * c - 1.0, oy, 0.0]];
            }
        }
        let slot = |info: Option<(gltf::Texture, u32)>, srgb: bool, walk: &mut Walk| -> u32 {
            let Some((texture, set)) = info else { return 0 };
            if set != 0 {
                walk.other_uv_sets = true;
                return 0;
            }
            walk.texture(&texture, srgb).map_or(0, |i| i + 1)
        };
        material.textures[TEX_BASE_COLOR] = slot(base.map(|i| (i.texture(), i.tex_coord())), true, self);
        material.textures[TEX_METAL_ROUGH] = slot(
            pbr.metallic_roughness_texture().map(|i| (i.texture(), i.tex_coord())),
            false,
            self,
        );
        material.textures[TEX_EMISSIVE] = slot(m.emissive_texture().map(|i| (i.texture(), i.tex_coord())), true, self);
        if let Some(normal) = m.normal_texture() {
            material.normal_scale = normal.scale();
            material.textures[TEX_NORMAL] = slot(Some((normal.texture(), normal.tex_coord())), false, self);
        }
        // The emissive texture multiplies the emissive factor (black by default).
        if material.textures[TEX_EMISSIVE] != 0 && material.emission[..3] == [0.0; 3] {
            material.textures[TEX_EMISSIVE] = 0;
        }
    }

    /// The texture set's index of glTF texture `t` read as sRGB or linear (added once; a
    /// missing or undecodable image is a warning and no texture).
    fn texture(&mut self, t: &gltf::Texture, srgb: bool) -> Option<u32> {
        let sampler = Sampler::from_gltf(&t.sampler());
        let Some(image) = t.source() else {
            self.model
                .material_warnings
                .push(format!("{}: texture {} has no image: no texture", self.file, t.index()));
            return None;
        };
        let name = format!(
            "{}: image {}",
            self.file,
            image.name().map_or(image.index().to_string(), str::to_string)
        );
        let warnings = &mut self.model.material_warnings;
        match image.source() {
            gltf::image::Source::View { view, mime_type } => {
                let bytes = self
                    .buffers
                    .get(view.buffer().index())
                    .and_then(|b| b.get(view.offset()..view.offset() + view.length()));
                match bytes {
                    Some(bytes) => {
                        self.model
                            .textures
                            .add_bytes(bytes, Some(mime_type), &name, srgb, sampler, warnings)
                    }
                    None => {
                        warnings.push(format!("{name}: its buffer view lies outside its buffer: no texture"));
                        None
                    }
                }
            }
            gltf::image::Source::Uri { uri, mime_type } if uri.starts_with("data:") => match read_uri(uri, self.dir) {
                Ok(bytes) => self
                    .model
                    .textures
                    .add_bytes(&bytes, mime_type, &name, srgb, sampler, warnings),
                Err(e) => {
                    warnings.push(format!("{name}: {e}: no texture"));
                    None
                }
            },
            gltf::image::Source::Uri { uri, .. } => match uri_path(uri, self.dir) {
                Ok(path) => self.model.textures.add_file(&path, srgb, sampler, warnings),
                Err(e) => {
                    warnings.push(format!("{name}: {e}: no texture"));
                    None
                }
            },
        }
    }

    /// Parses the primitives of `mesh` (once).
    fn parse(&mut self, mesh: &gltf::Mesh) -> Result<(), String> {
        if self.parsed.contains_key(&mesh.index()) {
            return Ok(());
        }
        let mesh_name = mesh.name().map_or(format!("mesh {}", mesh.index()), str::to_string);
        let mut out = Vec::new();
        for primitive in mesh.primitives() {
            if primitive.mode() != Mode::Triangles {
                self.skipped_modes.insert(format!("{:?}", primitive.mode()));
                continue;
            }
            self.morph_targets |= primitive.morph_targets().len() > 0;
            let label = format!("{mesh_name}, primitive {}", primitive.index());
            let (tris, attrs) = triangles(&primitive, self.buffers).map_err(|e| format!("{label}: {e}"))?;
            if tris.is_empty() {
                continue;
            }
            let material = self.material(&primitive);
            let name = if mesh.primitives().len() > 1 {
                label
            } else {
                mesh_name.clone()
            };
            out.push(Parsed {
                name,
                tris: Arc::new(tris),
                attrs: Arc::new(attrs),
                material,
                mesh: None,
            });
        }
        self.parsed.insert(mesh.index(), out);
        Ok(())
    }

    /// Adds the objects of `node`, which shows `mesh` with the matrix `world`.
    fn instance(&mut self, node: &gltf::Node, mesh: &gltf::Mesh, world: Mat4) -> Result<(), String> {
        self.parse(mesh)?;
        let node_name = node.name().map_or(format!("node {}", node.index()), str::to_string);
        let transform = as_transform(world);
        let mirrored = world.determinant() < 0.0;
        let Some(parsed) = self.parsed.get_mut(&mesh.index()) else {
            return Ok(());
        };
        for p in parsed.iter_mut() {
            let (shape, transform) = match transform {
                Some(t) => {
                    let index = *p.mesh.get_or_insert_with(|| {
                        self.model.meshes.push(Mesh {
                            name: format!("{}#{}", self.file, p.name),
                            tris: p.tris.clone(),
                            attrs: p.attrs.clone(),
                        });
                        self.model.meshes.len() - 1
                    });
                    (Shape::Mesh(index), t)
                }
                None => {
                    let at = |v: [f32; 4]| {
                        let w = world.transform_point3(Vec3::new(v[0], v[1], v[2]));
                        [w.x, w.y, w.z, 0.0]
                    };
                    let baked = p
                        .tris
                        .iter()
                        .map(|t| match mirrored {
                            false => Triangle {
                                v0: at(t.v0),
                                v1: at(t.v1),
                                v2: at(t.v2),
                            },
                            true => Triangle {
                                v0: at(t.v0),
                                v1: at(t.v2),
                                v2: at(t.v1),
                            },
                        })
                        .collect();
                    let linear = Mat3::from_mat4(world);
                    self.model.meshes.push(Mesh {
                        name: format!("{}#{} at {node_name}", self.file, p.name),
                        tris: Arc::new(baked),
                        attrs: Arc::new(attrs::transformed(&p.attrs, linear, mirrored)),
                    });
                    (Shape::Mesh(self.model.meshes.len() - 1), Transform::IDENTITY)
                }
            };
            self.model.objects.push(SceneObject {
                name: format!("{node_name}: {}", p.name),
                shape,
                transform,
                material: p.material,
                animation: Animation::default(),
                instance: None,
            });
        }
        Ok(())
    }

    /// Adds punctual light `light` placed by the node matrix `world`: it sits at the node's
    /// origin and shines along the node's -z. glTF gives point and spot lights in candela and
    /// directional ones in lux; the renderer takes those numbers as radiant intensity and
    /// irradiance (one unit of radiance per candela), times the colour. `range` is ignored
    /// (the specification allows that: it only bounds the light's influence).
    fn light(&mut self, light: &gltf::khr_lights_punctual::Light, world: Mat4) {
        use gltf::khr_lights_punctual::Kind;
        let position = world.transform_point3(Vec3::ZERO);
        let direction = world.transform_vector3(-Vec3::Z).normalize_or_zero();
        let color = Vec3::from(light.color()) * light.intensity();
        let (kind, cos_outer, cos_inner) = match light.kind() {
            Kind::Point => (LIGHT_POINT, -1.0, -1.0),
            Kind::Directional => (LIGHT_DIRECTIONAL, -1.0, -1.0),
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => (LIGHT_SPOT, outer_cone_angle.cos(), inner_cone_angle.cos()),
        };
        let usable = position.is_finite()
            && direction != Vec3::ZERO
            && color.is_finite()
            && color.min_element() >= 0.0
            && cos_outer.is_finite()
            && cos_inner.is_finite();
        if !usable {
            self.unusable_lights += 1;
            return;
        }
        self.model.punctual.push(PunctualLight {
            position: [position.x, position.y, position.z, 0.0],
            direction: [direction.x, direction.y, direction.z, cos_outer],
            intensity: [color.x, color.y, color.z, cos_inner],
            kind,
            _pad: [0; 3],
        });
    }

    /// Takes the first usable perspective camera.
    fn camera(&mut self, camera: &gltf::Camera, world: Mat4) {
        if self.model.camera.is_some() {
            return;
        }
        let gltf::camera::Projection::Perspective(p) = camera.projection() else {
            return;
        };
        let position = world.transform_point3(Vec3::ZERO);
        let forward = world.transform_vector3(-Vec3::Z).normalize_or_zero();
        let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
        let vfov_deg = p.yfov().to_degrees();
        let usable = position.is_finite()
            && forward != Vec3::ZERO
            && up.cross(forward).length() > 1e-3
            && vfov_deg > 0.0
            && vfov_deg < 180.0;
        if !usable {
            self.model.warnings.push(format!(
                "{}: camera {} is degenerate (yfov {}, or a zero or skewed matrix): not used",
                self.file,
                camera.index(),
                p.yfov()
            ));
            return;
        }
        self.model.camera = Some(CameraSpec {
            position,
            look_at: position + forward,
            up,
            vfov_deg,
            aperture: 0.0,
            focus_distance: None,
        });
    }

    /// The model, with the warnings the walk collected.
    fn finish(mut self) -> Model {
        // A mesh several nodes show is instanced in a scene of two levels (each node an
        // instance of it); the renderer's rule decides for the rest.
        let mut uses = vec![0usize; self.model.meshes.len()];
        for o in &self.model.objects {
            if let Shape::Mesh(m) = o.shape {
                uses[m] += 1;
            }
        }
        for o in &mut self.model.objects {
            if matches!(o.shape, Shape::Mesh(m) if uses[m] > 1) {
                o.instance = Some(true);
            }
        }
        let file = self.file;
        let w = &mut self.model.warnings;
        if !self.skipped_modes.is_empty() {
            let modes: Vec<String> = self.skipped_modes.into_iter().collect();
            w.push(format!(
                "{file}: only TRIANGLES primitives are rendered: skipped primitives in mode {}",
                modes.join(", ")
            ));
        }
        if self.morph_targets {
            w.push(format!(
                "{file}: morph targets are not supported: the base shape is shown"
            ));
        }
        if self.other_uv_sets {
            self.model.material_warnings.push(format!(
                "{file}: textures on texture coordinate sets other than TEXCOORD_0 are not supported: left out"
            ));
        }
        let w = &mut self.model.warnings;
        if self.unusable_lights > 0 {
            w.push(format!(
                "{file}: {} punctual lights (KHR_lights_punctual) have a non-finite or negative colour, intensity or range, or a degenerate node transform: ignored",
                self.unusable_lights
            ));
        }
        self.model
    }
}
