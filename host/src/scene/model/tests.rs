//! Tests of the model importers: the glTF assets open with their triangle counts, a camera and
//! a light; OBJ materials split and map; the glTF node hierarchy lands where it should with each
//! mesh parsed once; and a corpus of broken files, each written here, gets an error (or a
//! warning) naming the file and the problem.
use super::super::{Scene, Shape};
use super::{load, Model};
use base64::Engine;
use glam::{Mat4, Quat, Vec3};
use shared::types::{MaterialKind, Triangle};
use std::path::{Path, PathBuf};

/// A fresh folder under the system's temporary folder.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("raytrace-model-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets")
}

/// Writes `files` (name, contents) into a fresh folder and loads the first.
fn load_written(dir_name: &str, files: &[(&str, &[u8])]) -> (PathBuf, Result<Model, String>) {
    let dir = temp_dir(dir_name);
    for (name, contents) in files {
        std::fs::write(dir.join(name), contents).unwrap();
    }
    let path = dir.join(files[0].0);
    let result = load(&path).map_err(|e| e.to_string());
    let _ = std::fs::remove_dir_all(&dir);
    (path, result)
}

/// The error of loading `files`, checked to name the first file and contain every `wanted`.
fn error_of(dir_name: &str, files: &[(&str, &[u8])], wanted: &[&str]) -> String {
    let (path, result) = load_written(dir_name, files);
    let message = result.map(|_| ()).unwrap_err();
    assert!(
        message.starts_with(&path.display().to_string()),
        "does not name the file: {message}"
    );
    for w in wanted {
        assert!(message.contains(w), "{w:?} missing from: {message}");
    }
    message
}

fn has_warning(warnings: &[String], wanted: &[&str]) -> bool {
    warnings.iter().any(|w| wanted.iter().all(|x| w.contains(x)))
}

fn albedo(m: &shared::types::Material) -> [f32; 3] {
    [m.albedo[0], m.albedo[1], m.albedo[2]]
}

/// Opens `path` as a scene and checks the automatic camera: it looks at the centre of the
/// bounds, and every vertex lies inside its vertical and horizontal field of view.
fn check_framed(scene: &Scene) {
    let c = scene.camera;
    let forward = (c.look_at - c.position).normalize();
    let half = (c.vfov_deg.to_radians() / 2.0).tan();
    for o in &scene.objects {
        if let Shape::Mesh(m) = o.shape {
            let matrix = o.transform.matrix();
            for v in scene.meshes[m].tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]) {
                let d = matrix.transform_point3(Vec3::new(v[0], v[1], v[2])) - c.position;
                let depth = d.dot(forward);
                assert!(depth > 0.0, "vertex behind the camera");
                let off_axis = (d - depth * forward).length();
                assert!(off_axis / depth < half, "vertex outside the view");
            }
        }
    }
}

#[test]
fn suzi_glb_opens_framed_and_lit() {
    let path = assets().join("suzi.glb");
    let (scene, warnings) = Scene::from_model(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.counts(), (14_842, 1), "the mesh and the key light");
    assert_eq!(scene.name, "suzi");
    check_framed(&scene);
    // Material "base" has no factors: the glTF defaults, white and fully metallic, rough.
    let (name, m) = &scene.materials[scene.objects[0].material as usize];
    assert_eq!(name, "base");
    assert_eq!(m.kind, MaterialKind::Pbr as u32);
    assert_eq!((albedo(m), m.metallic, m.roughness), ([1.0; 3], 1.0, 1.0));
    let light = scene.objects.last().unwrap();
    assert!(matches!(light.shape, Shape::Sphere { .. }));
    assert!(light.transform.translation.y > 0.6, "the key light is above the model");
    assert!(has_warning(&warnings, &["no camera"]), "{warnings:?}");
    assert!(has_warning(&warnings, &["key light"]), "{warnings:?}");
    // Its vertex normals shade it: every mesh has a normal at every corner.
    for m in &scene.meshes {
        assert_eq!(m.attrs.len(), m.tris.len(), "{}", m.name);
        assert!(m.attrs.iter().all(|a| a.normal_u.iter().all(|n| n[..3] != [0.0; 3])));
    }
    // The sky is set and the scene renders as a whole.
    assert!(scene.settings.sky_top.max_element() > 0.0);
    assert_eq!(scene.gpu_data(0.0).model_tris.len(), 14_842);
}

