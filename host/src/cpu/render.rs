//! The CPU renderer: the transform, BVH build, path tracing and display kernels of `shared`
//! run by the CPU executor (pixels in parallel with rayon: each writes only its own sum).
use crate::bvh::{build_levels, inverse_rows, BuildOptions, BuildResult, Levels, MeshPrims, Placement};
use crate::picture::Picture;
use crate::scene::{Instancing, SceneGpu};
use rayon::prelude::*;
use shared::denoise::Guide;
use shared::path::{self, World};
use shared::traverse::Scene;
use shared::types::{BuildParams, Frame, Object, RenderPush, Sphere, Triangle, FEATURE_GUIDES};
use std::time::Instant;

/// A CPU render: the picture, stage times in seconds, and the BVH it traced through.
pub struct CpuRender {
    pub picture: Picture,
    pub timings: Vec<(&'static str, f64)>,
    pub bvh: BuildResult,
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
    /// The denoiser's guides, where the frame's features ask for them (`FEATURE_GUIDES`).
    pub guides: Vec<Guide>,
}

/// The display kernel (`shared::display`) over every pixel of `accum`, in parallel.
pub fn display_image(accum: &[[f32; 4]], push: &RenderPush, frame: &Frame) -> Vec<u32> {
    accum
        .par_iter()
        .map(|&a| shared::display::pixel(a, push, frame))
        .collect()
}

/// The scene's primitives in world space: the transform kernel run for each (what the GPU's
/// transform stage writes).
pub fn world_primitives(scene: &SceneGpu) -> (Vec<Triangle>, Vec<Sphere>) {
    let (n_tris, n_spheres) = (scene.model_tris.len(), scene.model_spheres.len());
    transformed(
        &scene.objects,
        &scene.prim_object,
        &scene.model_tris,
        &scene.model_spheres,
        n_tris,
        n_spheres,
    )
}

/// The transform kernel over the first `n_tris` triangles and `n_spheres` spheres of
/// `model_tris` and `model_spheres` (their objects in `prim_object`), with `objects`.
pub fn transformed(
    objects: &[Object],
    prim_object: &[u32],
    model_tris: &[Triangle],
    model_spheres: &[Sphere],
    n_tris: usize,
    n_spheres: usize,
) -> (Vec<Triangle>, Vec<Sphere>) {
    let p = BuildParams {
        n_tris: n_tris as u32,
        n: (n_tris + n_spheres) as u32,
        shift: 0,
        passes: 0,
    };
    let mut tris = vec![Triangle::default(); n_tris];
    let mut spheres = vec![Sphere::default(); n_spheres];
    for i in 0..p.n {
        shared::transform::transform(
            i,
            &p,
            objects,
            prim_object,
            model_tris,
            model_spheres,
            bytemuck::cast_slice_mut(&mut tris),
            &mut spheres,
        );
    }
    (tris, spheres)
}

/// What both levels of an instanced scene are built from with its objects at `objects`:
/// the meshes, the world-space group (`Instancing::world_tris`, mesh 0) transformed as the
/// GPU's frame transforms it, and every instance where its object is. The layout was
/// checked when the data was made (`Scene::gpu_data_instanced`); an object moved since to a
/// transform that cannot be inverted stays where the data put it, with a warning.
pub fn levels_inputs<'a>(
    scene: &SceneGpu,
    i: &'a Instancing,
    objects: &[Object],
) -> (std::borrow::Cow<'a, [MeshPrims]>, Vec<Placement>) {
    let placements: Vec<Placement> = i
        .placements_at(objects)
        .into_iter()
        .zip(&i.placements)
        .map(|(moved, made)| match inverse_rows(&moved.rows) {
            Ok(_) => moved,
            Err(e) => {
                eprintln!("warning: object {} is not moved: {e}", made.object);
                *made
            }
        })
        .collect();
    let mut meshes = std::borrow::Cow::Borrowed(&i.meshes[..]);
    if i.world_tris > 0 {
        let n = i.world_tris as usize;
        meshes.to_mut()[0].tris = transformed(objects, &scene.prim_object, &scene.model_tris, &[], n, 0).0;
    }
    (meshes, placements)
}

