//! Alpha-tested and blended glTF materials on both backends: rays pass through the holes of
//! a MASK texture (closest-hit and any-hit queries, so pictures and shadows agree), a BLEND
//! surface of coverage 0.3 stops 30% of the rays, and CPU and GPU give the same answers.
use glam::Vec3;
use integration_tests::{assert_cpu_and_gpu_agree, assert_no_validation_errors, renderer};
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::scene::{Scene, SceneGpu};
use shared::traverse;
use shared::types::{Frame, Ray, FEATURE_ALPHA, INVALID};
use std::path::{Path, PathBuf};

/// Writes a glTF of two unit quads facing +z at z = 0: `masked` (x, y in [-1, 1]) with a
/// 2 x 1 base colour texture, opaque on its left texel and transparent on its right, alpha
/// mode MASK; `blended` (x in [-1, 1], y in [3, 5]), alpha factor 0.3, alpha mode BLEND.
fn write_quads(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let png = image::RgbaImage::from_raw(2, 1, vec![255, 255, 255, 255, 255, 255, 255, 0]).unwrap();
    png.save(dir.join("alpha.png")).unwrap();
    let mut bin = Vec::new();
    let quad = |y0: f32| {
        [
            [-1.0, y0, 0.0],
            [1.0, y0, 0.0],
            [1.0, y0 + 2.0, 0.0],
            [-1.0, y0 + 2.0, 0.0f32],
        ]
    };
    for v in quad(-1.0) {
        v.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for uv in [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0f32]] {
        uv.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    for v in quad(3.0) {
        v.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    assert_eq!(bin.len(), 140);
    std::fs::write(dir.join("quads.bin"), &bin).unwrap();
    let gltf = r#"{
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0, 1]}],
  "nodes": [{"mesh": 0}, {"mesh": 1}],
  "meshes": [
    {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]},
    {"primitives": [{"attributes": {"POSITION": 3}, "indices": 2, "material": 1}]}
  ],
  "materials": [
    {"name": "masked", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0},
     "alphaMode": "MASK", "alphaCutoff": 0.5},
    {"name": "blended", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 0.3], "metallicFactor": 0},
     "alphaMode": "BLEND"}
  ],
  "textures": [{"source": 0, "sampler": 0}],
  "samplers": [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}],
  "images": [{"uri": "alpha.png"}],
  "buffers": [{"uri": "quads.bin", "byteLength": 140}],
  "bufferViews": [
    {"buffer": 0, "byteOffset": 0, "byteLength": 48},
    {"buffer": 0, "byteOffset": 48, "byteLength": 32},
    {"buffer": 0, "byteOffset": 80, "byteLength": 12},
    {"buffer": 0, "byteOffset": 92, "byteLength": 48}
  ],
  "accessors": [
    {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
    {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
    {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
    {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, 3, 0], "max": [1, 5, 0]}
  ]
}"#;
    let path = dir.join("quads.gltf");
    std::fs::write(&path, gltf).unwrap();
    path
}

fn scene(test: &str) -> (Scene, SceneGpu, Frame) {
    let dir = std::env::temp_dir().join(format!("raytrace-alpha-{test}-{}", std::process::id()));
    let (scene, warnings) = Scene::from_model(&write_quads(&dir)).expect("the quads open");
    assert!(
        !warnings.iter().any(|w| w.contains("alpha mode")),
        "alpha modes warned about: {warnings:?}"
    );
    let data = scene.gpu_data(0.0);
    // Specialised as `render` does (and the kernels compile faster on lavapipe).
    let frame = scene.frame(&data);
    let features = raytrace::features::derive(&data, &frame, &Default::default()).unwrap();
    assert_ne!(features.bits & FEATURE_ALPHA, 0, "{:?}", features.decisions);
    let frame = features.apply(&frame);
    (scene, data, frame)
}

/// Rays straight down -z from z = 2 through a grid of points of the rectangle `lo..hi`.
fn grid(lo: (f32, f32), hi: (f32, f32), n: usize) -> Vec<Ray> {
    let mut rays = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let x = lo.0 + (hi.0 - lo.0) * (i as f32 + 0.5) / n as f32;
            let y = lo.1 + (hi.1 - lo.1) * (j as f32 + 0.5) / n as f32;
            rays.push(Ray {
                origin: [x, y, 2.0, 0.0],
                dir: [0.0, 0.0, -1.0, f32::INFINITY],
            });
        }
    }
    rays
}

