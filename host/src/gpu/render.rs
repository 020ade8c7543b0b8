//! The GPU renderer. One command buffer per frame: transform every primitive to world space,
//! rebuild the BVH (the LBVH of `GpuLbvh`), trace samples into the float accumulation
//! image, and run the display pass; a timestamp after each stage.
use crate::bvh::{BuildOptions, BuildResult, Levels, MortonBits};
use crate::gpu::denoise::{guide_bytes, GpuDenoiser};
use crate::gpu::driver::{DriverBuild, DriverInstance, DriverMesh, DriverScene, DriverTracer, CAST_RAYS, PATH_TRACE};
use crate::gpu::{BindingSets, Buffer, Commands, Gpu, GpuLbvh, GpuLevels, Kernel, Kernels};
use crate::picture::{swap_red_blue, Picture};
use crate::render::Accel;
use crate::scene::SceneGpu;
use anyhow::{bail, ensure, Context, Result};
use bytemuck::Pod;
use gpu_allocator::MemoryLocation;
use shared::denoise::GUIDE_PLANES;
use shared::envmap::EnvEntry;
use shared::path::{sample_groups, GROUP_ITEMS, MAX_GROUPS};
use shared::types::{
    grid, transform_groups, BuildParams, Camera, Frame, Hit, Object, Ray, RenderPush, Sphere, Triangle, CAST_ANY,
    CAST_OBJECT, CAST_SPAWN, DISPLAY_BGRA, DISPLAY_IN_TRACE, FEATURE_ALPHA, FEATURE_GUIDES, FEATURE_INSTANCES,
    FEATURE_NEE, FLAG_BVH, INVALID, TILE_SIDE, VARIANT_GROUPS, VARIANT_NO_PAIRS, VARIANT_STEPPED, WORKGROUP,
};
use std::sync::Arc;

/// Samples per pixel of a still image from which the real-time denoiser stops and the
/// accumulation is shown: `bench denoise` measured the raw accumulation's error below the
/// denoised image's from 96 (instances), 135 (bunny) and 213 (Cornell box) samples per
/// pixel on (H100, 2026-11-25): the least of them.
pub const DENOISE_UNTIL: u32 = 96;

/// Samples per pixel one path-tracing dispatch adds at most. Lanes run their samples back to
/// back (`path::pixel_samples`), so longer runs leave less idle tail per dispatch: 32
/// instead of 8 took 2-3% off 800x800 x 32 spp frames on the H100.
pub const SAMPLES_PER_DISPATCH: u32 = 32;

/// Device buffers of the scene and the images (descriptor set 1).
struct SceneBuffers {
    /// Host-visible: rewritten when objects move. Twice the objects: the current ones,
    /// then (while denoising) those of the previous frame (`Frame::prev_objects`).
    objects: Buffer,
    model_tris: Buffer,
    model_spheres: Buffer,
    prim_object: Buffer,
    materials: Buffer,
    lights: Buffer,
    /// Host-visible: rewritten when the camera or settings change.
    frame: Buffer,
    accum: Buffer,
    image: Buffer,
    /// The ray casts' rays, and the path tracer's shadow queue ([`GpuRenderer::shadow_queue`]).
    rays: Buffer,
    hits: Buffer,
    attrs: Buffer,
    punctual: Buffer,
    env: Buffer,
    textures: Buffer,
    texels: Buffer,
    /// The denoiser's guides (one guide while not denoising).
    guides: Buffer,
    /// The instances of a scene loaded by [`GpuRenderer::load_levels`] (a placeholder
    /// otherwise; an instanced scene's are its [`GpuLevels`]').
    instances: Buffer,
    /// Set 1 naming the buffers above; made again whenever one of them is replaced.
    set: Option<BindingSets>,
    n_objects: usize,
}

impl SceneBuffers {
    /// Makes set 1; binding 17 names `levels`' instances where there are levels.
    fn bind(&mut self, gpu: &Arc<Gpu>, kernels: &Kernels, levels: Option<&GpuLevels>) -> Result<()> {
        self.set = None;
        let buffers = [
            &self.objects,
            &self.model_tris,
            &self.model_spheres,
            &self.prim_object,
            &self.materials,
            &self.lights,
            &self.frame,
            &self.accum,
            &self.image,
            &self.rays,
            &self.hits,
            &self.attrs,
            &self.punctual,
            &self.env,
            &self.textures,
            &self.texels,
            &self.guides,
            levels.map_or(&self.instances, |l| l.instances()),
        ];
        self.set = Some(BindingSets::new(gpu, kernels, 1, &[&buffers])?);
        Ok(())
    }

    fn set(&self) -> Result<ash::vk::DescriptorSet> {
        Ok(self.set.as_ref().context("scene buffers not bound")?.sets[0])
    }
}

/// Seconds of every stage of the last submission recorded by [`GpuRenderer::record`].
pub fn frame_timings(cmds: &Commands) -> Result<Vec<(&'static str, f64)>> {
    Ok(cmds
        .timings()?
        .into_iter()
        .filter(|(l, _)| *l != "start")
        .map(|(l, ns)| (l, ns * 1e-9))
        .collect())
}

