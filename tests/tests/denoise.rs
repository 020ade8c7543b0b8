//! The denoiser (`shared::denoise`, SVGF): a constant image stays constant, an edge between
//! two objects is not blurred across, non-finite samples do not spread, a moved object leaves
//! no ghost, motion vectors are exact, and the GPU's guides and denoised images equal the CPU
//! executor's.
use glam::Vec3;
use integration_tests::{assert_no_validation_errors, renderer};
use raytrace::bvh::{BuildOptions, MortonBits};
use raytrace::cpu::{render_cpu, render_cpu_moving, CpuDenoiser};
use raytrace::gpu::Denoise;
use raytrace::picture::diff_stats;
use raytrace::scene::{Scene, SceneGpu};
use shared::denoise::{self, Guide};
use shared::types::{xyz, Frame, Object, FEATURE_GUIDES, FLAG_DENOISE, INVALID};

const SIZE: u32 = 48;

fn build() -> BuildOptions {
    BuildOptions::lbvh(MortonBits::B30)
}

/// The Cornell box at `SIZE x SIZE` with the guides on.
fn cornell() -> (Scene, SceneGpu, Frame) {
    let mut scene = Scene::builtin("cornell").expect("cornell");
    scene.settings.width = SIZE;
    scene.settings.height = SIZE;
    let data = scene.gpu_data(0.0);
    let mut frame = scene.frame(&data);
    frame.flags |= FLAG_DENOISE;
    frame.features |= FEATURE_GUIDES;
    (scene, data, frame)
}

/// A frame's guides of a plane facing the camera at distance 5: object `object(x, y)`,
/// colour `color(x, y)` (one sample), albedo 1.
fn plane(frame: &Frame, object: impl Fn(u32, u32) -> u32, color: impl Fn(u32, u32) -> [f32; 3]) -> Vec<Guide> {
    let c = &frame.camera;
    let normal = denoise::oct_encode((xyz(c.origin) - xyz(c.lower_left)).normalize());
    (0..frame.width * frame.height)
        .map(|i| {
            let (x, y) = (i % frame.width, i / frame.width);
            Guide {
                color: color(x, y),
                prev_x: x as f32 + 0.5,
                prev_y: y as f32 + 0.5,
                albedo: [1.0; 3],
                object: object(x, y),
                normal,
                depth: 5.0,
                prev_depth: 5.0,
                ..Guide::NONE
            }
        })
        .collect()
}