/// Both levels of an instanced scene with its objects at `objects`, built by the CPU
/// executor from [`levels_inputs`].
fn levels_at(scene: &SceneGpu, i: &Instancing, objects: &[Object], build: BuildOptions) -> Levels {
    let (meshes, placements) = levels_inputs(scene, i, objects);
    // The placements' meshes and transforms were checked by the layout that made `i`.
    build_levels(&meshes, &placements, build).unwrap_or_default()
}

/// What the path tracer reads of `scene`: `traced` (its primitives and BVH), the objects and
/// lights bindings (`objects`, `lights`), `frame`, and the scene's materials, attributes,
/// lights, environment and textures.
fn world<'a>(
    scene: &'a SceneGpu,
    traced: Scene<'a>,
    objects: &'a [Object],
    lights: &'a [u32],
    frame: &'a Frame,
) -> World<'a> {
    World {
        scene: traced,
        objects,
        prim_object: &scene.prim_object,
        materials: &scene.materials,
        lights,
        frame,
        attrs: &scene.attrs,
        punctual: &scene.punctual,
        env: scene.env.as_ref().map_or(&[], |e| e.entries.as_slice()),
        textures: &scene.textures.infos,
        texels: &scene.textures.texels,
    }
}

/// Renders `samples` samples per pixel of `scene` with `frame`; `progress` is called with
/// the number of rows finished.
pub fn render_cpu(
    scene: &SceneGpu,
    frame: &Frame,
    samples: u32,
    build: BuildOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> CpuRender {
    render_cpu_moving(scene, &scene.objects, frame, samples, build, progress)
}

/// [`render_cpu`] of a frame whose objects were at `previous` in the frame before (where
/// `frame.prev_objects` says so: the denoiser's motion vectors).
pub fn render_cpu_moving(
    scene: &SceneGpu,
    previous: &[Object],
    frame: &Frame,
    samples: u32,
    build: BuildOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> CpuRender {
    render_cpu_samples(scene, previous, frame, 0, samples, build, progress)
}

/// [`render_cpu_moving`] of samples `first..first + samples` (`render --shard`: the sums of a
/// frame's later samples alone).
pub fn render_cpu_samples(
    scene: &SceneGpu,
    previous: &[Object],
    frame: &Frame,
    first: u32,
    samples: u32,
    build: BuildOptions,
    progress: &(dyn Fn(u32) + Sync),
) -> CpuRender {
    // The objects binding: the current objects, then the previous ones.
    let objects = [scene.objects.as_slice(), previous].concat();
    let mut timings = Vec::new();
    let t = Instant::now();
    let (tris, spheres) = match scene.instancing {
        Some(_) => (Vec::new(), Vec::new()),
        None => world_primitives(scene),
    };
    timings.push(("transform", t.elapsed().as_secs_f64()));
    let (bvh, build_times) = match scene.instancing {
        Some(_) => Default::default(),
        None => crate::cpu::build(&tris, &spheres, build),
    };
    timings.extend(build_times);
    let nodes = bvh.traced_nodes();
    // Two levels: every mesh's BVH and the top level over the objects where they are now.
    let t = Instant::now();
    let levels = scene
        .instancing
        .as_ref()
        .map(|i| levels_at(scene, i, &scene.objects, build));
    if levels.is_some() {
        timings.push(("levels", t.elapsed().as_secs_f64()));
    }
    // Lights, and with two levels the objects showing them.
    let lights = scene.light_words();

    let t = Instant::now();
    // A segment at a time (`path::pixel_samples_guided`): the CPU executor runs a subgroup of
    // one lane, so the stepped loop would keep no other lanes walking (the unit test below
    // runs it).
    let features = crate::render::tracer_features(frame, build);
    let traced = match &levels {
        Some(l) => Scene {
            coverage: scene.coverage(),
            ..l.scene(features)
        },
        None => Scene {
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
            coverage: scene.coverage(),
            features,
        },
    };
    let world = world(scene, traced, &objects, &lights, frame);
    let push = RenderPush {
        sample_base: first,
        samples,
        ..Default::default()
    };
    let (w, h) = (frame.width, frame.height);
    let done = std::sync::atomic::AtomicU32::new(0);
    let guided = world.scene.features & FEATURE_GUIDES != 0;
    let mut accum = vec![[0.0f32; 4]; (w * h) as usize];
    let mut guides = vec![Guide::NONE; (w * h) as usize];
    let rows = accum.par_chunks_mut(w as usize).zip(guides.par_chunks_mut(w as usize));
    rows.enumerate().for_each(|(y, (row, guide_row))| {
        for (x, (a, g)) in row.iter_mut().zip(guide_row).enumerate() {
            (*a, *g) = path::pixel_samples_guided(x as u32, y as u32, &push, &world, &mut path::Walk);
        }
        progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
    });
    timings.push(("trace", t.elapsed().as_secs_f64()));
    if !guided {
        guides = Vec::new();
    }

    let t = Instant::now();
    let display = display_image(&accum, &push, frame);
    timings.push(("display", t.elapsed().as_secs_f64()));
    // Two levels: both levels' nodes and the meshes' primitives stand for the BVH and the
    // world (what `GpuRenderer::bvh` and `world` read back then).
    let (bvh, tris, spheres) = match levels {
        Some(l) => (
            BuildResult {
                nodes: l.nodes,
                ..Default::default()
            },
            l.tris,
            l.spheres,
        ),
        None => (bvh, tris, spheres),
    };
    CpuRender {
        picture: Picture {
            width: w,
            height: h,
            accum,
            samples,
            display,
        },
        timings,
        bvh,
        tris,
        spheres,
        guides,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::SceneArgs;
    use shared::types::{DISPLAY_BGRA, DISPLAY_IN_TRACE, FEATURE_INSTANCES, FEATURE_NEE, VARIANT_GROUPS};

    /// The shadow queue's passes run on the CPU over one band of a scene in two levels: the
    /// persistent resolve (one invocation taking every pixel, its next ray started as its walk
    /// ends) adds what the per-pixel resolve adds, and both what the path tracer casting in
    /// place adds, bit for bit. (On the GPU the persistent kernels run off lavapipe only; this
    /// runs their code everywhere.)
    #[test]
    fn the_persistent_shadow_resolve_adds_what_casting_in_place_adds() {
        for scene_name in ["cornell", "instances"] {
            let args = ["raytrace", scene_name, "--size", "40x30", "--instancing", "on"];
            let p = <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene");
            let (scene, frame) = (&p.data, &p.frame);
            let build = p.build(1);
            let levels = levels_at(
                scene,
                scene.instancing.as_ref().expect("two levels"),
                &scene.objects,
                build,
            );
            let features = crate::render::tracer_features(frame, build) & !FEATURE_GUIDES;
            assert!(features & FEATURE_INSTANCES != 0 && features & FEATURE_NEE != 0);
            let objects = [scene.objects.as_slice(), &scene.objects].concat();
            let lights = scene.light_words();
            let traced = Scene {
                coverage: scene.coverage(),
                ..levels.scene(features)
            };
            let world = world(scene, traced, &objects, &lights, frame);
            let (w, h) = (frame.width, frame.height);
            let band = w * h;
            let push = RenderPush {
                samples: 1,
                rows: h,
                ..Default::default()
            };
            let mut queue = vec![[0.0f32; 4]; path::queue_entries(band, frame.max_depth) as usize];
            // The guides buffer's last entry is the persistent kernels' counter.
            let mut counter = vec![[0u32; 4]];
            for y in 0..h {
                for x in 0..w {
                    path::queue_pixel(x, y, &push, &world, &mut counter, &mut queue);
                }
            }
            let slots: Vec<u32> = (0..band).map(|i| queue[(band + i) as usize][3] as u32).collect();
            let mut per_pixel = vec![[0.0f32; 4]; band as usize];
            for i in 0..band {
                path::resolve_pixel(i, &push, &world, &mut path::Walk, &mut per_pixel, &mut counter, &queue);
            }
            let mut persistent = vec![[0.0f32; 4]; band as usize];
            path::resolve_tiles(&push, &world, &mut persistent, &mut counter, &queue);
            let mut lit = 0;
            for i in 0..band {
                let (x, y) = (i % w, i / w);
                let in_place = path::pixel_samples_guided(x, y, &push, &world, &mut path::Walk).0;
                let bits = |a: [f32; 4]| a.map(f32::to_bits);
                assert_eq!(
                    bits(per_pixel[i as usize]),
                    bits(in_place),
                    "{scene_name} pixel ({x}, {y})"
                );
                assert_eq!(
                    bits(persistent[i as usize]),
                    bits(in_place),
                    "{scene_name} pixel ({x}, {y})"
                );
                // Pixels whose shadow rays reached the light: the queue's path radiance
                // without next-event estimation is less than the sample.
                if slots[i as usize] > 0 && queue[i as usize][0] != in_place[0] {
                    lit += 1;
                }
            }
            // Every pixel taken once, and the queue not trivial: many pixels queued a shadow
            // ray and were lit by one (the sixteen bunnies at 40x30: 519 and 449 of 1,200).
            assert_eq!(counter[0][0], band + 1, "{scene_name}");
            let queued = slots.iter().filter(|&&s| s > 0).count() as u32;
            assert!(
                queued > band / 3 && lit > band / 4,
                "{scene_name}: {queued} queued, {lit} lit of {band}"
            );
            assert!(slots.iter().all(|&s| s < frame.max_depth), "{scene_name}");
        }
    }

    /// The stepped path loop (`path::stepped_pixels`: the walks stepped in a loop of their
    /// own, lanes waiting for half their subgroup before they shade) traces each pixel's
    /// samples exactly as the loop of a segment at a time does, both for one pixel (the
    /// `path_stepped` kernel) and pixel after pixel from the counter (`path_stepped_persistent`,
    /// which runs off lavapipe only): samples, rays and guides bit for bit, also without the
    /// BVH and at depth 0 (where the host leaves the loop out); with `DISPLAY_IN_TRACE` it
    /// writes the same sums over whatever the accumulation held and displays them; and with
    /// `VARIANT_GROUPS` its groups of a pixel's samples add up, in group order, to the groups
    /// traced apart.
    #[test]
    fn the_stepped_path_loop_traces_what_a_segment_at_a_time_traces() {
        let cases: [&[&str]; 4] = [
            &["cornell", "--spp", "3", "--no-nee"],
            &["spheres", "--spp", "2", "--no-nee", "--no-roulette"],
            &["bunny", "--spp", "2", "--no-nee", "--depth", "6"],
            &["cornell", "--spp", "2", "--no-nee", "--no-bvh"],
        ];
        for (case, extra) in cases.iter().enumerate() {
            let args = [&["raytrace", "--size", "24x18"][..], extra].concat();
            let p = <SceneArgs as clap::Parser>::parse_from(args).prepare().expect("scene");
            let (scene, frame) = (&p.data, &p.frame);
            for depth in [frame.max_depth, 0] {
                let mut frame = *frame;
                frame.max_depth = depth;
                // The denoiser's guides too in one case (the first hits it captures).
                if case == 2 {
                    frame.features |= FEATURE_GUIDES;
                }
                assert_eq!(frame.features & (FEATURE_NEE | FEATURE_INSTANCES), 0, "{extra:?}");
                let build = p.build(1);
                let (tris, spheres) = world_primitives(scene);
                let (bvh, _) = crate::cpu::build(&tris, &spheres, build);
                let nodes = bvh.traced_nodes();
                let traced = Scene {
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
                    coverage: scene.coverage(),
                    features: crate::render::tracer_features(&frame, build),
                };
                let lights = scene.light_words();
                let grouped = Scene {
                    features: traced.features | VARIANT_GROUPS,
                    ..traced
                };
                let grouped_world = world(scene, grouped, &scene.objects, &lights, &frame);
                let world = world(scene, traced, &scene.objects, &lights, &frame);
                let push = RenderPush {
                    samples: 2,
                    sample_base: 5,
                    ..Default::default()
                };
                let (w, h) = (frame.width, frame.height);
                // The persistent loop: accumulation, guides (the counter in the last entry).
                let mut accum = vec![[0.0f32; 4]; (w * h) as usize];
                let mut guides = vec![[0u32; 4]; (w * h * 4 + 1) as usize];
                path::stepped_tiles(&push, &world, &mut accum, &mut guides, &mut []);
                assert_eq!(guides[(w * h * 4) as usize][0], w.div_ceil(8) * h.div_ceil(4) * 32 + 1);
                // A frame's one dispatch that displays it (`DISPLAY_IN_TRACE`): sums written over
                // what the accumulation held, display codes as the display pass packs them.
                let shown = RenderPush {
                    flags: DISPLAY_IN_TRACE | DISPLAY_BGRA,
                    ..push
                };
                let mut written = vec![[7.5f32, -1.0, f32::NAN, 3.0]; (w * h) as usize];
                let mut image = vec![0u32; (w * h) as usize];
                let mut counter = vec![[0u32; 4]; (w * h * 4 + 1) as usize];
                path::stepped_tiles(&shown, &world, &mut written, &mut counter, &mut image);
                let mut rays = 0.0;
                for y in 0..h {
                    for x in 0..w {
                        let (stepped, g1) = path::stepped_samples(x, y, &push, &world);
                        let (segments, g2) = path::pixel_samples_guided(x, y, &push, &world, &mut path::Walk);
                        let bits = |a: [f32; 4]| a.map(f32::to_bits);
                        let at = format!("{extra:?} depth {depth} pixel ({x}, {y})");
                        assert_eq!(bits(stepped), bits(segments), "{at}");
                        assert_eq!(bytemuck::bytes_of(&g1), bytemuck::bytes_of(&g2), "{at}");
                        assert_eq!(bits(accum[(y * w + x) as usize]), bits(stepped), "{at}");
                        assert_eq!(bits(written[(y * w + x) as usize]), bits(stepped), "{at}");
                        let code = shared::display::pixel(stepped, &shown, &frame);
                        assert_eq!(image[(y * w + x) as usize], code, "{at}");
                        rays += stepped[3];
                    }
                }
                if depth > 0 {
                    assert!(rays >= (w * h * 2) as f32, "{extra:?}: {rays} rays");
                } else {
                    assert_eq!(rays, 0.0, "{extra:?}");
                }
                if frame.features & FEATURE_GUIDES == 0 {
                    // With `VARIANT_GROUPS` (the host's persistent dispatches of several
                    // groups): 7 samples in groups of 3, 3 and 1, each group's sums written
                    // past the image, then added in group order to what each pixel held.
                    let (samples, groups, pixels) = (7, 3, w * h);
                    let push = RenderPush {
                        samples,
                        sample_base: 5,
                        flags: groups,
                        ..Default::default()
                    };
                    let held = [0.5, 0.25, 2.0, 3.0];
                    let mut accum = vec![held; (pixels * (1 + groups)) as usize];
                    let mut guides = vec![[0u32; 4]; (pixels * 4 + 1) as usize];
                    path::stepped_tiles(&push, &grouped_world, &mut accum, &mut guides, &mut []);
                    let items = w.div_ceil(8) * h.div_ceil(4) * 32 * groups;
                    assert_eq!(guides[(pixels * 4) as usize][0], items + 1, "{extra:?}");
                    for pixel in 0..pixels {
                        path::add_groups(pixel, pixels, groups, &mut accum);
                    }
                    for (pixel, got) in accum[..pixels as usize].iter().enumerate() {
                        let (x, y) = (pixel as u32 % w, pixel as u32 / w);
                        let sums: Vec<[f32; 4]> = (0..groups)
                            .map(|g| {
                                let (first, count) = path::group_samples(samples, groups, g);
                                let q = RenderPush {
                                    sample_base: 5 + first,
                                    samples: count,
                                    ..Default::default()
                                };
                                path::pixel_samples(x, y, &q, &world)
                            })
                            .collect();
                        let add = |a: [f32; 4], b: [f32; 4]| [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]];
                        let expected = add(held, sums[1..].iter().fold(sums[0], |t, s| add(t, *s)));
                        let at = format!("{extra:?} depth {depth} pixel ({x}, {y}), grouped");
                        assert_eq!(got.map(f32::to_bits), expected.map(f32::to_bits), "{at}");
                    }
                }
            }
        }
    }
}