/// Closest-hit and any-hit answers (hit or not) of `rays` on the CPU, through the BVH.
fn cpu_queries(data: &SceneGpu, frame: &Frame, rays: &[Ray]) -> (Vec<bool>, Vec<bool>) {
    let (tris, spheres) = raytrace::cpu::world_primitives(data);
    let (bvh, _) = raytrace::cpu::build(&tris, &spheres, BuildOptions::lbvh(MortonBits::B30));
    let nodes = bvh.traced_nodes();
    let s = traverse::Scene {
        tris: bytemuck::cast_slice(&tris),
        spheres: &spheres,
        nodes: bytemuck::cast_slice(&nodes),
        wide: bytemuck::cast_slice(&bvh.wide),
        order: &bvh.sorted_prims,
        n_tris: frame.n_tris,
        n_prims: frame.n_prims,
        top: 0,
        instances: &[],
        n_instances: 0,
        coverage: data.coverage(),
        features: frame.features,
    };
    let o = |r: &Ray| Vec3::new(r.origin[0], r.origin[1], r.origin[2]);
    let d = |r: &Ray| Vec3::new(r.dir[0], r.dir[1], r.dir[2]);
    let closest = rays
        .iter()
        .map(|r| traverse::closest(&s, o(r), d(r), r.dir[3]).prim != INVALID)
        .collect();
    let any = rays.iter().map(|r| traverse::any(&s, o(r), d(r), r.dir[3])).collect();
    (closest, any)
}

fn fraction(hits: &[bool]) -> f64 {
    hits.iter().filter(|&&h| h).count() as f64 / hits.len() as f64
}

#[test]
fn rays_pass_through_masked_holes_and_blended_surfaces_in_proportion() {
    let (_, data, frame) = scene("cpu");
    // The masked quad: its left half (u < 0.5) is covered, its right half a hole.
    let left = grid((-0.95, -0.95), (-0.05, 0.95), 24);
    let right = grid((0.05, -0.95), (0.95, 0.95), 24);
    let blended = grid((-0.95, 3.05), (0.95, 4.95), 64);
    for (name, rays, want) in [("left", &left, 1.0), ("right", &right, 0.0)] {
        let (closest, any) = cpu_queries(&data, &frame, rays);
        assert_eq!(fraction(&closest), want, "{name} half, closest hits");
        assert_eq!(fraction(&any), want, "{name} half, any hits");
    }
    let (closest, any) = cpu_queries(&data, &frame, &blended);
    for (query, hits) in [("closest", &closest), ("any", &any)] {
        let f = fraction(hits);
        assert!((f - 0.3).abs() < 0.03, "blended quad, {query} hits: {f}");
    }
    // The same ray decides the same way in both queries.
    assert_eq!(closest, any);
    // Without the feature every surface is opaque again.
    let opaque = Frame {
        features: frame.features & !FEATURE_ALPHA,
        ..frame
    };
    assert_eq!(fraction(&cpu_queries(&data, &opaque, &right).0), 1.0);
}

#[test]
fn cpu_and_gpu_agree_on_holes_in_queries_and_pictures() {
    let Some((gpu, mut r)) = renderer("cpu_and_gpu_agree_on_holes_in_queries_and_pictures") else {
        return;
    };
    let (_, data, mut frame) = scene("gpu");
    let rays: Vec<Ray> = [
        grid((-0.95, -0.95), (-0.05, 0.95), 16),
        grid((0.05, -0.95), (0.95, 0.95), 16),
        grid((-0.95, 3.05), (0.95, 4.95), 48),
    ]
    .concat();
    r.set_build(BuildOptions::lbvh(MortonBits::B30));
    r.load(&data, &frame).expect("load");
    r.render(0, true).expect("build");
    let gpu_closest: Vec<bool> = r.cast(&rays).unwrap().iter().map(|h| h.prim != INVALID).collect();
    let gpu_any: Vec<bool> = r.cast_any(&rays).unwrap().iter().map(|h| h.prim != INVALID).collect();
    let (cpu_closest, cpu_any) = cpu_queries(&data, &frame, &rays);
    assert_eq!(gpu_closest, cpu_closest, "closest hits differ");
    assert_eq!(gpu_any, cpu_any, "any hits differ");
    // A picture of the quads, lit by the sky through the holes.
    frame.width = 48;
    frame.height = 48;
    assert_cpu_and_gpu_agree(&mut r, &data, &frame, 16, 0.02);
    assert_no_validation_errors(&gpu);
}