#[test]
fn pmndrs_glb_opens_with_its_texture() {
    let path = assets().join("pmndrs.glb");
    let (scene, warnings) = Scene::from_model(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.counts(), (1_552, 1));
    check_framed(&scene);
    let (_, m) = &scene.materials[scene.objects[0].material as usize];
    assert_eq!((m.kind, m.metallic), (MaterialKind::Pbr as u32, 0.0));
    // Its embedded base colour texture, decoded with a full mip chain, and UVs on the mesh.
    assert_eq!(m.textures[shared::types::TEX_BASE_COLOR], 1, "{warnings:?}");
    let t = scene.textures.infos[0];
    assert!(t.width > 1 && t.levels > 1, "{t:?}");
    assert!(scene
        .meshes
        .iter()
        .all(|mesh| crate::scene::attrs::has_uvs(&mesh.attrs)));
    assert!(!has_warning(&warnings, &["texture"]), "{warnings:?}");
    // Opening by path through the CLI's entry point gives the same scene.
    let (opened, _) = Scene::open_with_warnings(path.to_str().unwrap()).unwrap();
    assert_eq!(opened.counts(), scene.counts());
}

const TWO_MATERIALS_OBJ: &str = "mtllib two.mtl\n\
    v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n\
    usemtl red\nf 1 2 3 4\n\
    usemtl blue\nf 1 2 5\nf 2 6 5\n";

const TWO_MATERIALS_MTL: &str = "newmtl red\nKd 0.8 0.1 0.1\n\nnewmtl blue\nKd 0.1 0.2 0.9\n";

#[test]
fn obj_materials_split_into_one_object_each() {
    let (_, model) = load_written(
        "two",
        &[
            ("two.obj", TWO_MATERIALS_OBJ.as_bytes()),
            ("two.mtl", TWO_MATERIALS_MTL.as_bytes()),
        ],
    );
    let model = model.unwrap();
    assert!(model.warnings.is_empty() && model.material_warnings.is_empty());
    assert_eq!(model.objects.len(), 2);
    let red = &model.objects[0];
    let blue = &model.objects[1];
    let (red_name, red_m) = &model.materials[red.material as usize];
    let (blue_name, blue_m) = &model.materials[blue.material as usize];
    assert_eq!((red_name.as_str(), albedo(red_m)), ("red", [0.8, 0.1, 0.1]));
    assert_eq!((blue_name.as_str(), albedo(blue_m)), ("blue", [0.1, 0.2, 0.9]));
    assert_eq!(red_m.kind, MaterialKind::Diffuse as u32);
    // The quad is triangulated; each object has its own faces only.
    let tris = |o: &crate::scene::SceneObject| match o.shape {
        Shape::Mesh(m) => model.meshes[m].tris.len(),
        Shape::Sphere { .. } => 0,
    };
    assert_eq!((tris(red), tris(blue)), (2, 2));
}

#[test]
fn mtl_kinds_map_onto_the_renderer_kinds() {
    let mtl = "newmtl glass\nKd 0.9 0.9 0.9\nNi 1.33\nd 0.2\n\
        newmtl chrome\nKd 0.1 0.1 0.1\nKs 0.9 0.8 0.7\nNs 98\n\
        newmtl lamp\nKd 0 0 0\nKe 5 4 3\n\
        newmtl glowing\nKd 0.5 0.5 0.5\nKe 1 1 1\n\
        newmtl plastic\nKd 0.6 0.6 0.6\nKs 0.5 0.5 0.5\nNs 250\nillum 2\n";
    let mut obj = String::from("mtllib kinds.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for name in ["glass", "chrome", "lamp", "glowing", "plastic"] {
        obj.push_str(&format!("usemtl {name}\nf 1 2 3\n"));
    }
    let (_, model) = load_written("kinds", &[("kinds.obj", obj.as_bytes()), ("kinds.mtl", mtl.as_bytes())]);
    let model = model.unwrap();
    let m = |name: &str| model.materials.iter().find(|(n, _)| n == name).unwrap().1;
    let glass = m("glass");
    assert_eq!((glass.kind, glass.ior), (MaterialKind::Dielectric as u32, 1.33));
    let chrome = m("chrome");
    assert_eq!(chrome.kind, MaterialKind::Metal as u32);
    assert_eq!(albedo(&chrome), [0.9, 0.8, 0.7]);
    assert!((chrome.roughness - 0.1414).abs() < 1e-3, "sqrt(2 / 100)");
    let lamp = m("lamp");
    assert_eq!(lamp.kind, MaterialKind::Emissive as u32);
    assert_eq!(lamp.emission[..3], [5.0, 4.0, 3.0]);
    let glowing = m("glowing");
    assert_eq!((glowing.kind, glowing.emission[0]), (MaterialKind::Diffuse as u32, 1.0));
    assert_eq!(m("plastic").kind, MaterialKind::Diffuse as u32, "Ks weaker than Kd");
    assert_eq!(model.objects.len(), 5);
}

