//! Vertex attributes on both backends: interpolated vertex normals shade a faceted sphere like
//! the sphere it approximates, the shading normal never lets a path below the geometric
//! surface, and CPU and GPU agree on a model with smooth normals.
use glam::Vec3;
use integration_tests::{assert_cpu_and_gpu_agree, assert_no_validation_errors, renderer};
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cpu::render_cpu;
use raytrace::inputs::hard_cases::icosphere;
use raytrace::picture::Picture;
use raytrace::scene::attrs::{self, from_vertices};
use raytrace::scene::{material, CameraSpec, Mesh, Scene, SceneObject, Settings, Shape, Transform};
use shared::types::{VertexAttrs, FEATURE_SHADING_NORMALS};
use std::sync::Arc;

const SIZE: u32 = 48;
const SPP: u32 = 256;

/// A white diffuse ball under a sky bright above and black below, seen from the front: its
/// shading follows its normals closely. `shape` is a sphere or an icosphere mesh whose vertex
/// normals are `normals` (none: flat facets).
fn ball(shape: Shape, meshes: Vec<Mesh>) -> Scene {
    Scene {
        name: "ball".into(),
        punctual: Vec::new(),
        environment: None,
        textures: Default::default(),
        camera: CameraSpec {
            position: Vec3::new(0.0, 0.0, 3.0),
            look_at: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aperture: 0.0,
            focus_distance: None,
        },
        settings: Settings {
            width: SIZE,
            height: SIZE,
            spp: SPP,
            max_depth: 3,
            nee: false,
            sky_top: Vec3::splat(1.0),
            sky_bottom: Vec3::ZERO,
            ..Settings::default()
        },
        materials: vec![("white".into(), material::diffuse([0.8; 3]))],
        meshes,
        objects: vec![SceneObject {
            name: "ball".into(),
            shape,
            transform: Transform::IDENTITY,
            material: 0,
            animation: Default::default(),
            instance: None,
        }],
    }
}

fn icoball(normals: bool) -> Scene {
    let m = icosphere(2);
    let tris = m.triangles(Vec3::ZERO);
    let attrs = if normals {
        let n: Vec<[f32; 3]> = m.verts.iter().map(|v| v.normalize().to_array()).collect();
        from_vertices(&m.faces, Some(&n), None)
    } else {
        Vec::new()
    };
    let mesh = Mesh {
        name: "icosphere".into(),
        tris: Arc::new(tris),
        attrs: Arc::new(attrs),
    };
    ball(Shape::Mesh(0), vec![mesh])
}

