//! HDR environment maps in the path tracer: a convex diffuse ball under a uniform map reflects
//! exactly its albedo (next-event estimation and MIS toward the map are unbiased), sampling the
//! map beats BSDF sampling under a small sun at equal rays, GGX under the map matches a furnace
//! bound, and CPU and GPU agree.
use glam::Vec3;
use integration_tests::{assert_cpu_and_gpu_agree, assert_no_validation_errors, renderer};
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cpu::render_cpu;
use raytrace::picture::{diff_stats, Picture};
use raytrace::scene::envmap::EnvMap;
use raytrace::scene::{material, CameraSpec, Environment, Scene, SceneObject, Settings, Shape, Transform};
use shared::types::FEATURE_ENVMAP;
use std::sync::Arc;

const SIZE: u32 = 32;

/// A ball of radius 1 at the origin, filling the middle of the picture, made of `m`, under
/// `map`.
fn ball_under(map: EnvMap, m: shared::types::Material, nee: bool) -> Scene {
    Scene {
        name: "ball".into(),
        camera: CameraSpec {
            position: Vec3::new(0.0, 0.0, 4.0),
            look_at: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 40.0,
            aperture: 0.0,
            focus_distance: None,
        },
        settings: Settings {
            width: SIZE,
            height: SIZE,
            max_depth: 4,
            nee,
            ..Settings::default()
        },
        materials: vec![("ball".into(), m)],
        meshes: Vec::new(),
        objects: vec![SceneObject {
            name: "ball".into(),
            shape: Shape::Sphere { radius: 1.0 },
            transform: Transform::IDENTITY,
            material: 0,
            animation: Default::default(),
            instance: None,
        }],
        punctual: Vec::new(),
        textures: Default::default(),
        environment: Some(Environment {
            map: Arc::new(map),
            rotation_deg: 30.0,
            intensity: 1.0,
        }),
    }
}

fn uniform_map() -> EnvMap {
    EnvMap::from_rgb(16, 8, &[[1.0; 3]; 128], "uniform").0
}

/// Sky 0.05 and a sun of about 3 degrees, 20000 times brighter, 30 degrees above the horizon
/// behind the camera (`u` near 0: toward `+z`, turned 30 degrees by [`ball_under`]).
fn sun_map() -> EnvMap {
    let (w, h) = (256u32, 128u32);
    let rgb: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if (0..2).contains(&x) && (42..44).contains(&y) {
                [20000.0; 3]
            } else {
                [0.05; 3]
            }
        })
        .collect();
    EnvMap::from_rgb(w, h, &rgb, "sun").0
}

fn render(scene: &Scene, spp: u32) -> Picture {
    let data = scene.gpu_data(0.0);
    let frame = scene.frame(&data);
    assert_ne!(frame.features & FEATURE_ENVMAP, 0);
    render_cpu(&data, &frame, spp, BuildOptions::lbvh(MortonBits::B30), &|_| {}).picture
}

/// Mean radiance (average of the channels) of the pixels within `r` pixels of the centre.
fn centre_mean(p: &Picture, r: f32) -> f64 {
    let lin = p.linear();
    let c = SIZE as f32 / 2.0;
    let (mut sum, mut n) = (0.0, 0);
    for y in 0..SIZE {
        for x in 0..SIZE {
            if (x as f32 + 0.5 - c).hypot(y as f32 + 0.5 - c) < r {
                let v = lin[(y * SIZE + x) as usize];
                sum += (v[0] + v[1] + v[2]) as f64 / 3.0;
                n += 1;
            }
        }
    }
    sum / n as f64
}

#[test]
fn a_diffuse_ball_under_a_uniform_map_reflects_its_albedo() {
    for nee in [true, false] {
        let p = render(&ball_under(uniform_map(), material::diffuse([0.5; 3]), nee), 64);
        let ball = centre_mean(&p, 5.0);
        assert!((ball - 0.5).abs() < 0.01, "nee {nee}: ball {ball}, want 0.5");
        // The corners see the map itself.
        let corner = p.linear()[0];
        assert!((corner[0] - 1.0).abs() < 1e-5, "background {corner:?}");
    }
}

#[test]
fn sampling_the_map_beats_bsdf_sampling_under_a_small_sun_at_equal_rays() {
    let white = material::diffuse([0.8; 3]);
    let reference = render(&ball_under(sun_map(), white, true), 512);
    // Next-event estimation traces about twice the rays a sample: give BSDF sampling twice
    // the samples.
    let with = render(&ball_under(sun_map(), white, true), 16);
    let without = render(&ball_under(sun_map(), white, false), 32);
    let (e_with, e_without) = (
        diff_stats(&with, &reference).unwrap().relative_rmse,
        diff_stats(&without, &reference).unwrap().relative_rmse,
    );
    eprintln!("relative RMSE: map sampling {e_with}, BSDF sampling {e_without}");
    assert!(
        e_with < 0.3 * e_without,
        "map sampling {e_with} vs BSDF sampling {e_without}"
    );
}

#[test]
fn ggx_under_a_uniform_map_stays_within_its_furnace_bounds() {
    // A white rough metal ball under a uniform map of radiance 1: every pixel on it sees at
    // most 1 and, by the BSDF's furnace test (shared::pbr), at least 1 - ln 2 at normal
    // incidence for roughness 1.
    for roughness in [0.2, 1.0] {
        let p = render(
            &ball_under(uniform_map(), material::pbr([1.0; 3], 1.0, roughness, 1.5), true),
            64,
        );
        let centre = centre_mean(&p, 2.0);
        assert!(centre <= 1.01, "roughness {roughness}: {centre}");
        assert!(
            centre >= 1.0 - std::f64::consts::LN_2 - 0.02,
            "roughness {roughness}: {centre}"
        );
    }
}

#[test]
fn cpu_and_gpu_agree_under_an_environment_map() {
    let Some((gpu, mut r)) = renderer("cpu_and_gpu_agree_under_an_environment_map") else {
        return;
    };
    let scene = ball_under(sun_map(), material::pbr([0.9, 0.6, 0.3], 0.3, 0.4, 1.5), true);
    let data = scene.gpu_data(0.0);
    let frame = scene.frame(&data);
    assert_cpu_and_gpu_agree(&mut r, &data, &frame, 16, 0.02);
    assert_no_validation_errors(&gpu);
}