#[test]
fn missing_or_malformed_mtl_is_a_warning() {
    let (_, model) = load_written("nomtl", &[("two.obj", TWO_MATERIALS_OBJ.as_bytes())]);
    let model = model.unwrap();
    assert!(
        has_warning(
            &model.material_warnings,
            &["two.obj", "two.mtl", "cannot read", "grey diffuse"]
        ),
        "{:?}",
        model.material_warnings
    );
    assert_eq!(model.objects.len(), 1, "every face in the default material");
    assert_eq!(model.materials[0].0, "default");
    assert_eq!(albedo(&model.materials[0].1), [0.8; 3]);

    let bad_mtl = "newmtl red\nKd 0.8 zero 0.1\n";
    let (_, model) = load_written(
        "badmtl",
        &[
            ("two.obj", TWO_MATERIALS_OBJ.as_bytes()),
            ("two.mtl", bad_mtl.as_bytes()),
        ],
    );
    let model = model.unwrap();
    assert!(
        has_warning(&model.material_warnings, &["two.mtl", "line 2", "Kd 0.8 zero"]),
        "{:?}",
        model.material_warnings
    );
    assert_eq!(model.objects.len(), 1);

    // An undefined material is a warning too.
    let mtl = "newmtl red\nKd 1 0 0\n";
    let (_, model) = load_written(
        "undefined",
        &[("two.obj", TWO_MATERIALS_OBJ.as_bytes()), ("two.mtl", mtl.as_bytes())],
    );
    let model = model.unwrap();
    assert!(
        has_warning(&model.material_warnings, &["usemtl blue"]),
        "{:?}",
        model.material_warnings
    );
    assert_eq!(model.objects.len(), 2);
}

#[test]
fn bad_obj_files_name_the_line() {
    error_of(
        "objsyntax",
        &[("bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n")],
        &["line 3", "v 0 1 zero", "position"],
    );
    error_of(
        "objface",
        &[("bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n")],
        &["line 5", "f 1 2 9", "does not exist"],
    );
    error_of(
        "objnan",
        &[("bad.obj", b"v 0 0 0\nv NaN 0 0\nv 0 1 0\nf 1 2 3\n")],
        &["line 2", "non-finite"],
    );
    error_of("objempty", &[("empty.obj", b"# nothing\nv 0 0 0\n")], &["no triangles"]);
    error_of(
        "objbinary",
        &[("bin.obj", &[0xff, 0xfe, 0x00, 0x41, b'\n'])],
        &["line 1", "UTF-8"],
    );
}

/// A glTF file with one triangle (0,0,0), (1,0,0), (0,1,0) in a base64 buffer as mesh 0, and
/// `nodes` and `scenes` as given.
fn one_triangle_gltf(nodes: &str, extra: &str) -> String {
    let bytes: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "buffers": [{{"byteLength": 36, "uri": "data:application/octet-stream;base64,{data}"}}],
  "bufferViews": [{{"buffer": 0, "byteLength": 36}}],
  "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                  "min": [0, 0, 0], "max": [1, 1, 0]}}],
  "meshes": [{{"name": "tri", "primitives": [{{"attributes": {{"POSITION": 0}}}}]}}],
  "nodes": {nodes}{extra}
}}"#
    )
}

fn world(m: Mat4, tri: &Triangle) -> [Vec3; 3] {
    [tri.v0, tri.v1, tri.v2].map(|v| m.transform_point3(Vec3::new(v[0], v[1], v[2])))
}

