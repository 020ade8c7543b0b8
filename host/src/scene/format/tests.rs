//! Tests of the TOML format: the example files, defaults, shared meshes, and one bad input per
//! kind of error, each message checked for the file and the problem.
use super::super::{Scene, Shape};
use glam::Vec3;
use shared::types::MaterialKind;
use std::path::{Path, PathBuf};

const LABEL: &str = "test.toml";

const HEADER: &str = "[camera]\nposition = [0, 1, -5]\nlook_at = [0, 0, 0]\n\n\
    [materials.white]\nkind = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n";

const BALL: &str = "[[objects]]\nsphere = 1\nmaterial = \"white\"\n";

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

fn parse(text: &str) -> Result<Scene, super::SceneError> {
    Scene::from_toml_str(text, LABEL, Path::new(""))
}

/// The error message for `text`, checked to name the file and to contain every one of `wanted`.
fn error_of(text: &str, wanted: &[&str]) -> String {
    let message = parse(text).map(|_| ()).unwrap_err().to_string();
    assert!(message.starts_with(LABEL), "does not name the file: {message}");
    for w in wanted {
        assert!(message.contains(w), "{w:?} missing from: {message}");
    }
    message
}

/// A fresh folder under the system's temporary folder.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("raytrace-scene-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn example_cornell_is_the_builtin_cornell() {
    let file = Scene::load(&scenes_dir().join("cornell.toml")).unwrap_or_else(|e| panic!("{e}"));
    let builtin = Scene::builtin("cornell").unwrap();
    assert_eq!(file.name, builtin.name);
    assert_eq!(file.camera, builtin.camera);
    assert_eq!(file.settings, builtin.settings);
    assert_eq!(file.materials, builtin.materials);
    assert_eq!(file.objects.len(), builtin.objects.len());
    for (a, b) in file.objects.iter().zip(&builtin.objects) {
        assert_eq!((&a.name, a.shape, a.material), (&b.name, b.shape, b.material));
        let t = (a.transform.translation - b.transform.translation).abs().max_element();
        assert!(t < 1e-3, "{}: {:?} != {:?}", a.name, a.transform, b.transform);
        assert_eq!(
            (a.transform.rotation_deg, a.transform.scale),
            (b.transform.rotation_deg, b.transform.scale)
        );
    }
    let (fa, fb) = (file.gpu_data(0.0), builtin.gpu_data(0.0));
    assert_eq!(fa.model_tris, fb.model_tris);
    assert_eq!(fa.prim_object, fb.prim_object);
    assert_eq!(fa.lights, fb.lights);
    assert_eq!(file.frame(&fa), builtin.frame(&fb));
}