/// Milliseconds of the stage labelled `label` in timings of [`frame_timings`] (summed where
/// it appears more than once, 0 where it does not).
pub fn stage_ms(timings: &[(&'static str, f64)], label: &str) -> f64 {
    timings.iter().filter(|(l, _)| *l == label).map(|(_, s)| s * 1e3).sum()
}

/// Whether and how [`GpuRenderer`] denoises.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub enum Denoise {
    #[default]
    Off,
    /// Every frame from its own samples, with the history of the frames before (real time).
    EveryFrame,
    /// Every frame from all samples since the last change, without history (a still render).
    Accumulated,
}

/// Renders scenes on the GPU.
pub struct GpuRenderer {
    gpu: Arc<Gpu>,
    kernels: Arc<Kernels>,
    lbvh: GpuLbvh,
    /// An instanced scene's two levels (`SceneGpu::instancing`): the tracers walk them, and
    /// a frame builds the top level again instead of transforming and building the world.
    levels: Option<GpuLevels>,
    /// Triangles of the two levels' world-space group (`Instancing::world_tris`): a frame
    /// transforms and builds them with `lbvh`, as a flattened scene, then copies them in.
    world_tris: u32,
    /// How the group's tree in `lbvh` was last built, while the frames after may refit it
    /// (see [`GROUP_REFITS`]), and the refits since.
    group_tree: Option<BuildOptions>,
    group_refits: u32,
    /// Refits of the group between two builds of it (`GROUP_REFITS` unless set).
    group_refits_max: u32,
    /// Refits of the top level between two builds of it (`levels::TOP_REFITS` unless set).
    top_refits_max: u32,
    cmds: Commands,
    bufs: Option<SceneBuffers>,
    frame: Frame,
    /// Samples per pixel accumulated so far.
    samples: u32,
    /// Index of the first sample traced (`render --shard`: a frame's later samples alone).
    first_sample: u32,
    build: BuildOptions,
    /// `DISPLAY_*` flags of the display pass.
    display_flags: u32,
    /// GPU seconds of the last ray cast's dispatch.
    last_cast_s: f64,
    /// The objects as last set.
    objects: Vec<Object>,
    /// The denoiser, while denoising, and how.
    denoiser: Option<GpuDenoiser>,
    denoise: Denoise,
    /// [`Denoise::EveryFrame`] shows the accumulation instead once a still image has this
    /// many samples per pixel.
    denoise_until: u32,
    /// Whether the last frame recorded was denoised.
    denoised_last: bool,
    /// Times the accumulation restarted since the denoiser began (see [`Self::write_motion`]).
    restarts: u32,
    /// The camera and objects of the last frame recorded (the denoiser's motion).
    shown: Option<(Camera, Vec<Object>)>,
    /// The driver tracer, while frames trace through the driver's acceleration structures
    /// (`--accel driver`), and how it builds them.
    driver: Option<DriverTracer>,
    driver_build: DriverBuild,
    /// Whether the path tracer runs persistent (see [`Self::path_kernel`]); `None`: as the
    /// device asks.
    persistent: Option<bool>,
    /// Whether the path tracer may run the stepped loop where the frame allows it (see
    /// [`Self::tracer_constant`]); `None`: off lavapipe.
    stepped: Option<bool>,
    /// Whether shadow rays of scenes in two levels are queued (see [`Self::shadow_queue`]);
    /// `None`: where the scene has them. And the rows of a band of the queue, `None`: as
    /// many as [`QUEUE_BYTES`] holds.
    queue_shadows: Option<bool>,
    queue_rows: Option<u32>,
}

/// Bytes the shadow queue ([`GpuRenderer::shadow_queue`]) takes at most (or the device's largest
/// binding): frames whose band of every row needs more trace bands of fewer rows, one after
/// another. 1080p at depth 4 takes 365 MB in one band, 800x800 at depth 16 481 MB.
const QUEUE_BYTES: u64 = 512 << 20;

/// Frames that refit the world-space group's tree of a scene in two levels (`GpuLbvh::record_refit`:
/// its triangles move, its topology does not) between two builds of it, unless
/// [`GpuRenderer::set_group_refits`] says otherwise; a tree restructured by treelets (frames
/// of 16 samples per pixel and more) too, by the counter refit (`refit_restructured`): at 16
/// samples a frame with `--treelets on` the forest's rebuild 0.71 -> 0.14 ms, its frame
/// 115.2 / 114.4 -> 114.7 / 113.9 ms, the pond's 0.53 -> 0.09, 22.6 / 22.4 -> 22.3 / 22.2, the
/// traces unchanged (session 35). A refit costs a third of a
/// build (the forest's pond of 30,720 triangles: the frame's rebuild 0.205 -> 0.144 ms) but
/// the tree drifts from the one a build would make: the pond's surface-area cost rose by
/// 0.9% on average over 3 refits, 9% over 59, and at 59 the forest's trace lost more than the
/// refits saved. H100, `bench realtime --scenes forest,pond.toml --nee`, two passes, 0 -> 3:
/// forest 7.99 -> 7.96 ms (NEE 10.09-10.15 -> 10.04-10.11), pond 1.71-1.72 -> 1.66-1.67
/// (NEE 2.66 -> 2.62); bench/NOTES.md, session 34.
pub const GROUP_REFITS: u32 = 3;

/// Entries of the accumulation image past a frame's `pixels` sums where persistent dispatches
/// write their sample groups' sums (`shared::path::sample_groups`, `group_slot`): room for
/// [`GROUP_ITEMS`] at most, none where that would take the image past the device's
/// `max_binding` bytes (its frames then trace a pixel's samples as one item).
fn group_room(pixels: u64, max_binding: u64) -> u64 {
    let room = (GROUP_ITEMS as u64).min(MAX_GROUPS as u64 * pixels);
    if (pixels + room) * 16 <= max_binding {
        room
    } else {
        0
    }
}

/// Workgroups of 1,024 invocations the persistent path tracer is dispatched as at most
/// (those the device cannot hold at once start when others end, find no pixels left and
/// end): more than any GPU holds at once today (an H100 holds 132, one an SM).
const PERSISTENT_GROUPS: u32 = 1024;

impl GpuRenderer {
    pub fn new(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>) -> Result<GpuRenderer> {
        Ok(GpuRenderer {
            gpu: gpu.clone(),
            kernels: kernels.clone(),
            lbvh: GpuLbvh::new(gpu, kernels)?,
            levels: None,
            world_tris: 0,
            group_tree: None,
            group_refits: 0,
            group_refits_max: GROUP_REFITS,
            top_refits_max: super::levels::TOP_REFITS,
            cmds: Commands::new(gpu)?,
            bufs: None,
            frame: Frame::default(),
            samples: 0,
            first_sample: 0,
            build: BuildOptions::lbvh(MortonBits::B30),
            display_flags: 0,
            last_cast_s: 0.0,
            objects: Vec::new(),
            denoiser: None,
            denoise: Denoise::Off,
            denoise_until: DENOISE_UNTIL,
            denoised_last: false,
            restarts: 0,
            shown: None,
            driver: None,
            driver_build: DriverBuild::default(),
            persistent: None,
            stepped: None,
            queue_shadows: None,
            queue_rows: None,
        })
    }

    /// Runs the path tracer persistent (`Some(true)`), in tiles (`Some(false)`), or as
    /// [`Self::path_kernel`] decides (`None`): tests compare the two kernels.
    pub fn set_persistent(&mut self, persistent: Option<bool>) {
        self.persistent = persistent;
    }

    /// Lets the path tracer step its walks itself where the frame allows (`Some(true)`: see
    /// `render::tracer_features`), never (`Some(false)`), or off lavapipe (`None`): tests
    /// compare the two loops on lavapipe.
    pub fn set_stepped(&mut self, stepped: Option<bool>) {
        self.stepped = stepped;
    }

    /// Whether the path tracer's frames run the stepped loop (`path::stepped_pixels`).
    pub fn stepped(&self) -> bool {
        self.tracer_constant() & VARIANT_STEPPED != 0
    }

    /// Queues next-event estimation's shadow rays (`Some(true)`), casts them in place
    /// (`Some(false)`), or as [`Self::shadow_queue`] decides (`None`): tests compare the two.
    pub fn set_shadow_queue(&mut self, queue: Option<bool>) {
        self.queue_shadows = queue;
    }

    /// Bands of `rows` rows for the shadow queue (`None`: as many as [`QUEUE_BYTES`] holds):
    /// tests render frames of several bands.
    pub fn set_queue_rows(&mut self, rows: Option<u32>) {
        self.queue_rows = rows;
    }

    /// Whether frames trace the shadow rays of next-event estimation in a pass of their own
    /// (`path_queue` or `path_queue_persistent` traces a sample of every pixel of a band of
    /// rows and queues its light samples, `shadow_resolve` casts them and adds the lit ones;
    /// the same bits as cast in place): for scenes in two levels with next-event estimation,
    /// on the project's walk. Cast in place, the two-level walk of the shadow rays beside the
    /// path's made NEE frames twice those without on the H100 (the herd 13.0 against 6.5 ms);
    /// queued, the real-time NEE frames of the herd, the forest and the sixteen bunnies in two
    /// levels are 23-26% faster (12.9 -> 9.6, 18.5 -> 14.2, 8.4 -> 6.2 ms) and their
    /// 32-sample frames 9-11% (bench/NOTES.md, session 32). Flattened scenes cast in place:
    /// their NEE frames cost about what their shadow rays alone do.
    fn shadow_queue(&self) -> bool {
        let c = self.tracer_constant();
        let two_levels_nee = c & FEATURE_INSTANCES != 0 && c & FEATURE_NEE != 0;
        self.driver.is_none() && self.queue_shadows.unwrap_or(two_levels_nee) && two_levels_nee
    }

    /// Rows of a band of the shadow queue: as many as [`QUEUE_BYTES`] holds, a multiple of 8.
    fn queue_rows(&self) -> u32 {
        let f = &self.frame;
        let row = shared::path::queue_entries(f.width, f.max_depth) * 16;
        let rows = (QUEUE_BYTES.min(self.gpu.max_binding) / row.max(1)) as u32 / 8 * 8;
        self.queue_rows.unwrap_or(rows.max(8)).clamp(1, f.height.max(1))
    }

    /// Makes the shadow queue (the ray casts' rays buffer, binding 9: a set of bindings
    /// more would pass lavapipe's 32 storage buffers a kernel) large enough for a band of the
    /// frame, where frames queue.
    fn reserve_queue(&mut self) -> Result<()> {
        if !self.shadow_queue() {
            return Ok(());
        }
        let bytes = shared::path::queue_entries(self.queue_rows() * self.frame.width, self.frame.max_depth) * 16;
        let b = self.bufs.as_mut().context("no scene loaded")?;
        if b.rays.size < bytes {
            b.set = None;
            b.rays = Buffer::new(&self.gpu, "rays and shadow queue", bytes, MemoryLocation::GpuOnly)?;
            b.bind(&self.gpu, &self.kernels, self.levels.as_ref())?;
        }
        Ok(())
    }

    /// The path tracer's kernel: persistent ([`Kernel::PathTracePersistent`]) off lavapipe,
    /// else 8x8 tiles. Persistent: workgroups of 1,024 invocations, which NVIDIA's compiler
    /// must fit in an SM's 65,536 registers, 64 each (its 8x8 tiles take 96 for the two-level
    /// walk, 128 with next-event estimation), every invocation taking its next pixel from a
    /// counter, so no workgroup holds an SM while a few of its invocations finish. H100
    /// (bench/NOTES.md, session 29): two-level real-time frames 8-12% faster (37-51% with
    /// NEE), their frames of 32 samples 43-54%, flattened frames of one sample 2-8%; flattened
    /// frames of several samples then lost up to 44%, but since the stepped loop they gain too
    /// (H200, session 52: the bunny's diffuse frames 7-13% faster, 4K 11%, primary rays and
    /// next-event estimation 0-3%; one frame lost 2%, the closed box at 800x800 and 32
    /// samples). Not on lavapipe: llvmpipe runs a workgroup's subgroups one after another, so
    /// its first ones take most of the pixels, and its loop limiter (65,535 iterations of a
    /// loop an invocation, counted across the loop's entries) then ends their paths early.
    /// Where frames queue their shadow rays ([`Self::shadow_queue`]), the queue's kernels of
    /// both kinds; where they run the stepped loop ([`Self::stepped`]), its kernels of both
    /// kinds.
    fn path_kernel(&self) -> Kernel {
        let persistent = self.persistent.unwrap_or(!self.gpu.is_lavapipe());
        match (self.shadow_queue(), self.stepped(), persistent) {
            (true, _, true) => Kernel::PathQueuePersistent,
            (true, _, false) => Kernel::PathQueue,
            (false, true, true) => Kernel::PathSteppedPersistent,
            (false, true, false) => Kernel::PathStepped,
            (false, false, true) => Kernel::PathTracePersistent,
            (false, false, false) => Kernel::PathTrace,
        }
    }

    /// What frames trace through from now on: the project's BVH, or the driver's
    /// acceleration structures (an error naming what the device lacks where it has none),
    /// built as `build` says. Accumulation starts again.
    pub fn set_accel(&mut self, accel: Accel, build: DriverBuild) -> Result<()> {
        self.samples = 0;
        self.driver_build = build;
        match accel {
            Accel::Lbvh => self.driver = None,
            Accel::Driver => {
                let mut d = match self.driver.take() {
                    Some(d) => d,
                    None => DriverTracer::new(&self.gpu, &self.kernels)?,
                };
                if self.bufs.is_some() {
                    self.load_driver(&mut d)?;
                }
                self.driver = Some(d);
            }
        }
        Ok(())
    }

    /// Which tracer frames trace through.
    pub fn accel(&self) -> Accel {
        if self.driver.is_some() {
            Accel::Driver
        } else {
            Accel::Lbvh
        }
    }

    /// Makes the driver's structures for the scene loaded: a flattened scene's world, or an
    /// instanced scene's meshes (the world-space group's built every frame) and instances.
    fn load_driver(&self, d: &mut DriverTracer) -> Result<()> {
        let f = &self.frame;
        let alpha = f.features & FEATURE_ALPHA != 0;
        match &self.levels {
            None => {
                let (tris, _, _) = self.lbvh.buffers()?;
                let scene = DriverScene::flattened(tris, f.n_tris, f.n_prims - f.n_tris, alpha);
                d.load(&scene, self.driver_build, self.driver_sets()?)
            }
            Some(l) => {
                let layout = l.layout();
                let mut meshes: Vec<Option<DriverMesh>> = vec![None; layout.mesh_nodes.len()];
                for inst in &layout.instances {
                    let m = Self::mesh_of(layout, inst)?;
                    meshes[m] = Some(DriverMesh {
                        tri0: inst.tri0,
                        n_tris: inst.n_tris,
                        sphere0: inst.sphere0,
                        n_spheres: inst.n_spheres,
                        dynamic: inst.object == INVALID && self.world_tris > 0,
                    });
                }
                let scene = DriverScene {
                    tris: l.triangles(),
                    // A mesh no instance shows has nothing to build.
                    meshes: meshes
                        .into_iter()
                        .map(|m| {
                            m.unwrap_or(DriverMesh {
                                tri0: 0,
                                n_tris: 0,
                                sphere0: 0,
                                n_spheres: 0,
                                dynamic: false,
                            })
                        })
                        .collect(),
                    instances: self.driver_instances()?,
                    n_spheres: layout.n_spheres,
                    alpha,
                };
                d.load(&scene, self.driver_build, self.driver_sets()?)
            }
        }
    }

    /// Sets 0 and 1 of the tracers for the scene loaded.
    fn driver_sets(&self) -> Result<[ash::vk::DescriptorSet; 2]> {
        let b = self.bufs.as_ref().context("no scene loaded")?;
        Ok([self.trace_set()?, b.set()?])
    }

    /// The mesh (its index in the layout) instance `inst` shows.
    fn mesh_of(layout: &crate::bvh::LevelsLayout, inst: &shared::instance::Instance) -> Result<usize> {
        layout
            .mesh_nodes
            .iter()
            .position(|&n| n == inst.nodes)
            .context("an instance of no mesh in the levels' layout")
    }

    /// The driver's top-level instances of the two levels loaded, as the objects are placed
    /// now (the world-space group's by the identity).
    fn driver_instances(&self) -> Result<Vec<DriverInstance>> {
        let Some(l) = &self.levels else {
            return Ok(Vec::new());
        };
        let layout = l.layout();
        layout
            .instances
            .iter()
            .enumerate()
            .map(|(k, inst)| {
                Ok(DriverInstance {
                    mesh: Self::mesh_of(layout, inst)?,
                    rows: if inst.object == INVALID {
                        shared::instance::IDENTITY
                    } else {
                        layout.objects[inst.object as usize].rows
                    },
                    custom: k as u32,
                })
            })
            .collect()
    }

    /// How frames are denoised from now on (`shared::denoise`).
    pub fn set_denoise(&mut self, mode: Denoise) -> Result<()> {
        if mode == self.denoise {
            return Ok(());
        }
        self.denoise = mode;
        if mode == Denoise::Accumulated {
            // Its guides sum every sample since the last change: start afresh.
            self.samples = 0;
        }
        if mode == Denoise::Off || self.bufs.is_none() {
            // (Without a scene yet, `load` makes the denoiser.)
            self.denoiser = None;
            return Ok(());
        }
        self.make_denoiser()
    }

    /// How frames are denoised.
    pub fn denoise(&self) -> Denoise {
        self.denoise
    }

    /// The seed of the random streams the frames trace with now: the frame's, changed at
    /// every restart of the accumulation while denoising every frame (see
    /// [`Self::write_motion`]). The restart count is mixed in (as `bench denoise`'s "seed per
    /// frame"): consecutive seeds would be the streams of neighbouring pixels.
    pub fn traced_seed(&self) -> u32 {
        self.frame.seed ^ 0x5bd1_e995u32.wrapping_mul(self.restarts)
    }

    /// Samples per pixel of a still image from which [`Denoise::EveryFrame`] shows the
    /// accumulation unfiltered (`u32::MAX`: never).
    pub fn set_denoise_until(&mut self, samples: u32) {
        self.denoise_until = samples;
    }

    /// Whether the next frame of `samples` samples will be denoised.
    pub fn denoises_next(&self, samples: u32) -> bool {
        match self.denoise {
            Denoise::Off => false,
            Denoise::Accumulated => true,
            Denoise::EveryFrame => self.samples + samples <= self.denoise_until || self.samples == 0,
        }
    }

    /// A denoiser for the frame's size, and guides for it to read.
    fn make_denoiser(&mut self) -> Result<()> {
        self.denoiser = None;
        self.shown = None;
        self.restarts = 0;
        let b = self.bufs.as_mut().context("no scene loaded")?;
        let (w, h) = (self.frame.width, self.frame.height);
        let bytes = guide_bytes((w * h) as u64);
        if b.guides.size < bytes {
            b.set = None;
            b.guides = Buffer::new(&self.gpu, "denoiser guides", bytes, MemoryLocation::GpuOnly)?;
            b.bind(&self.gpu, &self.kernels, self.levels.as_ref())?;
        }
        self.denoiser = Some(GpuDenoiser::new(&self.gpu, &self.kernels, &b.guides, w, h)?);
        Ok(())
    }

    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    pub fn kernels(&self) -> &Arc<Kernels> {
        &self.kernels
    }

    /// Samples per pixel accumulated since the last change.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Traces samples from index `first` on (each sample's random stream is its index's):
    /// the accumulation then sums samples `first..first + samples()`. For shards of a frame.
    pub fn set_first_sample(&mut self, first: u32) {
        self.first_sample = first;
    }

    /// Packs the display image as B, G, R, A bytes (for BGRA swapchain images).
    pub fn set_bgra(&mut self, bgra: bool) {
        self.display_flags = if bgra { DISPLAY_BGRA } else { 0 };
    }

    /// The frame (camera, size, settings) being rendered.
    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// The display pass's packed 8-bit image (`frame().width * frame().height` pixels).
    pub fn display_buffer(&self) -> Result<&Buffer> {
        Ok(&self.bufs.as_ref().context("no scene loaded")?.image)
    }

    /// How the BVH is built every frame.
    pub fn set_build(&mut self, build: BuildOptions) {
        self.build = build;
        self.group_tree = None;
    }

    /// Frames that refit a scene's world-space group between two builds of it (0: built
    /// every frame).
    pub fn set_group_refits(&mut self, refits: u32) {
        self.group_refits_max = refits;
    }

    /// Frames that refit a scene's top level between two builds of it (0: built every
    /// frame; see `gpu::levels::TOP_REFITS`).
    pub fn set_top_refits(&mut self, refits: u32) {
        self.top_refits_max = refits;
        if let Some(l) = self.levels.as_mut() {
            l.set_top_refits(refits);
        }
    }

    /// How the BVH is built every frame.
    pub fn build_options(&self) -> BuildOptions {
        self.build
    }

    /// Specialisation constant 0 of the tracing kernels: the frame's `FEATURE_*` and
    /// `VARIANT_*` bits, the wide traversal where the build collapses the tree, and a
    /// flattened scene's binary walk without pairs where the device could not hold them
    /// (`GpuLbvh::has_pairs`).
    fn tracer_constant(&self) -> u32 {
        let features = crate::render::tracer_features(&self.frame, self.build) & !FEATURE_GUIDES;
        let tree_only = self.levels.is_none() && !self.build.wide && !self.lbvh.has_pairs();
        // Not on lavapipe unless asked: it runs a subgroup as one thread's SIMD vector, and
        // the test suite there took up to twice as long through the stepped loop (the accuracy
        // test 213 -> 493 s: bench/NOTES.md, session 51).
        let stepped = self.stepped.unwrap_or(!self.gpu.is_lavapipe());
        let features = if stepped { features } else { features & !VARIANT_STEPPED };
        features | if tree_only { VARIANT_NO_PAIRS } else { 0 }
    }

    /// [`Self::tracer_constant`] of the path tracer: with the guides while denoising (and
    /// only then: they are written where the denoiser has made room for them).
    fn path_trace_constant(&self) -> u32 {
        self.tracer_constant() | if self.denoiser.is_some() { FEATURE_GUIDES } else { 0 }
    }

    /// Uploads a scene and its frame; accumulation starts again.
    pub fn load(&mut self, scene: &SceneGpu, frame: &Frame) -> Result<()> {
        self.bufs = None;
        // The levels before, whose meshes' BVHs the new ones keep where the meshes are the
        // same (an edit adds, removes or moves objects: only the top level is built again).
        let previous = self.levels.take();
        self.world_tris = 0;
        self.group_tree = None;
        let gpu = &self.gpu.clone();
        let dev = |name: &str, bytes: usize| Buffer::new(gpu, name, bytes as u64, MemoryLocation::GpuOnly);
        let host = |name: &str, bytes: usize| Buffer::new(gpu, name, bytes as u64, MemoryLocation::CpuToGpu);
        let pixels = (frame.width * frame.height) as usize;
        let mut objects = host("objects", 2 * size_of_val(scene.objects.as_slice()))?;
        objects.write(&[scene.objects.as_slice(), scene.objects.as_slice()].concat())?;
        let model_tris = dev("model triangles", size_of_val(scene.model_tris.as_slice()))?;
        let model_spheres = dev("model spheres", size_of_val(scene.model_spheres.as_slice()))?;
        let prim_object = dev("object of each primitive", size_of_val(scene.prim_object.as_slice()))?;
        let materials = dev("materials", size_of_val(scene.materials.as_slice()))?;
        let light_words = scene.light_words();
        let lights = dev("lights", size_of_val(light_words.as_slice()))?;
        let frame_buf = host("frame", size_of::<Frame>())?;
        let room = group_room(pixels as u64, gpu.max_binding) as usize;
        let accum = dev("accumulation image", (pixels + room) * 16)?;
        let image = dev("display image", pixels * 4)?;
        let rays = dev("rays", size_of::<Ray>())?;
        let hits = dev("hits", size_of::<Hit>())?;
        let attrs = dev("vertex attributes", size_of_val(scene.attrs.as_slice()))?;
        let punctual = dev("punctual lights", size_of_val(scene.punctual.as_slice()))?;
        let env_entries: &[EnvEntry] = scene.env.as_ref().map_or(&[], |e| e.entries.as_slice());
        let env = dev("environment map", size_of_val(env_entries))?;
        let textures = dev("textures", size_of_val(scene.textures.infos.as_slice()))?;
        let texels = dev("texels", size_of_val(scene.textures.texels.as_slice()))?;
        let guides = dev("denoiser guides", guide_bytes(0) as usize)?;
        let instances = dev("instances", size_of::<shared::instance::Instance>())?;
        self.upload(&model_tris, &scene.model_tris)?;
        self.upload(&model_spheres, &scene.model_spheres)?;
        self.upload(&prim_object, &scene.prim_object)?;
        self.upload(&materials, &scene.materials)?;
        self.upload(&lights, &light_words)?;
        self.upload(&attrs, &scene.attrs)?;
        self.upload(&punctual, &scene.punctual)?;
        self.upload(&env, env_entries)?;
        self.upload(&textures, &scene.textures.infos)?;
        self.upload(&texels, &scene.textures.texels)?;
        self.bufs = Some(SceneBuffers {
            objects,
            model_tris,
            model_spheres,
            prim_object,
            materials,
            lights,
            frame: frame_buf,
            accum,
            image,
            rays,
            hits,
            attrs,
            punctual,
            env,
            textures,
            texels,
            guides,
            instances,
            set: None,
            n_objects: scene.objects.len(),
        });
        self.objects = scene.objects.clone();
        if let Some(i) = &scene.instancing {
            let placements = i.placements_at(&scene.objects);
            let opts = BuildOptions {
                wide: false,
                pairs: false,
                ..self.build
            };
            let mut levels = GpuLevels::keeping(previous.as_ref(), gpu, &self.kernels, &i.meshes, &placements, opts)?;
            levels.set_top_refits(self.top_refits_max);
            self.levels = Some(levels);
            self.world_tris = i.world_tris;
            if i.world_tris > 0 {
                self.lbvh.reserve(i.world_tris as usize, 0)?;
            }
        } else {
            // Buffers made here have the room the builds ask for (no second allocation at
            // the first frame).
            self.lbvh.reserve_room(self.build)?;
            self.lbvh.reserve(scene.model_tris.len(), scene.model_spheres.len())?;
        }
        if let Some(b) = self.bufs.as_mut() {
            b.bind(gpu, &self.kernels, self.levels.as_ref())?;
        }
        self.set_frame(frame)?;
        if self.denoise != Denoise::Off {
            self.make_denoiser()?;
        }
        if let Some(mut d) = self.driver.take() {
            let loaded = self.load_driver(&mut d);
            self.driver = Some(d);
            loaded?;
        }
        Ok(())
    }

    /// Device bytes of the BVH and the primitives it holds: both levels (meshes' primitives
    /// and nodes, instances, the top level's builder, and the builder of a world-space
    /// group) where instanced, else the builder's.
    pub fn bvh_memory(&self) -> u64 {
        match &self.levels {
            Some(l) if self.world_tris == 0 => l.memory(),
            Some(l) => {
                let (nodes, rest) = self.lbvh.memory();
                l.memory() + nodes + rest
            }
            None => {
                let (nodes, rest) = self.lbvh.memory();
                nodes + rest
            }
        }
    }

    /// Device bytes of what the tracer walks: the BVH's nodes (both levels where instanced),
    /// or the driver's bottom and top levels (`--accel driver`).
    pub fn structure_bytes(&self) -> u64 {
        match (&self.driver, &self.levels) {
            (Some(d), _) => d.structure_bytes(),
            (None, Some(l)) => l.memory(),
            (None, None) => self.lbvh.memory().0,
        }
    }

    /// With two levels: how many meshes' BVHs the last [`Self::load`] built, and how many it
    /// kept from the scene loaded before.
    pub fn meshes_built(&self) -> Option<(usize, usize)> {
        self.levels.as_ref().map(|l| (l.built, l.kept))
    }

    /// Set 0 of the tracers: the two levels' buffers, or the builder's.
    fn trace_set(&self) -> Result<ash::vk::DescriptorSet> {
        match &self.levels {
            Some(l) => Ok(l.trace_set()),
            None => self.lbvh.set(),
        }
    }

    /// Copies `data` into the device-local `dst` through a staging buffer.
    fn upload<T: Pod>(&mut self, dst: &Buffer, data: &[T]) -> Result<()> {
        if data.is_empty() {
            return Ok(());
        }
        let bytes = size_of_val(data) as u64;
        let mut staging = Buffer::new(&self.gpu, "staging", bytes, MemoryLocation::CpuToGpu)?;
        staging.write(data)?;
        self.cmds.begin()?;
        self.cmds.copy_range(&staging, 0, dst, 0, bytes);
        self.cmds.submit_wait().context("uploading scene data")
    }

    /// Takes the two levels `l` (`bvh::build_levels`) as what ray casts walk: the meshes'
    /// primitives and both levels' nodes in the builder's buffers, the instances in render
    /// binding 17, the frame's counts, [`FLAG_BVH`] and [`FEATURE_INSTANCES`]. The loaded
    /// scene's objects stay (the renderer's frames do not instance yet: a render transforms
    /// and builds the loaded scene again).
    pub fn load_levels(&mut self, l: &Levels) -> Result<()> {
        ensure!(!l.instances.is_empty(), "a scene of no instances");
        self.lbvh.upload(&l.tris, &l.spheres)?;
        self.lbvh.upload_nodes(&l.nodes)?;
        let gpu = self.gpu.clone();
        let instances = Buffer::new(
            &gpu,
            "instances",
            size_of_val(l.instances.as_slice()) as u64,
            MemoryLocation::GpuOnly,
        )?;
        self.upload(&instances, &l.instances)?;
        let b = self.bufs.as_mut().context("no scene loaded")?;
        b.instances = instances;
        self.levels = None;
        b.bind(&gpu, &self.kernels, None)?;
        let mut f = self.frame;
        f.n_tris = l.tris.len() as u32;
        f.n_prims = (l.tris.len() + l.spheres.len()) as u32;
        f.n_instances = l.instances.len() as u32;
        f.top_nodes = l.top;
        f.features |= FEATURE_INSTANCES;
        f.flags |= FLAG_BVH;
        self.set_frame(&f)
    }

    /// New camera, settings or image size (same scene); accumulation starts again.
    pub fn set_frame(&mut self, frame: &Frame) -> Result<()> {
        let b = self.bufs.as_mut().context("no scene loaded")?;
        let prims = match &self.levels {
            Some(l) => l.layout().n_tris + l.layout().n_spheres,
            None => self.lbvh.len(),
        };
        if frame.n_prims != prims {
            bail!("the frame does not fit the loaded scene (primitive count changed): load it again");
        }
        let pixels = (frame.width * frame.height) as u64;
        let room = group_room(pixels, self.gpu.max_binding);
        if b.accum.size < (pixels + room) * 16 || b.image.size < pixels * 4 {
            b.set = None;
            b.accum = Buffer::new(
                &self.gpu,
                "accumulation image",
                (pixels + room) * 16,
                MemoryLocation::GpuOnly,
            )?;
            b.image = Buffer::new(&self.gpu, "display image", pixels * 4, MemoryLocation::GpuOnly)?;
            b.bind(&self.gpu, &self.kernels, self.levels.as_ref())?;
        }
        b.frame.write(std::slice::from_ref(frame))?;
        self.frame = *frame;
        self.samples = 0;
        self.reserve_queue()?;
        if self
            .denoiser
            .as_ref()
            .is_some_and(|d| !d.fits(frame.width, frame.height))
        {
            self.make_denoiser()?;
        }
        Ok(())
    }

    /// New object transforms (same objects); accumulation starts again. With two levels a
    /// transform that cannot be inverted is refused by the object's number, and nothing
    /// changes.
    pub fn set_objects(&mut self, objects: &[Object]) -> Result<()> {
        let b = self.bufs.as_mut().context("no scene loaded")?;
        if objects.len() != b.n_objects {
            bail!("{} objects given, {} loaded", objects.len(), b.n_objects);
        }
        if let Some(l) = self.levels.as_mut() {
            let rows: Vec<_> = objects.iter().map(|o| o.rows).collect();
            l.set_transforms(&rows)?;
        }
        b.objects.write(objects)?;
        if self.levels.is_some() && self.driver.is_some() {
            let instances = self.driver_instances()?;
            if let Some(d) = self.driver.as_mut() {
                d.set_instances(&instances)?;
            }
        }
        self.objects = objects.to_vec();
        self.samples = 0;
        Ok(())
    }

    /// Records transform and BVH build (when `rebuild`), `samples` more samples per pixel,
    /// and the display pass into one command buffer, runs it, and returns each stage's GPU
    /// seconds (build stages as labelled by the LBVH, then `trace` and `display`).
    pub fn render(&mut self, samples: u32, rebuild: bool) -> Result<Vec<(&'static str, f64)>> {
        let mut cmds = std::mem::replace(&mut self.cmds, Commands::none(&self.gpu));
        let r = cmds
            .begin()
            .and_then(|()| self.record(&mut cmds, samples, rebuild))
            .and_then(|()| cmds.submit_wait().context("rendering"))
            .and_then(|()| frame_timings(&cmds));
        self.cmds = cmds;
        r
    }

    /// Records (into `cmds`, which is recording) what [`GpuRenderer::render`] runs: a
    /// timestamp `begin`, then transform and build, `trace`, `display` (none where the trace
    /// displays the frame: `DISPLAY_IN_TRACE`). The samples count as accumulated from here on.
    pub fn record(&mut self, cmds: &mut Commands, samples: u32, rebuild: bool) -> Result<()> {
        // The first wide build, or the first with pairs, makes the builder's buffers again
        // with room for it (other builds leave it out): the frame transforms and builds anew.
        if self.levels.is_none() && self.lbvh.reserve_room(self.build)? {
            self.samples = 0;
        }
        let still = self.samples > 0;
        // A frame without samples has nothing new to filter (its guides are an earlier
        // frame's): it shows the accumulation.
        let denoise = samples > 0 && self.denoises_next(samples);
        self.denoised_last = denoise;
        if self.denoise == Denoise::EveryFrame && denoise {
            self.write_motion(still)?;
        }
        // Guides sum this frame's samples, or every sample since the last change.
        let guides_from = match self.denoise {
            Denoise::Accumulated => self.samples,
            _ => 0,
        };
        // The path tracer's pipeline (the driver's tens of milliseconds the first time) is
        // made while the build is recorded.
        let path_kernel = self.path_kernel();
        self.reserve_queue()?;
        if self.driver.is_none() {
            self.kernels.make_soon(path_kernel, self.path_trace_constant());
        }
        let b = self.bufs.as_ref().context("no scene loaded")?;
        let k = &self.kernels;
        let f = self.frame;
        let sets = [self.trace_set()?, b.set()?];
        // The persistent stepped loop splits each pixel's samples into groups where the image
        // has room for their sums (not with the denoiser's guides, which the first sample
        // makes), in a kernel specialised for it (`VARIANT_GROUPS`).
        let pixels = f.width * f.height;
        let room = b.accum.size / 16 - pixels as u64;
        let grouped = path_kernel == Kernel::PathSteppedPersistent
            && self.driver.is_none()
            && self.path_trace_constant() & FEATURE_GUIDES == 0;
        let groups_of = |n: u32| match sample_groups(pixels, n) {
            g if grouped && g as u64 * pixels as u64 <= room => g,
            _ => 1,
        };
        // A frame from no samples whose samples one path tracer dispatch traces (not in
        // groups, nor through the shadow queue) and that the denoiser does not show writes its
        // accumulation and display image in that dispatch (`DISPLAY_IN_TRACE`): no clearing
        // before it, no display pass after.
        let denoised = denoise && self.denoiser.is_some();
        let in_trace = self.samples == 0
            && (1..=SAMPLES_PER_DISPATCH).contains(&samples)
            && groups_of(samples) == 1
            && !self.shadow_queue()
            && !denoised;
        cmds.timestamp("begin");
        if self.samples == 0 && !in_trace {
            cmds.fill_range(&b.accum, 0, pixels as u64 * 16, 0);
            cmds.barrier();
        }
        // The transform stage; before a build of the project's BVH it reduces the build's
        // bounds too (`transform_bounds`), and the build starts from the Morton codes.
        let transform = |cmds: &mut Commands, n_tris: u32, n: u32, builds: bool| -> Result<()> {
            let p = BuildParams {
                n_tris,
                n,
                shift: 0,
                passes: 0,
            };
            let (kernel, groups) = if builds {
                (Kernel::TransformBounds, transform_groups(n))
            } else {
                (Kernel::Transform, n.div_ceil(WORKGROUP))
            };
            let (x, y) = grid(groups);
            let sets = [self.lbvh.set()?, sets[1]];
            cmds.dispatch_sets(k, &sets, kernel, bytemuck::bytes_of(&p), x, y)?;
            cmds.barrier();
            cmds.timestamp("transform");
            Ok(())
        };
        if let Some(l) = self.levels.as_mut().filter(|_| rebuild || self.samples == 0) {
            // The world-space group, as a flattened scene's world, then the top level.
            if self.world_tris > 0 {
                if self.driver.is_some() {
                    transform(cmds, self.world_tris, self.world_tris, false)?;
                    l.record_world_tris(cmds, &self.lbvh, self.world_tris)?;
                    self.group_tree = None;
                } else {
                    let build = BuildOptions {
                        wide: false,
                        ..self.build
                    };
                    // Its triangles move, its topology stays: the tree built last is refit,
                    // and built again every `group_refits_max + 1` frames.
                    let refit = self.group_tree == Some(build);
                    if refit && self.group_refits < self.group_refits_max {
                        transform(cmds, self.world_tris, self.world_tris, false)?;
                        self.lbvh.record_refit(cmds, build, false)?;
                        self.group_refits += 1;
                    } else {
                        transform(cmds, self.world_tris, self.world_tris, true)?;
                        self.lbvh.record_bounded(cmds, build, false)?;
                        (self.group_tree, self.group_refits) = (Some(build), 0);
                    }
                    l.record_world(cmds, &self.lbvh, self.world_tris)?;
                }
            }
            match self.driver.as_mut() {
                Some(d) => d.record_build(cmds, sets)?,
                None => l.record_top(cmds)?,
            }
        } else if rebuild || self.samples == 0 {
            transform(cmds, f.n_tris, f.n_prims, self.driver.is_none())?;
            match self.driver.as_mut() {
                Some(d) => d.record_build(cmds, sets)?,
                None => self.lbvh.record_bounded(cmds, self.build, false)?,
            }
        }
        let driver_features = self.kernels.tracer_constant(self.path_trace_constant());
        let trace = match self.driver {
            Some(_) => ash::vk::Pipeline::null(),
            None => self.kernels.specialised(path_kernel, self.path_trace_constant())?,
        };
        let persistent = matches!(
            path_kernel,
            Kernel::PathTracePersistent | Kernel::PathSteppedPersistent | Kernel::PathQueuePersistent
        );
        // A persistent kernel's workgroups for `pixels`, its pixel counter (the guides' last
        // entry, `path::render_tiles`) zeroed first.
        let guides = &self.bufs.as_ref().context("no scene loaded")?.guides;
        let persistent_grid = |cmds: &mut Commands, pixels: u32| {
            cmds.fill_range(guides, guides.size - 16, 16, 0);
            cmds.barrier();
            (pixels.div_ceil(1024).min(PERSISTENT_GROUPS), 1)
        };
        // The path tracer over the push's rows.
        let trace_rows = |cmds: &mut Commands, push: &RenderPush| {
            let (gx, gy) = if persistent {
                persistent_grid(cmds, push.rows * f.width)
            } else {
                (f.width.div_ceil(TILE_SIDE), push.rows.div_ceil(TILE_SIDE))
            };
            cmds.dispatch_pipeline(k, trace, &sets, bytemuck::bytes_of(push), gx, gy);
            cmds.barrier();
        };
        let mut done = 0;
        if self.shadow_queue() {
            // One sample a dispatch, band after band: the path tracer queues, `shadow_resolve`
            // casts and adds; persistent where the path tracer is (not on lavapipe: see
            // `path_kernel`).
            let resolve_kernel = if persistent {
                Kernel::ShadowResolvePersistent
            } else {
                Kernel::ShadowResolve
            };
            let resolve = self.kernels.specialised(resolve_kernel, self.path_trace_constant())?;
            let rows = self.queue_rows();
            for s in 0..samples {
                for row_base in (0..f.height).step_by(rows as usize) {
                    let push = RenderPush {
                        sample_base: self.first_sample + self.samples + s,
                        samples: 1,
                        count: guides_from + s,
                        row_base,
                        rows: rows.min(f.height - row_base),
                        ..Default::default()
                    };
                    trace_rows(cmds, &push);
                    let (x, y) = if persistent {
                        persistent_grid(cmds, push.rows * f.width)
                    } else {
                        grid((push.rows * f.width).div_ceil(WORKGROUP))
                    };
                    cmds.dispatch_pipeline(k, resolve, &sets, bytemuck::bytes_of(&push), x, y);
                    cmds.barrier();
                }
            }
            done = samples;
        }
        while done < samples {
            let n = (samples - done).min(SAMPLES_PER_DISPATCH);
            let groups = groups_of(n);
            let push = RenderPush {
                sample_base: self.first_sample + self.samples + done,
                samples: n,
                count: guides_from + done,
                rows: f.height,
                flags: match groups {
                    1 if in_trace => DISPLAY_IN_TRACE | self.display_flags,
                    1 => 0,
                    g => g,
                },
                ..Default::default()
            };
            match self.driver.as_mut() {
                Some(d) => d.record_launch(cmds, PATH_TRACE, driver_features, sets, &push, f.width, f.height)?,
                None if groups > 1 => {
                    let constant = self.path_trace_constant() | VARIANT_GROUPS;
                    let grouped_trace = self.kernels.specialised(path_kernel, constant)?;
                    let (gx, gy) = persistent_grid(cmds, pixels * groups);
                    cmds.dispatch_pipeline(k, grouped_trace, &sets, bytemuck::bytes_of(&push), gx, gy);
                    cmds.barrier();
                    let add = RenderPush {
                        count: pixels,
                        flags: groups,
                        ..Default::default()
                    };
                    let (x, y) = grid(pixels.div_ceil(WORKGROUP));
                    cmds.dispatch_sets(k, &sets, Kernel::AccumGroups, bytemuck::bytes_of(&add), x, y)?;
                    cmds.barrier();
                }
                None => trace_rows(cmds, &push),
            }
            done += n;
        }
        cmds.timestamp("trace");
        if let Some(d) = self.denoiser.as_mut().filter(|_| denoise) {
            let bgra = self.display_flags & DISPLAY_BGRA != 0;
            if self.denoise == Denoise::Accumulated {
                d.record(cmds, k, sets[1], self.samples + samples, false, false, bgra)?;
            } else {
                d.record(cmds, k, sets[1], samples, true, still, bgra)?;
            }
        } else if !in_trace {
            let push = RenderPush {
                samples: self.samples + samples,
                flags: self.display_flags,
                ..Default::default()
            };
            let (x, y) = grid((f.width * f.height).div_ceil(WORKGROUP));
            cmds.dispatch_sets(k, &sets, Kernel::DisplayImage, bytemuck::bytes_of(&push), x, y)?;
            cmds.barrier();
            cmds.timestamp("display");
        }
        self.samples += samples;
        Ok(())
    }

    /// Writes the previous frame's camera and object transforms where the path tracer's
    /// motion vectors read them (`Frame::prev_camera`, the second half of the objects), and
    /// remembers this frame's for the next. Every restart of the accumulation (a frame that
    /// is not `still`) after the first changes the seed: otherwise each moving frame
    /// would trace its pixels with the same random numbers (sample 0 of the same seed), and
    /// the denoiser's temporal history would average the same noise. A still image that was
    /// never moved keeps the scene's seed, so it accumulates what `render` does.
    fn write_motion(&mut self, still: bool) -> Result<()> {
        if !still && self.shown.is_some() {
            self.restarts = self.restarts.wrapping_add(1);
        }
        let seed = self.traced_seed();
        let b = self.bufs.as_mut().context("no scene loaded")?;
        let (camera, objects) = self
            .shown
            .take()
            .unwrap_or_else(|| (self.frame.camera, self.objects.clone()));
        let mut f = self.frame;
        f.prev_camera = camera;
        f.prev_objects = self.objects.len() as u32;
        f.seed = seed;
        b.frame.write(std::slice::from_ref(&f))?;
        b.objects
            .write(&[self.objects.as_slice(), objects.as_slice()].concat())?;
        self.shown = Some((self.frame.camera, self.objects.clone()));
        Ok(())
    }

    /// Rays traced per sample over the whole image, from the accumulation image's ray counts
    /// (0 before any sample).
    pub fn rays_per_sample(&mut self) -> Result<f64> {
        let pixels = (self.frame.width * self.frame.height) as usize;
        let b = self.bufs.as_ref().context("no scene loaded")?;
        let accum: Vec<[f32; 4]> = self.cmds.read_back(&b.accum, pixels)?;
        let rays: f64 = accum.iter().map(|a| a[3] as f64).sum();
        Ok(if self.samples == 0 {
            0.0
        } else {
            rays / self.samples as f64
        })
    }

    /// The accumulated and displayed images.
    pub fn picture(&mut self) -> Result<Picture> {
        let pixels = (self.frame.width * self.frame.height) as usize;
        let b = self.bufs.as_ref().context("no scene loaded")?;
        let mut display: Vec<u32> = self.cmds.read_back(&b.image, pixels)?;
        if self.display_flags & DISPLAY_BGRA != 0 {
            // Back to RGBA: a picture is the same whatever window it was shown in.
            display.iter_mut().for_each(|p| *p = swap_red_blue(*p));
        }
        let mut accum = self.sums()?;
        if let Some(d) = self.denoiser.as_ref().filter(|_| self.denoised_last) {
            // The denoised frame, as the sums of `samples` samples (ray counts kept).
            let out: Vec<[f32; 4]> = self.cmds.read_back(&d.output, pixels)?;
            let n = self.samples as f32;
            for (a, o) in accum.iter_mut().zip(out) {
                *a = [o[0] * n, o[1] * n, o[2] * n, a[3]];
            }
        }
        Ok(Picture {
            width: self.frame.width,
            height: self.frame.height,
            accum,
            samples: self.samples,
            display,
        })
    }

    /// The accumulation image alone: every pixel's radiance sums and ray count.
    pub fn sums(&mut self) -> Result<Vec<[f32; 4]>> {
        let mut out = vec![[0.0; 4]; self.pixels()];
        self.sums_into(&mut out)?;
        Ok(out)
    }

    /// [`GpuRenderer::sums`] into `out`, which holds [`GpuRenderer::pixels`] values.
    pub fn sums_into(&mut self, out: &mut [[f32; 4]]) -> Result<()> {
        ensure!(
            out.len() == self.pixels(),
            "{} values for the sums of {} pixels",
            out.len(),
            self.pixels()
        );
        let b = self.bufs.as_ref().context("no scene loaded")?;
        self.cmds.read_back_into(&b.accum, out)
    }

    /// Pixels of the frame.
    pub fn pixels(&self) -> usize {
        (self.frame.width * self.frame.height) as usize
    }

    /// The path tracer's guides of the last frame (while denoising).
    pub fn guides(&mut self) -> Result<Vec<shared::denoise::Guide>> {
        if self.denoiser.is_none() {
            bail!("guides are written only while denoising");
        }
        let pixels = (self.frame.width * self.frame.height) as usize;
        let b = self.bufs.as_ref().context("no scene loaded")?;
        let planes: Vec<[u32; 4]> = self.cmds.read_back(&b.guides, pixels * GUIDE_PLANES as usize)?;
        Ok(crate::cpu::guides_from_planes(&planes))
    }

    /// The BVH of the last build, every stage's output.
    pub fn bvh(&mut self) -> Result<BuildResult> {
        match self.levels.as_mut() {
            // Two levels: both levels' nodes (every mesh's, then the top level's).
            Some(l) => Ok(BuildResult {
                nodes: l.nodes()?,
                ..Default::default()
            }),
            None => self.lbvh.result(self.build),
        }
    }

    /// Builds the BVH afresh now, as a frame that builds does (in two levels the group and
    /// the top level, which the frames between builds refit: `GROUP_REFITS`,
    /// `levels::TOP_REFITS`), tracing no sample: what the CPU executor's build of the scene
    /// as it is now equals, bit for bit.
    pub fn rebuild_now(&mut self) -> Result<()> {
        self.build_next();
        self.render(0, true).map(|_| ())
    }

    /// The next frame that rebuilds builds the BVH afresh (in two levels the group and the top
    /// level too, which it would refit), as the CPU executor's render of the scene does.
    pub fn build_next(&mut self) {
        self.group_tree = None;
        if let Some(l) = self.levels.as_mut() {
            l.build_top_next();
        }
    }

    /// World-space primitives of the last transform stage (with two levels: the meshes'
    /// model-space primitives).
    pub fn world(&mut self) -> Result<(Vec<Triangle>, Vec<Sphere>)> {
        match self.levels.as_mut() {
            Some(l) => l.primitives(),
            None => self.lbvh.primitives(),
        }
    }

    /// GPU seconds of the last cast's dispatch ([`Self::cast`], [`Self::cast_any`], ...).
    pub fn last_cast_seconds(&self) -> f64 {
        self.last_cast_s
    }

    /// Closest hits of `rays` through the current BVH (or brute force, by the frame's flag),
    /// with the frame's `FEATURE_*` and `VARIANT_*` bits.
    pub fn cast(&mut self, rays: &[Ray]) -> Result<Vec<Hit>> {
        self.cast_flags(rays, rays.len(), 0)
    }

    /// Closest hits of `rays` whose `prim` names the object hit (through an instance, its
    /// object; [`CAST_OBJECT`]): picking.
    pub fn cast_objects(&mut self, rays: &[Ray]) -> Result<Vec<Hit>> {
        self.cast_flags(rays, rays.len(), CAST_OBJECT)
    }

    /// Whether anything lies along each of `rays` (the shadow-ray query), as hits with `t = 0`
    /// or misses.
    pub fn cast_any(&mut self, rays: &[Ray]) -> Result<Vec<Hit>> {
        self.cast_flags(rays, rays.len(), CAST_ANY)
    }

    /// Rays leaving hits, as paths do ([`CAST_SPAWN`]): `pairs[2 i]` is cast, and from its
    /// hit point a ray along `pairs[2 i + 1]`'s direction, origin offset on the GPU. Returns
    /// both hits of every pair.
    pub fn cast_spawn(&mut self, pairs: &[Ray]) -> Result<Vec<Hit>> {
        if !pairs.len().is_multiple_of(2) {
            bail!("spawning casts take pairs of rays, {} given", pairs.len());
        }
        self.cast_flags(pairs, pairs.len() / 2, CAST_SPAWN)
    }

    /// GPU seconds of one closest-hit (or, with `any`, any-hit) query of every ray of `rays`:
    /// the rays uploaded once, then `repeats` dispatches back to back in one submission
    /// (benchmarks: between single casts the GPU idles for the transfers and lowers its
    /// clocks).
    pub fn time_casts(&mut self, rays: &[Ray], any: bool, repeats: u32) -> Result<f64> {
        let flags = if any { CAST_ANY } else { 0 };
        let mut b = self.bufs.take().context("no scene loaded")?;
        let r = self.cast_with(&mut b, rays, rays.len(), flags, repeats.max(1));
        self.bufs = Some(b);
        r?;
        Ok(self.last_cast_s / repeats.max(1) as f64)
    }

    fn cast_flags(&mut self, rays: &[Ray], count: usize, flags: u32) -> Result<Vec<Hit>> {
        let mut b = self.bufs.take().context("no scene loaded")?;
        let r = self.cast_with(&mut b, rays, count, flags, 1);
        self.bufs = Some(b);
        r
    }

    fn cast_with(
        &mut self,
        b: &mut SceneBuffers,
        rays: &[Ray],
        count: usize,
        flags: u32,
        repeats: u32,
    ) -> Result<Vec<Hit>> {
        let hits_bytes = (rays.len() * size_of::<Hit>()) as u64;
        if b.rays.size < size_of_val(rays) as u64 || b.hits.size < hits_bytes {
            if b.rays.size < size_of_val(rays) as u64 {
                b.rays = Buffer::new(&self.gpu, "rays", size_of_val(rays) as u64, MemoryLocation::GpuOnly)?;
            }
            if b.hits.size < hits_bytes {
                b.hits = Buffer::new(&self.gpu, "hits", hits_bytes, MemoryLocation::GpuOnly)?;
            }
            b.bind(&self.gpu, &self.kernels, self.levels.as_ref())?;
        }
        self.upload(&b.rays, rays)?;
        let push = RenderPush {
            count: count as u32,
            flags,
            ..Default::default()
        };
        let sets = [self.trace_set()?, b.set()?];
        let (x, y) = grid((count as u32).div_ceil(WORKGROUP));
        let cast = match self.driver {
            Some(_) => ash::vk::Pipeline::null(),
            None => self.kernels.specialised(Kernel::CastRays, self.tracer_constant())?,
        };
        let driver_features = self.kernels.tracer_constant(self.tracer_constant());
        if let Some(d) = &self.driver {
            // Through the structures the last frame built.
            ensure!(
                d.built(),
                "ray casts through the driver's structures need a frame rendered first"
            );
        }
        self.cmds.begin()?;
        self.cmds.timestamp("start");
        for _ in 0..repeats {
            match self.driver.as_mut() {
                Some(d) => d.record_launch(&mut self.cmds, CAST_RAYS, driver_features, sets, &push, count as u32, 1)?,
                None => {
                    self.cmds
                        .dispatch_pipeline(&self.kernels, cast, &sets, bytemuck::bytes_of(&push), x, y);
                    self.cmds.barrier();
                }
            }
        }
        self.cmds.timestamp("cast");
        self.cmds.submit_wait().context("casting rays")?;
        self.last_cast_s = stage_ms(&frame_timings(&self.cmds)?, "cast") * 1e-3;
        self.cmds.read_back(&b.hits, rays.len())
    }
}