fn close(a: [Vec3; 3], b: [Vec3; 3]) -> bool {
    a.iter().zip(&b).all(|(x, y)| (*x - *y).abs().max_element() < 1e-5)
}

#[test]
fn gltf_node_hierarchy_places_each_instance_and_parses_the_mesh_once() {
    // Node 0 is moved by 10 in x and holds node 1 (scaled by 2) and node 2 (moved 5 up), both
    // showing mesh 0. Node 3 scales y by 3 over node 4, turned 45 degrees about z: a shear,
    // baked into the triangles.
    let (s, c) = (22.5f32.to_radians().sin(), 22.5f32.to_radians().cos());
    let nodes = format!(
        r#"[
    {{"name": "parent", "translation": [10, 0, 0], "children": [1, 2]}},
    {{"name": "big", "scale": [2, 2, 2], "mesh": 0}},
    {{"name": "up", "translation": [0, 5, 0], "mesh": 0}},
    {{"name": "stretch", "scale": [1, 3, 1], "children": [4]}},
    {{"name": "turned", "rotation": [0, 0, {s}, {c}], "mesh": 0}}
  ],
  "scenes": [{{"nodes": [0, 3]}}],
  "scene": 0"#
    );
    let text = one_triangle_gltf(&nodes, "");
    let (_, model) = load_written("hierarchy", &[("tree.gltf", text.as_bytes())]);
    let model = model.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(model.objects.len(), 3);
    let local = Triangle {
        v0: [0.0, 0.0, 0.0, 0.0],
        v1: [1.0, 0.0, 0.0, 0.0],
        v2: [0.0, 1.0, 0.0, 0.0],
    };
    let expected = [
        Mat4::from_translation(Vec3::new(10.0, 0.0, 0.0)) * Mat4::from_scale(Vec3::splat(2.0)),
        Mat4::from_translation(Vec3::new(10.0, 5.0, 0.0)),
        Mat4::from_scale(Vec3::new(1.0, 3.0, 1.0)) * Mat4::from_quat(Quat::from_rotation_z(45f32.to_radians())),
    ];
    let got = model.world_triangles();
    assert_eq!(got.len(), 3);
    for (k, (m, t)) in expected.iter().zip(&got).enumerate() {
        let identity = world(Mat4::IDENTITY, t);
        assert!(close(identity, world(*m, &local)), "object {k}: {identity:?}");
    }
    // The two plain instances share the parsed mesh and carry transforms; the sheared one is
    // baked (its transform is the identity).
    let mesh_of = |k: usize| match model.objects[k].shape {
        Shape::Mesh(m) => m,
        Shape::Sphere { .. } => unreachable!(),
    };
    assert_eq!(mesh_of(0), mesh_of(1));
    assert_ne!(mesh_of(0), mesh_of(2));
    assert_eq!(model.meshes.len(), 2);
    assert_eq!(model.objects[0].transform.scale, Vec3::splat(2.0));
    assert_eq!(model.objects[2].transform, crate::scene::Transform::IDENTITY);
    assert_eq!(model.objects[1].name, "up: tri");
    // The shared mesh's nodes are instances in a scene of two levels; the baked one is left
    // to the renderer's rule.
    let marks: Vec<_> = model.objects.iter().map(|o| o.instance).collect();
    assert_eq!(marks, [Some(true), Some(true), None]);
    let (scene, _) = model.into_scene("tree", "tree.gltf");
    let data = scene.gpu_data_as(0.0, crate::scene::InstancingMode::Auto).unwrap();
    let i = data.instancing.as_ref().expect("two levels");
    assert_eq!((i.placements.len(), i.world_tris), (scene.objects.len(), 0));
    assert!(
        data.instancing_why.contains("2 instance = true"),
        "{}",
        data.instancing_why
    );
}

#[test]
fn node_matrices_become_transforms_unless_sheared_or_mirrored() {
    let turned = Mat4::from_scale_rotation_translation(
        Vec3::new(1.0, 2.0, 3.0),
        Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0),
        Vec3::new(4.0, -5.0, 6.0),
    );
    let t = super::gltf::as_transform(turned).expect("a rotation, scale and translation");
    let again = Mat4::from(t.matrix());
    let off = (again - turned)
        .to_cols_array()
        .iter()
        .fold(0.0f32, |m, d| m.max(d.abs()));
    assert!(off < 1e-5, "{again} != {turned}");
    let sheared = Mat4::from_scale(Vec3::new(1.0, 3.0, 1.0)) * Mat4::from_rotation_z(0.5);
    assert_eq!(super::gltf::as_transform(sheared), None);
    assert_eq!(
        super::gltf::as_transform(Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))),
        None
    );
}