#[test]
fn example_glass_bunny_loads_its_mesh_relative_to_the_file() {
    let scene = Scene::load(&scenes_dir().join("glass-bunny.toml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.name, "glass-bunny");
    assert_eq!(scene.counts(), (69_666, 2));
    assert_eq!(scene.meshes[0].name, "../assets/bunny.obj");
    let glass = scene.material_index("glass").unwrap();
    assert_eq!(scene.materials[glass as usize].1.kind, MaterialKind::Dielectric as u32);
    assert_eq!(scene.materials[glass as usize].1.ior, 1.5);
    assert_eq!(scene.objects[0].material, glass);
    assert_eq!(scene.objects[0].animation.spin_deg_per_s, Vec3::new(0.0, 20.0, 0.0));
    assert_ne!(scene.objects[0].transform_at(0.0), scene.objects[0].transform_at(1.0));
    let gpu = scene.gpu_data(0.0);
    assert_eq!(gpu.lights, vec![69_667]);
    assert_eq!(scene.settings.width, 960);
    assert_eq!(scene.camera.aperture, 0.05);
}

#[test]
fn docs_example_loads() {
    let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs");
    let text = std::fs::read_to_string(docs.join("scenes.md")).unwrap();
    let start = text.find("```toml\n").unwrap() + "```toml\n".len();
    let example = &text[start..start + text[start..].find("```").unwrap()];
    let scene = Scene::from_toml_str(example, "docs/scenes.md", &docs).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        (scene.name.as_str(), scene.objects.len(), scene.materials.len()),
        ("demo", 4, 4)
    );
    let ball = &scene.objects[2];
    assert!(ball.animation.orbit.is_some() && ball.animation.bob.is_some());
}

#[test]
fn omitted_values_take_their_defaults() {
    let scene = parse(&format!("{HEADER}{BALL}")).unwrap();
    assert_eq!(scene.name, "test");
    assert_eq!(scene.settings, super::Settings::default());
    assert_eq!(
        (scene.camera.up, scene.camera.vfov_deg, scene.camera.aperture),
        (Vec3::Y, 40.0, 0.0)
    );
    assert_eq!(scene.camera.focus_distance, None);
    assert_eq!(scene.objects[0].name, "sphere");
    assert_eq!(scene.objects[0].transform, super::Transform::IDENTITY);
    let text = "[camera]\nposition = [0, 1, -5]\nlook_at = [0, 0, 0]\n\
        [materials.glass]\nkind = \"dielectric\"\n[materials.chrome]\nkind = \"metal\"\nalbedo = [1, 1, 1]\n\
        [render]\ngamma = \"2.0\"\n[[objects]]\nsphere = 1\nmaterial = \"chrome\"\n";
    let scene = parse(text).unwrap();
    assert_eq!(scene.materials[0].0, "glass", "materials keep the file's order");
    assert_eq!(
        (scene.materials[0].1.ior, scene.materials[0].1.albedo),
        (1.5, [1.0, 1.0, 1.0, 0.0])
    );
    assert_eq!(scene.materials[1].1.roughness, 0.0);
    assert!(scene.settings.gamma2);
}

#[test]
fn every_field_is_read() {
    let text = "name = \"all\"\n\
        [camera]\nposition = [1, 2, 3]\nlook_at = [0, 0, 1]\nup = [0, 0, 1]\nvfov = 60\naperture = 0.2\nfocus_distance = 4\n\
        [render]\nwidth = 320\nheight = 200\nspp = 4\ndepth = 5\nnee = false\nmis = false\nrussian_roulette = false\n\
        exposure = 2.5\ngamma = \"srgb\"\nsky = { top = [1, 2, 3], bottom = [4, 5, 6] }\nseed = 9\n\
        [materials.m]\nkind = \"metal\"\nalbedo = [0.1, 0.2, 0.3]\nemission = [1, 0, 0]\nroughness = 0.5\n\
        [[objects]]\nname = \"cube\"\nmesh = \"builtin:cube\"\nmaterial = \"m\"\ntranslate = [1, 2, 3]\n\
        rotate = [10, 20, 30]\nscale = [1, 2, 3]\n\
        instance = false\n\
        [objects.animation]\nspin = [1, 2, 3]\norbit = { center = [1, 0, 1], radius = 2, period = 3 }\n\
        bob = { amplitude = 0.5, period = 2 }\nwave = { amplitude = 0.1, wavelength = 2, period = 4, heading = 90 }\n";
    let s = parse(text).unwrap();
    assert_eq!(s.name, "all");
    let c = s.camera;
    assert_eq!(
        (c.position, c.look_at, c.up),
        (Vec3::new(1.0, 2.0, 3.0), Vec3::Z, Vec3::Z)
    );
    assert_eq!((c.vfov_deg, c.aperture, c.focus_distance), (60.0, 0.2, Some(4.0)));
    let r = s.settings;
    assert_eq!((r.width, r.height, r.spp, r.max_depth, r.seed), (320, 200, 4, 5, 9));
    assert_eq!(
        (r.nee, r.mis, r.russian_roulette, r.gamma2, r.exposure),
        (false, false, false, false, 2.5)
    );
    assert_eq!(
        (r.sky_top, r.sky_bottom),
        (Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0))
    );
    let m = s.materials[0].1;
    assert_eq!(
        (m.kind, m.albedo, m.emission, m.roughness),
        (1, [0.1, 0.2, 0.3, 0.0], [1.0, 0.0, 0.0, 0.0], 0.5)
    );
    let o = &s.objects[0];
    assert_eq!((o.name.as_str(), o.shape), ("cube", Shape::Mesh(0)));
    assert_eq!(s.meshes[0].tris.len(), 12);
    assert_eq!(o.transform.rotation_deg, Vec3::new(10.0, 20.0, 30.0));
    assert_eq!(o.transform.scale, Vec3::new(1.0, 2.0, 3.0));
    let a = o.animation;
    assert_eq!(a.spin_deg_per_s, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(
        a.orbit.map(|o| (o.center, o.radius, o.period_s)),
        Some((Vec3::new(1.0, 0.0, 1.0), 2.0, 3.0))
    );
    assert_eq!(a.bob.map(|b| (b.amplitude, b.period_s)), Some((0.5, 2.0)));
    let w = a.wave.unwrap();
    assert_eq!(
        (w.amplitude, w.wavelength, w.period_s, w.heading_deg),
        (0.1, 2.0, 4.0, 90.0)
    );
    // At 5 s: a quarter wave on (phase 0.25), half a wave a unit, heading along z.
    let [amp, kx, kz, phase] = w.params(5.0);
    assert!((amp, phase) == (0.1, 0.25) && kx.abs() < 1e-7 && (kz - 0.5).abs() < 1e-7);
    assert_eq!(o.instance, Some(false));
    assert_eq!(parse(&format!("{HEADER}{BALL}")).unwrap().objects[0].instance, None);
}

#[test]
fn a_mesh_used_twice_is_loaded_once() {
    let dir = temp_dir("shared");
    std::fs::write(dir.join("tri.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let object = |mesh: &str| format!("[[objects]]\nmesh = \"{mesh}\"\nmaterial = \"white\"\n");
    let text = format!(
        "{HEADER}{}{}{}{}",
        object("tri.obj"),
        object("builtin:quad"),
        object("tri.obj"),
        object("builtin:quad")
    );
    let scene = Scene::from_toml_str(&text, LABEL, &dir).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(scene.meshes.len(), 2);
    let shapes: Vec<Shape> = scene.objects.iter().map(|o| o.shape).collect();
    assert_eq!(shapes, [Shape::Mesh(0), Shape::Mesh(1), Shape::Mesh(0), Shape::Mesh(1)]);
    assert_eq!(scene.objects[0].name, "tri");
    assert_eq!(scene.counts(), (6, 0));
    assert_eq!(scene.gpu_data(0.0).model_tris.len(), 6);
}

#[test]
fn open_takes_a_path_too() {
    let path = scenes_dir().join("cornell.toml");
    let scene = Scene::open(path.to_str().unwrap()).unwrap();
    assert_eq!(scene.objects.len(), 8);
}

#[test]
fn syntax_error_names_the_line() {
    error_of(&format!("{HEADER}{BALL}\n[render\nwidth = 3\n"), &["line 12", "column"]);
}

#[test]
fn unknown_and_mistyped_fields_are_refused() {
    let text = format!("{HEADER}colour = [1, 0, 0]\n{BALL}");
    error_of(&text, &["line 8", "unknown field `colour`"]);
    error_of(&format!("{HEADER}{BALL}radius = 2\n"), &["unknown field `radius`"]);
    error_of(
        &format!("{HEADER}{BALL}[render]\nwidth = \"wide\"\n"),
        &["line 12", "invalid type"],
    );
    error_of(&format!("{HEADER}{BALL}[render]\nwidth = -1\n"), &["line 12", "u32"]);
    error_of(
        &format!("{HEADER}{BALL}scale = \"big\"\n"),
        &["line 11", "scale must be a number or an array of three numbers"],
    );
    error_of(
        &format!("{HEADER}{BALL}[objects.animation]\nwobble = 1\n"),
        &["unknown field `wobble`"],
    );
    error_of(
        "[materials.white]\nkind = \"diffuse\"\nalbedo = [1, 1, 1]\n",
        &["missing field `camera`"],
    );
}

#[test]
fn unknown_material_is_named() {
    let text = format!("{HEADER}[[objects]]\nname = \"ball\"\nsphere = 1\nmaterial = \"gold\"\n");
    error_of(
        &text,
        &["objects[0] (\"ball\")", "\"gold\"", "not defined", "\"white\""],
    );
}

#[test]
fn unknown_material_kind_is_named() {
    let text = format!("{HEADER}[materials.shiny]\nkind = \"plastic\"\nalbedo = [1, 1, 1]\n{BALL}");
    error_of(&text, &["\"shiny\"", "unknown kind \"plastic\""]);
}

#[test]
fn material_fields_must_fit_the_kind() {
    let text = format!("{HEADER}[materials.m]\nkind = \"diffuse\"\nalbedo = [1, 1, 1]\nior = 1.3\n{BALL}");
    error_of(&text, &["material \"m\"", "`ior`"]);
    let text = format!("{HEADER}[materials.m]\nkind = \"metal\"\n{BALL}");
    error_of(&text, &["material \"m\"", "albedo"]);
    let text = format!("{HEADER}[materials.m]\nkind = \"metal\"\nalbedo = [1, 1, 1]\nroughness = 2\n{BALL}");
    error_of(&text, &["material \"m\"", "roughness must lie in [0, 1]"]);
}

#[test]
fn missing_obj_file_is_named() {
    let text = format!("{HEADER}[[objects]]\nmesh = \"meshes/nope.obj\"\nmaterial = \"white\"\n");
    error_of(&text, &["cannot load mesh \"meshes/nope.obj\"", "nope.obj"]);
    let text = format!("{HEADER}[[objects]]\nmesh = \"builtin:teapot\"\nmaterial = \"white\"\n");
    error_of(&text, &["builtin:teapot", "builtin:cube, builtin:grid, builtin:quad"]);
}

#[test]
fn obj_with_nan_vertex_is_refused() {
    let dir = temp_dir("nan");
    std::fs::write(dir.join("bad.obj"), "v 0 0 0\nv NaN 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let text = format!("{HEADER}[[objects]]\nmesh = \"bad.obj\"\nmaterial = \"white\"\n");
    let result = Scene::from_toml_str(&text, LABEL, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    let message = result.map(|_| ()).unwrap_err().to_string();
    assert!(message.starts_with(LABEL), "{message}");
    assert!(
        message.contains("bad.obj") && message.contains("non-finite"),
        "{message}"
    );
}

#[test]
fn empty_scene_is_refused() {
    error_of(HEADER, &["the scene has no objects"]);
}

#[test]
fn bad_sizes_are_refused() {
    error_of(
        &format!("{HEADER}[[objects]]\nsphere = -1\nmaterial = \"white\"\n"),
        &["objects[0]", "sphere radius must be positive", "-1"],
    );
    error_of(
        &format!("{HEADER}{BALL}scale = [1, 2, 1]\n"),
        &["objects[0]", "uniform scale"],
    );
    error_of(
        &format!("{HEADER}{BALL}scale = 0\n"),
        &["objects[0]", "scale must be positive"],
    );
    let cube = "[[objects]]\nmesh = \"builtin:cube\"\nmaterial = \"white\"\n";
    error_of(
        &format!("{HEADER}{cube}scale = [1, -2, 1]\n"),
        &["objects[0]", "scale must be positive"],
    );
    error_of(
        &format!("{HEADER}{BALL}[render]\nwidth = 0\n"),
        &["render", "width and height must be positive"],
    );
    error_of(
        &format!("{HEADER}{BALL}[render]\ngamma = \"2.2\"\n"),
        &["render", "gamma"],
    );
    let bob = "[objects.animation]\nbob = { amplitude = 1, period = 0 }\n";
    error_of(&format!("{HEADER}{BALL}{bob}"), &["objects[0]", "bob period"]);
    let wave = |w: &str| format!("[objects.animation]\nwave = {{ {w} }}\n");
    let good = "amplitude = 1, wavelength = 2, period = 3";
    error_of(
        &format!("{HEADER}{BALL}{}", wave(good)),
        &["objects[0]", "a sphere cannot wave"],
    );
    let waving = |w: &str| format!("{HEADER}{cube}{}", wave(w));
    assert!(parse(&waving(good)).is_ok());
    error_of(
        &waving("amplitude = 1, wavelength = 0, period = 3"),
        &["objects[0]", "wave length"],
    );
    error_of(
        &waving("amplitude = 1, wavelength = 2, period = -3"),
        &["objects[0]", "wave period"],
    );
    error_of(
        &waving("amplitude = inf, wavelength = 2, period = 3"),
        &["objects[0]", "wave amplitude"],
    );
    error_of(&waving("amplitude = 1, wavelength = 2"), &["period"]);
    error_of(
        &format!("{HEADER}{BALL}instance = false\n"),
        &["objects[0]", "instance = false is for meshes"],
    );
    error_of(
        &format!("{HEADER}{cube}instance = \"yes\"\n"),
        &["line 11", "expected a boolean"],
    );
    let shape = "[[objects]]\nsphere = 1\nmesh = \"builtin:cube\"\nmaterial = \"white\"\n";
    error_of(&format!("{HEADER}{shape}"), &["objects[0]", "not both"]);
}

#[test]
fn bad_cameras_are_refused() {
    let with = |camera: &str| {
        format!(
            "[camera]\n{camera}\n{}{BALL}",
            &HEADER[HEADER.find("[materials").unwrap()..]
        )
    };
    error_of(
        &with("position = [0, 1, -5]\nlook_at = [0, 0, 0]\nvfov = 180"),
        &["camera", "vfov", "180"],
    );
    error_of(
        &with("position = [0, 1, -5]\nlook_at = [0, 0, 0]\nvfov = 0"),
        &["camera", "vfov"],
    );
    error_of(
        &with("position = [0, 0, 0]\nlook_at = [0, 0, 0]"),
        &["camera", "same point"],
    );
    error_of(
        &with("position = [0, 5, 0]\nlook_at = [0, 0, 0]"),
        &["camera", "parallel"],
    );
}

#[test]
fn missing_scene_file_is_named() {
    let path = scenes_dir().join("no-such-scene.toml");
    let message = Scene::load(&path).unwrap_err().to_string();
    assert!(
        message.contains("no-such-scene.toml") && message.contains("cannot read"),
        "{message}"
    );
}