/// A hash of `(x, y, k)` in `[0, 1)`: per-pixel noise.
fn noise(x: u32, y: u32, k: u32) -> f32 {
    let mut h = x.wrapping_mul(0x9e37_79b9) ^ y.wrapping_mul(0x85eb_ca6b) ^ k.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

#[test]
fn a_constant_image_stays_constant() {
    let (_, _, frame) = cornell();
    let guides = plane(&frame, |_, _| 0, |_, _| [0.3, 0.5, 0.7]);
    let mut d = CpuDenoiser::default();
    for k in 0..3 {
        let out = d.run(&frame, &guides, 1, true, k > 0);
        for o in &out.output {
            // To the filter's half-float rounding (2^-11).
            for (c, want) in o.iter().zip([0.3, 0.5, 0.7]) {
                assert!((c - want).abs() <= 5e-4 * want, "frame {k}: {o:?}");
            }
        }
    }
}

#[test]
fn an_edge_between_two_objects_is_not_blurred_across() {
    let (_, _, frame) = cornell();
    let half = SIZE / 2;
    // Noisy red on the left object, noisy blue on the right one, in one plane: only the
    // objects tell them apart.
    let guides = plane(
        &frame,
        |x, _| u32::from(x >= half),
        |x, y| {
            let n = 2.0 * noise(x, y, 0);
            if x < half {
                [n, 0.0, 0.0]
            } else {
                [0.0, 0.0, n]
            }
        },
    );
    let out = CpuDenoiser::default().run(&frame, &guides, 1, false, false);
    for y in 0..SIZE {
        for x in [half - 1, half] {
            let o = out.output[(y * SIZE + x) as usize];
            let (own, other) = if x < half { (o[0], o[2]) } else { (o[2], o[0]) };
            assert_eq!(other, 0.0, "pixel ({x}, {y}) took colour across the edge: {o:?}");
            assert!(own > 0.2, "pixel ({x}, {y}) lost its own colour: {o:?}");
        }
    }
    // And the noise is filtered: the edge columns' spread is far below the input's.
    let spread = |x: u32, k: usize| {
        let v: Vec<f32> = (0..SIZE).map(|y| out.output[(y * SIZE + x) as usize][k]).collect();
        let mean = v.iter().sum::<f32>() / v.len() as f32;
        (v.iter().map(|a| (a - mean) * (a - mean)).sum::<f32>() / v.len() as f32).sqrt()
    };
    // The input's deviation is 2 / sqrt(12) = 0.58.
    assert!(spread(half - 1, 0) < 0.2 && spread(half, 2) < 0.2);
}

#[test]
fn non_finite_samples_do_not_spread() {
    let (_, _, frame) = cornell();
    let bad = [(10, 10, f32::NAN), (30, 20, f32::INFINITY), (31, 20, f32::NEG_INFINITY)];
    let guides = plane(
        &frame,
        |_, _| 0,
        |x, y| match bad.iter().find(|b| (b.0, b.1) == (x, y)) {
            Some(b) => [b.2, 0.5, b.2],
            None => [0.5; 3],
        },
    );
    let mut d = CpuDenoiser::default();
    for k in 0..3 {
        let out = d.run(&frame, &guides, 1, true, true);
        for (i, o) in out.output.iter().enumerate() {
            assert!(o.iter().all(|c| c.is_finite()), "frame {k}, pixel {i}: {o:?}");
            // A bad sample counts as black in one pixel: its neighbours stay near 0.5.
            let (x, y) = (i as u32 % SIZE, i as u32 / SIZE);
            if !bad.iter().any(|b| (b.0, b.1) == (x, y)) {
                assert!(o[..3].iter().all(|c| (c - 0.5).abs() < 0.05), "pixel ({x}, {y}): {o:?}");
            }
        }
    }
}

/// `objects` with object `k` moved by `by`.
fn moved(objects: &[Object], k: usize, by: Vec3) -> Vec<Object> {
    let mut o = objects.to_vec();
    for (row, d) in o[k].rows.iter_mut().zip(by.to_array()) {
        row[3] += d;
    }
    o
}

/// The last object of the Cornell box (a box on the floor).
fn mover(data: &SceneGpu) -> usize {
    data.objects.len() - 1
}

#[test]
fn motion_vectors_follow_the_objects_and_the_camera() {
    let (_, data, mut frame) = cornell();
    let k = mover(&data);
    let shift = Vec3::new(0.3, 0.0, 0.0);
    let before = moved(&data.objects, k, -shift);
    frame.prev_objects = data.objects.len() as u32;
    // The previous camera stood 0.2 to the left.
    let mut prev = frame.camera;
    for v in [&mut prev.origin, &mut prev.lower_left] {
        v[0] -= 0.2;
    }
    frame.prev_camera = prev;
    let cpu = render_cpu_moving(&data, &before, &frame, 1, build(), &|_| {});
    let mut checked = 0;
    for (i, g) in cpu.guides.iter().enumerate() {
        if g.object == INVALID {
            continue;
        }
        // The hit point, from the pixel's ray (the jitter is unknown: within the pixel).
        let (x, y) = (i as u32 % SIZE, i as u32 / SIZE);
        let d = denoise::pixel_direction(&frame.camera, SIZE, SIZE, x, y);
        let p = xyz(frame.camera.origin) + d * g.depth;
        let back = if g.object as usize == k { p - shift } else { p };
        let (px, py, dist) = denoise::project(&prev, SIZE, SIZE, back);
        // Within the pixel's footprint (the sample's jitter), and the distance to a few ulps
        // of the scene's size.
        assert!(
            (g.prev_x - px).abs() < 1.0 && (g.prev_y - py).abs() < 1.0,
            "pixel ({x}, {y}) object {}: motion to ({}, {}), expected ({px}, {py})",
            g.object,
            g.prev_x,
            g.prev_y
        );
        assert!((g.prev_depth - dist).abs() < 0.05 * dist);
        checked += 1;
    }
    assert!(checked > (SIZE * SIZE / 2) as usize);
}

#[test]
fn motion_inverts_the_object_transform_exactly() {
    // A turned, scaled and moved object; a point on it now and where the same model point
    // was under the previous transform.
    let transform = |turn: f32, scale: f32, at: Vec3| {
        let m = glam::Mat3::from_rotation_y(turn) * glam::Mat3::from_diagonal(Vec3::new(scale, 1.0, -scale));
        let c = m.inverse().transpose() * m.determinant();
        let rows = |a: glam::Mat3, t: Vec3| {
            let r = a.transpose();
            [
                [r.x_axis.x, r.x_axis.y, r.x_axis.z, t.x],
                [r.y_axis.x, r.y_axis.y, r.y_axis.z, t.y],
                [r.z_axis.x, r.z_axis.y, r.z_axis.z, t.z],
            ]
        };
        (
            Object {
                rows: rows(m, at),
                normal_rows: rows(c, Vec3::ZERO),
                ..Object::default()
            },
            m,
        )
    };
    let (now, m_now) = transform(0.7, 2.0, Vec3::new(1.0, 0.5, -3.0));
    let (then, m_then) = transform(0.5, 1.5, Vec3::new(0.8, 0.4, -3.2));
    let (_, _, mut frame) = cornell();
    frame.prev_objects = 1;
    let objects = [now, then];
    for q in [
        Vec3::new(0.1, 0.2, 0.3),
        Vec3::new(-0.4, 0.0, 0.25),
        Vec3::new(0.3, -0.2, -0.1),
    ] {
        let p = m_now * q + Vec3::new(1.0, 0.5, -3.0);
        let expected = m_then * q + Vec3::new(0.8, 0.4, -3.2);
        let got = denoise::motion(&frame, &objects, 0, p);
        let want = denoise::project(&frame.prev_camera, SIZE, SIZE, expected);
        assert!(
            (got.0 - want.0).abs() < 1e-3 && (got.1 - want.1).abs() < 1e-3 && (got.2 - want.2).abs() < 1e-5,
            "{got:?} != {want:?}"
        );
    }
}

#[test]
fn a_moved_object_leaves_no_ghost() {
    let (_, data, mut frame) = cornell();
    let k = mover(&data);
    frame.prev_objects = data.objects.len() as u32;
    // The box stands still for 8 frames, jumps 0.35 to the side, and 12 frames later the
    // image must match one where it always stood there.
    let away = moved(&data.objects, k, Vec3::new(0.35, 0.0, 0.0));
    let run = |path: &[&[Object]]| {
        let mut d = CpuDenoiser::default();
        let mut prev = path[0];
        let mut out = None;
        for (n, objects) in path.iter().enumerate() {
            let mut f = frame;
            f.seed = n as u32;
            let scene = SceneGpu {
                objects: objects.to_vec(),
                ..data.clone()
            };
            let r = render_cpu_moving(&scene, prev, &f, 1, build(), &|_| {});
            out = Some(d.run(&f, &r.guides, 1, n > 0, false));
            prev = objects;
        }
        out.expect("frames")
    };
    let mut jumped: Vec<&[Object]> = vec![&data.objects; 8];
    jumped.extend(vec![away.as_slice(); 12]);
    let always = vec![away.as_slice(); 20];
    let (a, b) = (run(&jumped), run(&always));
    let mean = |o: &[[f32; 4]]| o.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>() / o.len() as f64;
    let diff = a
        .output
        .iter()
        .zip(&b.output)
        .map(|(p, q)| (0..3).map(|c| (p[c] - q[c]).abs() as f64).sum::<f64>())
        .sum::<f64>()
        / a.output.len() as f64;
    // The same noise (same seeds), the same scene for the last 12 frames: what remains of the
    // box's old place is the history's lag, 0.8^12 = 7% of the difference at the jump at
    // most, and much less where the history was rejected.
    assert!(
        diff < 0.03 * mean(&b.output),
        "mean difference {diff} of {}",
        mean(&b.output)
    );
}

#[test]
fn gpu_guides_and_denoised_images_equal_the_cpu() {
    let Some((gpu, mut r)) = renderer("gpu_guides_and_denoised_images_equal_the_cpu") else {
        return;
    };
    let (_, data, frame) = cornell();
    let k = mover(&data);
    // A render's denoising (all samples, no history).
    let cpu = render_cpu(&data, &frame, 4, build(), &|_| {});
    let cpu_picture = cpu
        .picture
        .clone()
        .denoised(&CpuDenoiser::default().run(&frame, &cpu.guides, 4, false, false));
    r.set_build(build());
    r.load(&data, &frame).expect("load");
    r.set_denoise(Denoise::Accumulated).expect("denoise");
    r.render(4, true).expect("render");
    let d = diff_stats(&cpu_picture, &r.picture().expect("picture")).expect("diff");
    assert!(
        d.relative_rmse < 0.03,
        "denoised render: relative RMSE {}",
        d.relative_rmse
    );

    // Real time: a frame, the box moved, the next frame; the guides' motion equals the CPU's.
    r.set_denoise(Denoise::EveryFrame).expect("denoise");
    r.render(1, true).expect("frame 1");
    let away = moved(&data.objects, k, Vec3::new(0.2, 0.0, 0.0));
    r.set_objects(&away).expect("move");
    r.render(1, true).expect("frame 2");
    let gpu_guides = r.guides().expect("guides");
    let mut f = frame;
    f.prev_objects = data.objects.len() as u32;
    // The renderer changed the seed when the accumulation restarted.
    f.seed = r.traced_seed();
    let scene = SceneGpu {
        objects: away.clone(),
        ..data.clone()
    };
    let cpu = render_cpu_moving(&scene, &data.objects, &f, 1, build(), &|_| {});
    let mut same = 0;
    for (g, c) in gpu_guides.iter().zip(&cpu.guides) {
        if g.object != c.object || g.object == INVALID {
            continue;
        }
        same += 1;
        assert!(
            (g.prev_x - c.prev_x).abs() < 1e-3 && (g.prev_y - c.prev_y).abs() < 1e-3,
            "GPU motion ({}, {}), CPU ({}, {})",
            g.prev_x,
            g.prev_y,
            c.prev_x,
            c.prev_y
        );
        assert!((g.depth - c.depth).abs() <= 1e-4 * c.depth);
    }
    assert!(
        same > (SIZE * SIZE * 9 / 10) as usize,
        "{same} pixels hit the same object"
    );
    assert_no_validation_errors(&gpu);
}

#[test]
fn a_removed_object_leaves_no_trace_in_the_next_denoised_frame() {
    let test = "a_removed_object_leaves_no_trace_in_the_next_denoised_frame";
    let Some(gpu) = integration_tests::gpu(test) else {
        return;
    };
    let kernels = std::sync::Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
    let mut scene = Scene::builtin("cornell").expect("cornell");
    (scene.settings.width, scene.settings.height) = (32, 32);
    let target = scene.camera.look_at;
    let mut live = raytrace::view::LiveScene::new(scene);
    let mut r = raytrace::gpu::GpuRenderer::new(&gpu, &kernels).expect("renderer");
    r.set_denoise(Denoise::EveryFrame).expect("denoise");
    let frame = |live: &mut raytrace::view::LiveScene, r: &mut raytrace::gpu::GpuRenderer| {
        live.sync(r).expect("sync");
        r.render(1, true).expect("render");
        r.picture().expect("picture")
    };
    frame(&mut live, &mut r);
    // A sphere in the middle of the view for four denoised frames, moving, then removed.
    let sphere = live.add_sphere(target, 0.25 * target.length().max(1.0));
    for k in 0..4 {
        frame(&mut live, &mut r);
        live.translate(sphere, Vec3::new(0.01 * k as f32, 0.0, 0.0))
            .expect("move");
    }
    live.remove(sphere).expect("remove");
    let after = frame(&mut live, &mut r);
    // The same scene loaded by a renderer that never saw the sphere.
    let mut fresh = raytrace::gpu::GpuRenderer::new(&gpu, &kernels).expect("renderer");
    fresh.set_denoise(Denoise::EveryFrame).expect("denoise");
    fresh
        .load(&live.scene.gpu_data(live.time), &live.frame())
        .expect("load");
    fresh.render(1, true).expect("render");
    let clean = fresh.picture().expect("picture");
    assert_eq!(
        after.accum, clean.accum,
        "the removed sphere left a trace in the denoised frame"
    );
    assert_eq!(after.display, clean.display);
    assert_no_validation_errors(&gpu);
}