#[test]
fn gltf_camera_is_the_scene_camera() {
    // A camera at (0, 0, 5) looking down -z (its default), 30 degrees of vertical view.
    let nodes = r#"[{"mesh": 0}, {"camera": 0, "translation": [0, 0, 5]}],
  "scenes": [{"nodes": [0, 1]}],
  "cameras": [{"type": "perspective", "perspective": {"yfov": 0.5235988, "znear": 0.1}}]"#;
    let dir = temp_dir("camera");
    let path = dir.join("cam.gltf");
    std::fs::write(&path, one_triangle_gltf(nodes, "")).unwrap();
    let result = Scene::from_model(&path);
    let _ = std::fs::remove_dir_all(&dir);
    let (scene, warnings) = result.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.camera.position, Vec3::new(0.0, 0.0, 5.0));
    assert!((scene.camera.look_at - Vec3::new(0.0, 0.0, 4.0)).length() < 1e-6);
    assert!((scene.camera.vfov_deg - 30.0).abs() < 1e-3);
    assert!(!has_warning(&warnings, &["no camera"]), "{warnings:?}");
}

#[test]
fn gltf_punctual_lights_are_placed_by_their_nodes() {
    // A spot at (0, 3, 0) turned to look down (-z turned -90 degrees about x), a white point
    // light, a directional light along -z, and one with a negative intensity (ignored).
    let (s, c) = ((-45f32).to_radians().sin(), 45f32.to_radians().cos());
    let nodes = format!(
        r#"[{{"mesh": 0}},
    {{"translation": [0, 3, 0], "rotation": [{s}, 0, 0, {c}], "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}},
    {{"translation": [1, 2, 3], "extensions": {{"KHR_lights_punctual": {{"light": 1}}}}}},
    {{"extensions": {{"KHR_lights_punctual": {{"light": 2}}}}}},
    {{"extensions": {{"KHR_lights_punctual": {{"light": 3}}}}}}],
  "scenes": [{{"nodes": [0, 1, 2, 3, 4]}}]"#
    );
    let extra = r#",
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": {"KHR_lights_punctual": {"lights": [
    {"type": "spot", "color": [1, 0.5, 0.25], "intensity": 4, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.3}},
    {"type": "point", "intensity": 2},
    {"type": "directional", "intensity": 3},
    {"type": "point", "intensity": -1}
  ]}}"#;
    let (_, model) = load_written(
        "lights",
        &[("lights.gltf", one_triangle_gltf(&nodes, extra).as_bytes())],
    );
    let model = model.unwrap_or_else(|e| panic!("{e}"));
    let l = &model.punctual;
    assert_eq!(l.len(), 3, "{l:?}");
    assert_eq!(l[0].kind, shared::types::LIGHT_SPOT);
    assert!((Vec3::from_slice(&l[0].position[..3]) - Vec3::new(0.0, 3.0, 0.0)).length() < 1e-6);
    assert!(
        (Vec3::from_slice(&l[0].direction[..3]) - Vec3::NEG_Y).length() < 1e-5,
        "{:?}",
        l[0]
    );
    assert_eq!(&l[0].intensity[..3], &[4.0, 2.0, 1.0]);
    assert!((l[0].direction[3] - 0.3f32.cos()).abs() < 1e-6 && (l[0].intensity[3] - 0.1f32.cos()).abs() < 1e-6);
    assert_eq!(
        (l[1].kind, &l[1].position[..3]),
        (shared::types::LIGHT_POINT, &[1.0, 2.0, 3.0][..])
    );
    assert_eq!(
        (l[2].kind, &l[2].direction[..3]),
        (shared::types::LIGHT_DIRECTIONAL, &[0.0, 0.0, -1.0][..])
    );
    assert!(
        !has_warning(&model.warnings, &["not supported", "KHR_lights_punctual"]),
        "the extension read is called unsupported: {:?}",
        model.warnings
    );
    assert!(
        has_warning(&model.warnings, &["1 punctual lights", "ignored"]),
        "{:?}",
        model.warnings
    );
}