fn render(scene: &Scene) -> Picture {
    let data = scene.gpu_data(0.0);
    let frame = scene.frame(&data);
    render_cpu(&data, &frame, SPP, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture
}

#[test]
fn vertex_normals_shade_a_faceted_sphere_like_the_sphere() {
    let sphere = render(&ball(Shape::Sphere { radius: 1.0 }, Vec::new()));
    let smooth = render(&icoball(true));
    let flat = render(&icoball(false));
    // Inside the silhouette (the icosphere's is a polygon inside the sphere's circle).
    let (e_smooth, e_flat) = (centre_rmse(&smooth, &sphere), centre_rmse(&flat, &sphere));
    eprintln!("RMSE against the sphere in the centre: smooth {e_smooth}, flat {e_flat}");
    assert!(
        e_smooth < 0.5 * e_flat,
        "vertex normals did not bring the facets closer to the sphere: {e_smooth} vs flat {e_flat}"
    );
}

#[test]
fn normals_computed_for_a_mesh_without_them_are_smooth() {
    // The icosphere's faces meet at about 12 degrees: within the default crease angle.
    let m = icosphere(2);
    let tris = m.triangles(Vec3::ZERO);
    let computed = attrs::smooth(&tris, &[], attrs::DEFAULT_CREASE_DEG);
    for (t, a) in tris.iter().zip(&computed) {
        for (k, v) in [t.v0, t.v1, t.v2].iter().enumerate() {
            let want = Vec3::new(v[0], v[1], v[2]).normalize();
            let got = Vec3::from_slice(&a.normal_u[k][..3]);
            assert!(got.angle_between(want).to_degrees() < 2.0, "{got} vs {want}");
        }
    }
}

#[test]
fn bent_normals_never_send_a_path_below_the_surface() {
    // A floor (4 x 4 at y = 0, facing up) whose vertex normals lean 80 degrees, and under it a
    // lamp facing up at the floor's underside; the sky is black. No light can reach the top
    // of the floor, but a direction sampled about the leaning normal, or a light sample
    // above it, goes below the floor half the time: the geometric checks must stop both.
    let quad = raytrace::scene::shapes::by_name("quad").unwrap();
    let lean = Vec3::new(80f32.to_radians().sin(), 80f32.to_radians().cos(), 0.0);
    let mut a = VertexAttrs::default();
    for n in &mut a.normal_u {
        n[..3].copy_from_slice(&lean.to_array());
    }
    let floor = Mesh {
        name: "floor".into(),
        tris: Arc::new(quad.clone()),
        attrs: Arc::new(vec![a; quad.len()]),
    };
    let mut s = ball(Shape::Mesh(0), vec![floor, Mesh::flat("lamp", quad)]);
    s.objects[0].transform = Transform::new(Vec3::ZERO, Vec3::ZERO, Vec3::splat(4.0));
    s.materials.push(("lamp".into(), material::emissive([10.0; 3])));
    s.objects.push(SceneObject {
        name: "lamp".into(),
        shape: Shape::Mesh(1),
        transform: Transform::new(Vec3::new(0.0, -0.5, 0.0), Vec3::ZERO, Vec3::ONE),
        material: 1,
        animation: Default::default(),
        instance: None,
    });
    s.camera.position = Vec3::new(0.0, 3.0, 0.0);
    s.camera.up = Vec3::Z;
    s.settings.sky_top = Vec3::ZERO;
    s.settings.sky_bottom = Vec3::ZERO;
    s.settings.nee = true;
    let data = s.gpu_data(0.0);
    let frame = s.frame(&data);
    assert_ne!(frame.features & FEATURE_SHADING_NORMALS, 0);
    let p = render_cpu(&data, &frame, 16, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture;
    let lit = centre_luminance(&p);
    assert!(lit == 0.0, "light leaked through the floor: mean {lit}");
    // The same floor with the lamp above it, to the side, facing down, is lit: the checks
    // do not simply absorb everything.
    s.objects[1].transform = Transform::new(Vec3::new(1.6, 0.5, 0.0), Vec3::new(180.0, 0.0, 0.0), Vec3::ONE);
    let data = s.gpu_data(0.0);
    let frame = s.frame(&data);
    let p = render_cpu(&data, &frame, 16, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture;
    assert!(centre_luminance(&p) > 0.0);
}

#[test]
fn punctual_lights_give_their_analytic_radiance() {
    use shared::types::{PunctualLight, LIGHT_DIRECTIONAL, LIGHT_POINT, LIGHT_SPOT};
    // A large floor of albedo 0.5 seen from above, black sky: only next-event estimation lights it.
    let floor = raytrace::scene::shapes::by_name("quad").unwrap();
    let mut s = ball(Shape::Mesh(0), vec![Mesh::flat("floor", floor)]);
    s.materials[0].1 = material::diffuse([0.5; 3]);
    s.objects[0].transform = Transform::new(Vec3::ZERO, Vec3::ZERO, Vec3::splat(20.0));
    s.camera.position = Vec3::new(0.0, 3.0, 0.0);
    s.camera.up = Vec3::Z;
    s.settings.nee = true;
    s.settings.max_depth = 2;
    s.settings.sky_top = Vec3::ZERO;
    s.settings.sky_bottom = Vec3::ZERO;
    let light = |kind, position: Vec3, direction: Vec3, intensity: f32, cos_outer: f32, cos_inner: f32| PunctualLight {
        position: [position.x, position.y, position.z, 0.0],
        direction: [direction.x, direction.y, direction.z, cos_outer],
        intensity: [intensity, intensity, intensity, cos_inner],
        kind,
        _pad: [0; 3],
    };
    let centre = |s: &Scene| {
        let data = s.gpu_data(0.0);
        let frame = s.frame(&data);
        let p = render_cpu(&data, &frame, 4, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture;
        let lin = p.linear();
        let c = lin[(SIZE / 2 * SIZE + SIZE / 2) as usize];
        (c[0] + c[1] + c[2]) as f64 / 3.0
    };
    // Directional light from 45 degrees, irradiance 2 on a surface facing it: L = a E cos / pi.
    let dir = Vec3::new(0.0, -1.0, -1.0).normalize();
    s.punctual = vec![light(LIGHT_DIRECTIONAL, Vec3::ZERO, dir, 2.0, -1.0, -1.0)];
    let want = 0.5 * 2.0 * 45f64.to_radians().cos() / std::f64::consts::PI;
    let got = centre(&s);
    assert!((got - want).abs() < 1e-3 * want, "directional: {got} vs {want}");
    // A point light of intensity 8 two units above the floor's centre: L = a I / (pi h^2).
    s.punctual = vec![light(
        LIGHT_POINT,
        Vec3::new(0.0, 2.0, 0.0),
        Vec3::ZERO,
        8.0,
        -1.0,
        -1.0,
    )];
    let want = 0.5 * 8.0 / (std::f64::consts::PI * 4.0);
    let got = centre(&s);
    assert!((got - want).abs() < 0.01 * want, "point: {got} vs {want}");
    // A spot aimed beside the centre, its cone missing it: black; aimed at it: the point's.
    let aside = Vec3::new(1.0, -1.0, 0.0).normalize();
    let (outer, inner) = (10f32.to_radians().cos(), 5f32.to_radians().cos());
    s.punctual = vec![light(LIGHT_SPOT, Vec3::new(0.0, 2.0, 0.0), aside, 8.0, outer, inner)];
    assert_eq!(centre(&s), 0.0);
    s.punctual[0].direction = [0.0, -1.0, 0.0, outer];
    let got = centre(&s);
    assert!((got - want).abs() < 0.01 * want, "spot: {got} vs {want}");
}

/// Root mean square difference of the centre quarters of two pictures.
fn centre_rmse(a: &Picture, b: &Picture) -> f64 {
    let (la, lb) = (a.linear(), b.linear());
    let (w, h) = (a.width as usize, a.height as usize);
    let mut sq = 0.0;
    let mut n = 0;
    for y in h / 4..3 * h / 4 {
        for x in w / 4..3 * w / 4 {
            for k in 0..3 {
                let d = (la[y * w + x][k] - lb[y * w + x][k]) as f64;
                sq += d * d;
                n += 1;
            }
        }
    }
    (sq / n as f64).sqrt()
}

/// Mean luminance of the centre quarter of the picture (where the floor is).
fn centre_luminance(p: &Picture) -> f64 {
    let lin = p.linear();
    let (w, h) = (p.width as usize, p.height as usize);
    let mut sum = 0.0;
    let mut n = 0;
    for y in h / 4..3 * h / 4 {
        for x in w / 4..3 * w / 4 {
            let c = lin[y * w + x];
            sum += (c[0] + c[1] + c[2]) as f64 / 3.0;
            n += 1;
        }
    }
    sum / n as f64
}

#[test]
fn cpu_and_gpu_agree_with_vertex_normals_and_punctual_lights() {
    let Some((gpu, mut r)) = renderer("cpu_and_gpu_agree_with_vertex_normals_and_punctual_lights") else {
        return;
    };
    // With a spot light too: next-event estimation toward punctual lights on both backends.
    let mut scene = icoball(true);
    scene.settings.nee = true;
    scene.punctual = vec![shared::types::PunctualLight {
        position: [1.0, 2.0, 2.0, 0.0],
        direction: [-0.33, -0.66, -0.66, 0.9],
        intensity: [5.0, 4.0, 3.0, 0.95],
        kind: shared::types::LIGHT_SPOT,
        _pad: [0; 3],
    }];
    let data = scene.gpu_data(0.0);
    let frame = scene.frame(&data);
    assert_cpu_and_gpu_agree(&mut r, &data, &frame, 16, 0.02);
    assert_no_validation_errors(&gpu);
}

#[test]
fn an_emissive_texture_shows_on_a_quad_as_its_image_has_it() {
    use raytrace::scene::texture::{Sampler, TextureSet};
    use shared::types::TEX_EMISSIVE;
    // A 2x2 image: red, green / blue, white (row 0 at the top, as glTF's (0, 0) is).
    let img = image::RgbaImage::from_fn(2, 2, |x, y| match (x, y) {
        (0, 0) => image::Rgba([255, 0, 0, 255]),
        (1, 0) => image::Rgba([0, 255, 0, 255]),
        (0, 1) => image::Rgba([0, 0, 255, 255]),
        _ => image::Rgba([255, 255, 255, 255]),
    });
    let mut set = TextureSet::new();
    let mut warnings = Vec::new();
    let t = set.add_image(
        &image::DynamicImage::ImageRgba8(img),
        true,
        Sampler::default(),
        "checker",
        &mut warnings,
    );
    assert!(warnings.is_empty(), "{warnings:?}");
    // The unit quad at y = 0 facing up, u along +x and v along +z, seen from above with +z
    // down the picture: texel (0, 0) at the top left.
    let quad = raytrace::scene::shapes::by_name("quad").unwrap();
    let uv: Vec<[f32; 2]> = vec![[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]];
    let corners: Vec<[u32; 3]> = vec![[0, 1, 2], [0, 2, 3]];
    assert_eq!(
        quad[0].v1,
        [-0.5, 0.0, 0.5, 0.0],
        "the quad's corners as the UVs assume"
    );
    let attrs = from_vertices(&corners, None, Some(&uv));
    let mut s = ball(
        Shape::Mesh(0),
        vec![Mesh {
            name: "quad".into(),
            tris: Arc::new(quad),
            attrs: Arc::new(attrs),
        }],
    );
    let mut lamp = material::emissive([1.0; 3]);
    lamp.textures[TEX_EMISSIVE] = t + 1;
    s.materials[0].1 = lamp;
    s.textures = Arc::new(set);
    s.camera.position = Vec3::new(0.0, 2.0, 0.0);
    s.camera.up = Vec3::NEG_Z;
    s.camera.vfov_deg = 20.0;
    s.settings.max_depth = 1;
    let data = s.gpu_data(0.0);
    let frame = s.frame(&data);
    let p = render_cpu(&data, &frame, 4, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture;
    let lin = p.linear();
    // The quad spans about 2 * atan(0.25) / 20 degrees of the picture; texel centres lie a
    // quarter of it from the centre.
    let quarter = (SIZE as f32 * (0.25f32.atan().to_degrees() / 20.0) / 2.0) as u32;
    let at = |dx: i32, dy: i32| {
        let (x, y) = (
            (SIZE / 2) as i32 + dx * quarter as i32,
            (SIZE / 2) as i32 + dy * quarter as i32,
        );
        lin[(y as u32 * SIZE + x as u32) as usize]
    };
    // Bilinear filtering and the pixels' jitter blend a little of the neighbours in.
    let close = |c: [f32; 3], want: [f32; 3]| (0..3).all(|k| (c[k] - want[k]).abs() < 0.15);
    assert!(close(at(-1, -1), [1.0, 0.0, 0.0]), "top left {:?}", at(-1, -1));
    assert!(close(at(1, -1), [0.0, 1.0, 0.0]), "top right {:?}", at(1, -1));
    assert!(close(at(-1, 1), [0.0, 0.0, 1.0]), "bottom left {:?}", at(-1, 1));
    assert!(close(at(1, 1), [1.0, 1.0, 1.0]), "bottom right {:?}", at(1, 1));
}

#[test]
fn the_damaged_helmet_opens_textured_and_cpu_and_gpu_agree() {
    use shared::types::{FEATURE_NORMAL_MAPS, FEATURE_PBR, FEATURE_TEXTURES};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/damaged_helmet.glb");
    let args = <raytrace::cli::SceneArgs as clap::Parser>::parse_from([
        "raytrace",
        path.to_str().unwrap(),
        "--size",
        "32x32",
        "--spp",
        "4",
    ]);
    let p = args.prepare().expect("the helmet opens");
    let m = p.scene.materials[p.scene.objects[0].material as usize].1;
    assert!(
        m.textures.iter().all(|&t| t != 0),
        "base colour, metallic-roughness, normal, emissive: {:?}",
        m.textures
    );
    for bit in [FEATURE_TEXTURES, FEATURE_NORMAL_MAPS, FEATURE_PBR] {
        assert_ne!(p.frame.features & bit, 0, "{}", p.features.explain());
    }
    let Some((gpu, _)) = renderer("the_damaged_helmet_opens_textured_and_cpu_and_gpu_agree") else {
        return;
    };
    let kernels = Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
    let c = raytrace::cli::compare(&p, &gpu, &kernels, true).expect("compare");
    assert_eq!(c.same_build, Some(true));
    assert_eq!(c.topology_identical, Some(true));
    assert!(c.stats.relative_rmse < 0.03, "relative RMSE {}", c.stats.relative_rmse);
    assert_no_validation_errors(&gpu);
}