#[test]
fn gltf_materials_map_onto_the_renderer_kinds() {
    let nodes = r#"[{"mesh": 0}, {"mesh": 1}, {"mesh": 2}, {"mesh": 3}],
  "scenes": [{"nodes": [0, 1, 2, 3]}]"#;
    let extra = r#",
  "extensionsUsed": ["KHR_materials_emissive_strength", "KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_clearcoat"],
  "materials": [
    {"name": "gold", "pbrMetallicRoughness": {"baseColorFactor": [1, 0.8, 0.3, 1], "metallicFactor": 1, "roughnessFactor": 0.2}},
    {"name": "glass", "pbrMetallicRoughness": {"metallicFactor": 0},
     "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_ior": {"ior": 1.4}}},
    {"name": "lamp", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0},
     "emissiveFactor": [1, 0.5, 0.25], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}}
  ]"#;
    let text = one_triangle_gltf(nodes, extra).replace(
        r#""meshes": [{"name": "tri", "primitives": [{"attributes": {"POSITION": 0}}]}]"#,
        r#""meshes": [
    {"primitives": [{"attributes": {"POSITION": 0}, "material": 0}]},
    {"primitives": [{"attributes": {"POSITION": 0}, "material": 1}]},
    {"primitives": [{"attributes": {"POSITION": 0}, "material": 2}]},
    {"primitives": [{"attributes": {"POSITION": 0}}, {"attributes": {"POSITION": 0}, "mode": 1}]}
  ]"#,
    );
    let (_, model) = load_written("materials", &[("m.gltf", text.as_bytes())]);
    let model = model.unwrap_or_else(|e| panic!("{e}"));
    let m = |name: &str| model.materials.iter().find(|(n, _)| n == name).unwrap().1;
    let gold = m("gold");
    assert_eq!(
        (gold.kind, albedo(&gold), gold.metallic, gold.roughness, gold.ior),
        (MaterialKind::Pbr as u32, [1.0, 0.8, 0.3], 1.0, 0.2, 1.5)
    );
    let glass = m("glass");
    assert_eq!((glass.kind, glass.ior), (MaterialKind::Dielectric as u32, 1.4));
    let lamp = m("lamp");
    assert_eq!(
        (lamp.kind, lamp.emission),
        (MaterialKind::Emissive as u32, [4.0, 2.0, 1.0, 0.0])
    );
    let default = m("default");
    assert_eq!(
        (default.kind, albedo(&default)),
        (MaterialKind::Diffuse as u32, [0.8; 3])
    );
    assert_eq!(model.objects.len(), 4, "the LINES primitive is skipped");
    let w = &model.warnings;
    assert!(has_warning(w, &["m.gltf", "mode Lines"]), "{w:?}");
    assert!(has_warning(w, &["not supported", "KHR_materials_clearcoat"]), "{w:?}");
    assert!(!has_warning(w, &["KHR_materials_ior"]), "{w:?}");
    // An emitting model gets no key light.
    let (scene, warnings) = model.into_scene("m", "m.gltf");
    assert!(!has_warning(&warnings, &["key light"]), "{warnings:?}");
    assert!(scene.objects.iter().all(|o| matches!(o.shape, Shape::Mesh(_))));
}

#[test]
fn bad_gltf_files_are_named() {
    let suzi = std::fs::read(assets().join("suzi.glb")).unwrap();
    error_of(
        "truncated",
        &[("cut.glb", &suzi[..suzi.len() / 2])],
        &["binary glTF", "GLB"],
    );
    error_of("header", &[("cut.glb", &suzi[..10])], &["GLB"]);
    error_of(
        "json",
        &[(
            "bad.gltf",
            b"{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [\n}\n",
        )],
        &["invalid glTF JSON", "line 4"],
    );
    let external = one_triangle_gltf(r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#, "").replace(
        "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA",
        "missing%20buffer.bin",
    );
    assert!(external.contains("missing%20buffer.bin"));
    error_of(
        "nobin",
        &[("ext.gltf", external.as_bytes())],
        &["buffer 0", "missing buffer.bin", "cannot read"],
    );
    let short = one_triangle_gltf(r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#, "")
        .replace(r#""byteLength": 36, "uri""#, r#""byteLength": 72, "uri""#);
    error_of(
        "short",
        &[("short.gltf", short.as_bytes())],
        &["buffer 0", "36 bytes", "72"],
    );
    let past = one_triangle_gltf(r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#, "")
        .replace(r#""count": 3, "type""#, r#""count": 4, "type""#);
    error_of(
        "past",
        &[("past.gltf", past.as_bytes())],
        &["accessor 0", "past the end"],
    );
    let draco = one_triangle_gltf(
        r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#,
        r#", "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"]"#,
    );
    error_of(
        "draco",
        &[("draco.gltf", draco.as_bytes())],
        &["requires", "not support", "KHR_draco_mesh_compression"],
    );
    let nan = one_triangle_gltf(r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#, "").replace(
        "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA",
        "AADAfwAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA",
    );
    error_of(
        "gltfnan",
        &[("nan.gltf", nan.as_bytes())],
        &["tri", "vertex 0", "non-finite"],
    );
    let cycle = one_triangle_gltf(
        r#"[{"mesh": 0, "children": [1]}, {"children": [0]}], "scenes": [{"nodes": [0]}]"#,
        "",
    );
    error_of("cycle", &[("cycle.gltf", cycle.as_bytes())], &["node 0", "not a tree"]);
}

#[test]
fn missing_gltf_texture_is_a_warning() {
    let extra = r#",
  "images": [{"uri": "gone.png"}],
  "textures": [{"source": 0}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "baseColorFactor": [0.5, 0.5, 0.5, 1]}}]"#;
    let text = one_triangle_gltf(r#"[{"mesh": 0}], "scenes": [{"nodes": [0]}]"#, extra).replace(
        r#""attributes": {"POSITION": 0}"#,
        r#""attributes": {"POSITION": 0}, "material": 0"#,
    );
    let (_, model) = load_written("texture", &[("tex.gltf", text.as_bytes())]);
    let model = model.unwrap_or_else(|e| panic!("{e}"));
    let w = &model.material_warnings;
    assert!(has_warning(w, &["gone.png", "cannot read"]), "{w:?}");
    assert_eq!(albedo(&model.materials[0].1), [0.5; 3], "the base colour factor");
    assert_eq!(
        model.materials[0].1.textures, [0; 4],
        "no texture where its image is missing"
    );
}

#[test]
fn ply_files_open_and_bad_ones_are_named() {
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
        property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
        0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
    let (_, model) = load_written("ply", &[("quad.ply", ply.as_bytes())]);
    let model = model.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(model.world_triangles().len(), 2);
    error_of(
        "plyindex",
        &[("bad.ply", ply.replace("4 0 1 2 3", "3 0 1 7").as_bytes())],
        &["face 0", "vertex 7"],
    );
    error_of(
        "plycut",
        &[("cut.ply", ply.replace("0 1 0\n4 0 1 2 3\n", "0 1").as_bytes())],
        &["invalid PLY"],
    );
    error_of(
        "plynan",
        &[("nan.ply", ply.replace("1 1 0", "1 nan 0").as_bytes())],
        &["invalid PLY", "Line 12", "1 nan 0"],
    );
    error_of(
        "plyinf",
        &[("inf.ply", ply.replace("1 1 0", "1 1e39 0").as_bytes())],
        &["vertex 2", "non-finite"],
    );
}

#[test]
fn model_files_work_as_toml_meshes() {
    let dir = temp_dir("toml");
    std::fs::copy(assets().join("suzi.glb"), dir.join("suzi.glb")).unwrap();
    std::fs::write(dir.join("two.obj"), TWO_MATERIALS_OBJ).unwrap();
    let text = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n\
        [materials.white]\nkind = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
        [[objects]]\nmesh = \"suzi.glb\"\nmaterial = \"white\"\n\
        [[objects]]\nmesh = \"two.obj\"\nmaterial = \"white\"\n";
    let result = super::super::format::parse(text, "m.toml", &dir);
    let _ = std::fs::remove_dir_all(&dir);
    let (scene, warnings) = result.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.counts(), (14_842 + 4, 0));
    assert_eq!(scene.objects[0].name, "suzi");
    // The missing two.mtl does not matter here: the scene gives the material.
    assert!(!has_warning(&warnings, &["two.mtl"]), "{warnings:?}");
}
