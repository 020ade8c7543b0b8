//! The scene options every command that opens a scene takes (`render`, `compare`, `view`
//! and the benchmarks), and the scene prepared from them: opened, overridden, its kernel
//! features derived.
use crate::bvh::{BuildOptions, Layout, MortonBits};
use crate::features::{self, Features, Forced};
use crate::gpu::driver::DriverBuild;
use crate::render::{self, Accel, AccelChoice};
use crate::scene::{Environment, InstancingMode, Scene, SceneGpu};
use anyhow::{bail, Result};
use glam::Vec3;
use shared::types::{Frame, FLAG_DENOISE, FLAG_NEE};
use std::path::PathBuf;

/// Scene and settings of a render; unset options keep the scene's own settings.
#[derive(clap::Parser, Clone, Debug)]
pub struct SceneArgs {
    /// Built-in scene (cornell, suzanne, bunny, spheres, instances, herd, forest), a TOML scene
    /// file, or a model file (glTF, GLB, OBJ, PLY) opened as a scene.
    #[arg(default_value = "cornell")]
    pub scene: String,
    /// Samples per pixel.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Maximum number of bounces per path.
    #[arg(long)]
    pub depth: Option<u32>,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Trace by testing every primitive (the thesis's brute force) instead of the BVH.
    #[arg(long)]
    pub no_bvh: bool,
    /// Switch next-event estimation off.
    #[arg(long)]
    pub no_nee: bool,
    /// Next-event estimation without multiple importance sampling.
    #[arg(long)]
    pub no_mis: bool,
    /// Switch Russian roulette off.
    #[arg(long)]
    pub no_roulette: bool,
    /// Display with the thesis's gamma 1/2 instead of sRGB.
    #[arg(long)]
    pub gamma2: bool,
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Seed of the random streams.
    #[arg(long)]
    pub seed: Option<u32>,
    /// Animation time in seconds at which objects are placed.
    #[arg(long, default_value_t = 0.0)]
    pub time: f32,
    /// Morton code width of the BVH.
    #[arg(long, value_enum, default_value = "b30")]
    pub bits: Bits,
    /// Which BVH the tracer walks: the binary LBVH, or the 4-wide BVH collapsed from it on
    /// every build (children's boxes in their parent, up to two primitives a leaf). Binary is
    /// the default: on the H100 the wide one traces no faster and builds slower (bench/NOTES.md).
    #[arg(long, value_enum, default_value = "binary")]
    pub bvh: Layout,
    /// How the binary BVH's tree is built: the radix tree over the Morton codes (Karras 2012)
    /// with a bottom-up fit, or H-PLOC (agglomerative clustering within the radix tree's
    /// subtrees: a cheaper tree to trace, a slower build; never restructured by treelets).
    /// `auto` builds by H-PLOC where the frame traces at least 100 million path segments
    /// (pixels x spp x depth, twice with NEE) or the scene has at most 64 primitives (with
    /// --treelets auto; always with on, never with off), else by Karras: H-PLOC's build
    /// costs more (0.24 ms more for the bunny, 0.83 for 1.1M primitives) and its tree traces
    /// 1-10% faster, by scene (H200: the real-time bunny at 1920x1080, depth 4, pays from 16
    /// samples a frame; 800x800 at 32 spp, depth 16: every built-in frame 4-9% faster).
    #[arg(long, value_enum, default_value = "auto")]
    pub tree: Tree,
    /// Build a better binary tree than the radix tree (a slower build, a faster trace): by
    /// H-PLOC (`--tree auto` or `ploc`: see --tree for when `auto` does) or by restructuring
    /// treelets for surface-area cost (`--tree karras`: `auto` does when a frame has at
    /// least 16 samples per pixel and traces at least 32 samples per primitive).
    #[arg(long, value_enum, default_value = "auto")]
    pub treelets: Treelets,
    /// Whether every build writes each node's children as one 64-byte pair after the tree,
    /// which the binary walk reads a step instead of the node and then each child: twice the
    /// tree's bytes (the radix tree's fit writes its boxes into them; after treelets or
    /// H-PLOC, a pass over the tree copies them). `auto` writes them at every size, where a
    /// storage-buffer binding holds them: they make every frame measured faster (H200,
    /// real-time frames: the bunny 8%, the sixteen bunnies 9%, the herd's 10M primitives
    /// 10%).
    #[arg(long, value_enum, default_value = "auto")]
    pub pairs: Pairs,
    /// Objects as instances of their meshes (two-level BVH: each mesh built once, the top
    /// level over the objects every frame; objects that wave or are marked instance = false
    /// form a world-space group refit or built every frame) or flattened into one BVH: auto takes two
    /// levels where the scene marks instance = true, where the rebuild it saves outweighs
    /// tracing two levels (the copies saved are at least two thirds of the samples a build
    /// serves: measured on the H200), or where flattening would not fit.
    #[arg(long, value_enum, default_value = "auto")]
    pub instancing: InstancingMode,
    /// What finds the rays' hits on the GPU: the project's own BVH (lbvh), or the Vulkan
    /// driver's acceleration structures, built by the driver every frame (an instanced
    /// scene's meshes once, its top level every frame) and traced by a ray-tracing pipeline
    /// running the same path loop and shading (driver: devices with
    /// VK_KHR_ray_tracing_pipeline); auto: the driver's for a scene in two levels where the
    /// device has them (faster there on the H100), the project's BVH otherwise.
    #[arg(long, value_enum, default_value = "auto")]
    pub accel: AccelChoice,
    /// How the driver builds its bottom level every frame (with --accel driver).
    #[arg(long, value_enum, default_value = "fast-build")]
    pub driver_build: DriverBuild,
    /// Frames of a scene in two levels that refit its world-space group's BVH (the objects
    /// that wave: their triangles move, their topology stays) between two builds of it;
    /// 0 builds it every frame. Refitting empties the tree's boxes and fits them again: the
    /// build's other stages are skipped, and the tree drifts from the one a build would make.
    #[arg(long, default_value_t = crate::gpu::GROUP_REFITS)]
    pub group_refits: u32,
    /// Frames of a scene in two levels that refit its top level (the instances' boxes taken
    /// again, the tree kept) between two builds of it, each restructured by treelets; 0
    /// builds it every frame.
    #[arg(long, default_value_t = crate::gpu::TOP_REFITS)]
    pub top_refits: u32,
    /// Kernel features beyond what the scene needs: `all`, or +NAME / -NAME for triangles,
    /// spheres, nee, metal, dielectric, thin-lens (comma-separated).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub features: Vec<String>,
    /// Print which kernel features run and why.
    #[arg(long)]
    pub explain: bool,
    /// Denoise (spatiotemporal variance-guided filtering): a render's accumulated samples
    /// once, the viewer's every frame while the image moves.
    #[arg(long)]
    pub denoise: bool,
    /// Camera instead of the scene's: `POSITION:LOOK_AT[:VFOV]`, e.g. `0,1,5:0,0.5,0:40`
    /// (three numbers each, the vertical field of view in degrees).
    #[arg(long, value_parser = parse_camera)]
    pub camera: Option<(Vec3, Vec3, Option<f32>)>,
    /// An HDR environment map (equirectangular .exr or .hdr) lighting the scene instead of
    /// its sky or its own map.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// Turn of the environment map about the vertical axis, in degrees.
    #[arg(long)]
    pub env_rotation: Option<f32>,
    /// Factor on the environment map's radiance.
    #[arg(long)]
    pub env_intensity: Option<f32>,
}

/// Parses `--camera`: `x,y,z:x,y,z[:vfov]`.
pub fn parse_camera(s: &str) -> Result<(Vec3, Vec3, Option<f32>), String> {
    let parts: Vec<&str> = s.split(':').collect();
    let point = |p: &str| -> Result<Vec3, String> {
        let v: Vec<f32> = p
            .split(',')
            .map(|x| x.trim().parse::<f32>().map_err(|e| format!("{x:?}: {e}")))
            .collect::<Result<_, _>>()?;
        match v[..] {
            [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
            _ => Err(format!("{p:?} is not three finite numbers x,y,z")),
        }
    };
    let (position, look_at, vfov) = match parts[..] {
        [p, l] => (point(p)?, point(l)?, None),
        [p, l, f] => {
            let f: f32 = f.trim().parse().map_err(|e| format!("field of view {f:?}: {e}"))?;
            if !(f > 0.0 && f < 180.0) {
                return Err(format!("field of view {f} is not in (0, 180) degrees"));
            }
            (point(p)?, point(l)?, Some(f))
        }
        _ => return Err("write POSITION:LOOK_AT[:VFOV], e.g. 0,1,5:0,0.5,0:40".into()),
    };
    if position == look_at {
        return Err("the camera's position and look-at point are the same".into());
    }
    Ok((position, look_at, vfov))
}

/// How the binary tree is built (see `BuildOptions::ploc`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Tree {
    Auto,
    Karras,
    Ploc,
}

impl Tree {
    /// Path segments a frame traces (at most: [`segments`]) from which `auto` builds by
    /// H-PLOC (with `--treelets auto`). Its build costs more than the radix tree's (H200:
    /// 0.04 ms more for the Cornell box's 36 primitives, 0.19 for Suzanne, 0.24 for the
    /// bunny, 0.83 for the sixteen bunnies' 1.1M, 5.5 ms for the herd's 10M) and its tree
    /// saves a part of every segment's trace that grows with the scene, so that the frames
    /// where it pays begin at about the same amount of tracing at every size: H200,
    /// `bench realtime --spf K` (1920x1080, depth 4, no NEE, 8.3M segments a sample), H-PLOC
    /// against the radix tree: the bunny 4.5% slower at 4 spf, 1% at 8, 0.9% faster at 16;
    /// the sixteen bunnies 3.4% slower at 8, even at 16; the spheres 1.7% slower at 4, even
    /// at 8, 0.4% faster at 16; the herd's frame of 16 samples even (`render`). 800x800, 32
    /// spp, depth 16 with NEE (655M segments): every built-in frame faster, by 4-9%, the
    /// herd's by 5.5%. Where it errs: Suzanne never pays at depth 4 (3% slower at 16
    /// samples), and the closed box of the driver comparison traces 4.5% slower by H-PLOC
    /// than by the radix tree (bench/NOTES.md, session 57). The rule until session 57 (from
    /// 4 samples a frame where the frame traces 32 segments a primitive) was measured when
    /// the walk took about twice as long.
    pub const AUTO_SEGMENTS: u64 = 100_000_000;

    /// Primitives up to which `auto` builds by H-PLOC at any amount of tracing: its build is
    /// then one or two workgroups, 0.04 ms more than the radix tree's, and the Cornell box's
    /// tree by H-PLOC (36 primitives) traces 9-11% faster at every sample count (H200,
    /// `bench realtime --spf 1|2|4|8|16`: 0.624 against 0.643 ms at one sample, 2.374
    /// against 2.601 at 4; the only scene this small measured).
    pub const AUTO_PRIMS: u64 = 64;

    /// Whether frames tracing `segments` path segments (at most: [`segments`]) in a scene of
    /// `prims` primitives build by H-PLOC: `auto` from [`Self::AUTO_SEGMENTS`] or up to
    /// [`Self::AUTO_PRIMS`] with `--treelets auto`, always with `--treelets on`, never with
    /// `off`.
    pub fn builds_ploc(self, treelets: Treelets, segments: u64, prims: u64) -> bool {
        match (self, treelets) {
            (Tree::Ploc, _) => true,
            (Tree::Karras, _) => false,
            (Tree::Auto, Treelets::Auto) => segments >= Self::AUTO_SEGMENTS || prims <= Self::AUTO_PRIMS,
            (Tree::Auto, treelets) => treelets == Treelets::On,
        }
    }
}

/// The most path segments a frame of `spp` samples per pixel over `pixels` pixels traces
/// with `frame`'s depth: one a bounce, two with next-event estimation (its shadow ray).
pub fn segments(frame: &Frame, pixels: u64, spp: u32) -> u64 {
    let nee = if frame.flags & FLAG_NEE != 0 { 2 } else { 1 };
    pixels
        .saturating_mul(spp as u64)
        .saturating_mul(frame.max_depth.max(1) as u64 * nee)
}

/// Whether the binary BVH's builds write its pairs (`BuildOptions::pairs`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Pairs {
    Auto,
    On,
    Off,
}

impl Pairs {
    /// Whether builds write the pairs: `auto` does at every size, where one storage-buffer
    /// binding holds them (`GpuLbvh::has_pairs`; else the walk reads the tree alone). The
    /// walk through them is faster at every size and sample count measured since the walk
    /// loads whole words and steps in its own loop. H200, `bench realtime --instancing off
    /// --no-denoise` (1920x1080, depth 4), GPU frame p50 with and without: the bunny
    /// (69,678 primitives) 0.900 against 0.976 ms, the sixteen bunnies (1,114,659) 2.087
    /// against 2.290 (rebuild 0.434 against 0.378, trace 1.637 against 1.896), the herd
    /// (10,031,907) 6.617 against 7.339 (2.7 GB of GPU memory); at 4 spp 3.28 against 3.54,
    /// 7.15 against 8.19, 18.8 against 24.6 (bench/NOTES.md, session 56; session 42 had
    /// found large trees no faster with them).
    pub fn resolve(self) -> bool {
        match self {
            Pairs::Auto | Pairs::On => true,
            Pairs::Off => false,
        }
    }
}

/// Whether the BVH build restructures treelets (see `BuildOptions`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Treelets {
    Auto,
    On,
    Off,
}

impl Treelets {
    /// Samples per pixel in one frame from which `Auto` restructures. Below it the slower
    /// build costs more than the faster trace saves (H100, 5-leaf treelets: the bunny at
    /// 1920x1080 breaks even near 9 samples, the Cornell box at 800x800 near 7).
    pub const AUTO_FROM_SPP: u32 = 16;

    /// Samples a frame traces (pixels times samples per pixel) per primitive from which
    /// `Auto` restructures: restructuring costs about 8 ns a primitive on the H100 and saves
    /// 0.2 to 1.3 ns a sample, so large scenes need many samples to pay for it (800x800, 32
    /// spp, depth 16, the frame with and without: the herd's 10M primitives 232 against 184
    /// ms, the sixteen bunnies' 1.1M 100.6 against 99.5, the bunny 56.4 against 59.2, the
    /// Cornell box 28.7 against 30.9; bench/NOTES.md session 26).
    pub const AUTO_SAMPLES_PER_PRIM: u64 = 32;

    /// The choice for frames of `spp` samples per pixel over `pixels` pixels of a scene of
    /// `prims` primitives.
    pub fn resolve(self, spp: u32, pixels: u64, prims: u64) -> bool {
        match self {
            Treelets::Auto => spp >= Self::AUTO_FROM_SPP && pixels * spp as u64 >= Self::AUTO_SAMPLES_PER_PRIM * prims,
            Treelets::On => true,
            Treelets::Off => false,
        }
    }
}

#[derive(Copy, Clone, Debug, clap::ValueEnum)]
pub enum Bits {
    B30,
    B63,
}

impl From<Bits> for MortonBits {
    fn from(b: Bits) -> MortonBits {
        match b {
            Bits::B30 => MortonBits::B30,
            Bits::B63 => MortonBits::B63,
        }
    }
}

/// Parses `WIDTHxHEIGHT` (each side 1..=16384).
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size {s:?} is not WIDTHxHEIGHT"))?;
    let parse = |v: &str| v.trim().parse::<u32>().map_err(|e| format!("size {s:?}: {v:?}: {e}"));
    let (w, h) = (parse(w)?, parse(h)?);
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {s:?}: each side must be 1..=16384"));
    }
    Ok((w, h))
}

/// A scene ready to render: its description, GPU data and frame.
pub struct Prepared {
    pub scene: Scene,
    pub data: SceneGpu,
    pub frame: Frame,
    pub spp: u32,
    pub bits: MortonBits,
    pub treelets: Treelets,
    pub layout: Layout,
    pub tree: Tree,
    pub pairs: Pairs,
    /// What traces the rays on the GPU ([`Prepared::tracer`]), and how the driver builds
    /// where it does.
    pub accel: AccelChoice,
    pub driver_build: DriverBuild,
    /// Frames that refit a world-space group between its builds (`--group-refits`), and the
    /// top level (`--top-refits`).
    pub group_refits: u32,
    pub top_refits: u32,
    /// The kernel features the frame runs with, and why.
    pub features: Features,
}

impl SceneArgs {
    /// Opens the scene and applies the command-line overrides.
    pub fn prepare(&self) -> Result<Prepared> {
        let mut scene = Scene::open(&self.scene)?;
        let s = &mut scene.settings;
        if let Some(spp) = self.spp {
            if spp == 0 {
                bail!("--spp must be at least 1");
            }
            s.spp = spp;
        }
        if let Some(d) = self.depth {
            if d == 0 {
                bail!("--depth must be at least 1");
            }
            s.max_depth = d;
        }
        if let Some((w, h)) = self.size {
            (s.width, s.height) = (w, h);
        }
        s.nee &= !self.no_nee;
        s.mis &= !self.no_mis;
        s.russian_roulette &= !self.no_roulette;
        s.gamma2 |= self.gamma2;
        if let Some(e) = self.exposure {
            if !(e.is_finite() && e > 0.0) {
                bail!("--exposure must be a positive number, got {e}");
            }
            s.exposure = e;
        }
        if let Some(seed) = self.seed {
            s.seed = seed;
        }
        if let Some((position, look_at, vfov)) = self.camera {
            let c = &mut scene.camera;
            // Keep "up" unless it is parallel to the new view direction.
            let forward = (look_at - position).normalize();
            if c.up.cross(forward).length_squared() < 1e-6 {
                c.up = if forward.y.abs() < 0.9 { Vec3::Y } else { Vec3::Z };
            }
            (c.position, c.look_at, c.focus_distance) = (position, look_at, None);
            if let Some(f) = vfov {
                c.vfov_deg = f;
            }
        }
        self.apply_environment(&mut scene)?;
        self.check_accel()?;
        let data = scene
            .gpu_data_as(self.time, self.instancing)
            .map_err(anyhow::Error::msg)?;
        let mut frame = render::with_bvh(scene.frame(&data), !self.no_bvh);
        if self.denoise {
            frame.flags |= FLAG_DENOISE;
        }
        let features = features::derive(&data, &frame, &Forced::parse(&self.features)?)?;
        let frame = features.apply(&frame);
        Ok(Prepared {
            features,
            spp: scene.settings.spp,
            scene,
            data,
            frame,
            bits: self.bits.into(),
            treelets: self.treelets,
            layout: self.bvh,
            tree: self.tree,
            pairs: self.pairs,
            accel: self.accel,
            driver_build: self.driver_build,
            group_refits: self.group_refits,
            top_refits: self.top_refits,
        })
    }

    /// Refuses options of the project's BVH with `--accel driver`.
    fn check_accel(&self) -> Result<()> {
        if self.accel == AccelChoice::Driver && self.no_bvh {
            bail!("--no-bvh traces by brute force: not with --accel driver");
        }
        if self.accel == AccelChoice::Driver && self.bvh == Layout::Wide {
            bail!("--bvh wide picks the project's BVH layout: not with --accel driver");
        }
        Ok(())
    }
}

impl SceneArgs {
    /// `--env`, `--env-rotation`, `--env-intensity` on top of the scene's environment.
    fn apply_environment(&self, scene: &mut Scene) -> Result<()> {
        let current = scene.environment.as_ref();
        let rotation = self.env_rotation.or(current.map(|e| e.rotation_deg)).unwrap_or(0.0);
        let intensity = self.env_intensity.or(current.map(|e| e.intensity)).unwrap_or(1.0);
        if let Some(path) = &self.env {
            let (env, warnings) = Environment::load(path, rotation, intensity)?;
            for w in warnings {
                eprintln!("warning: {w}");
            }
            scene.environment = Some(env);
        } else if let Some(env) = scene.environment.as_mut() {
            if !(rotation.is_finite() && intensity.is_finite() && intensity >= 0.0) {
                bail!("--env-rotation must be finite and --env-intensity finite and at least 0");
            }
            (env.rotation_deg, env.intensity) = (rotation, intensity);
        } else if self.env_rotation.is_some() || self.env_intensity.is_some() {
            bail!(
                "--env-rotation and --env-intensity need an environment map (--env FILE or the scene's [environment])"
            );
        }
        Ok(())
    }
}

impl Prepared {
    /// How to build the BVH for frames of `spp` samples per pixel: by H-PLOC where `--tree`
    /// says ([`Tree::builds_ploc`]), else the radix tree, restructured by treelets where
    /// `--treelets` says it pays.
    pub fn build(&self, spp: u32) -> BuildOptions {
        let prims = self.frame.n_prims as u64;
        BuildOptions {
            bits: self.bits,
            treelets: self.treelets.resolve(spp, self.pixels(), prims),
            wide: self.layout == Layout::Wide,
            rounds: 1,
            ploc: self.tree.builds_ploc(self.treelets, self.segments(spp), prims),
            pairs: self.pairs.resolve(),
        }
    }

    /// The frame's pixels.
    pub fn pixels(&self) -> u64 {
        self.frame.width as u64 * self.frame.height as u64
    }

    /// The most path segments a frame of `spp` samples per pixel traces ([`segments`]).
    pub fn segments(&self, spp: u32) -> u64 {
        segments(&self.frame, self.pixels(), spp)
    }

    /// What traces this frame's rays on `gpu`, and why ([`AccelChoice::resolve`]).
    pub fn tracer(&self, gpu: &crate::gpu::Gpu) -> (Accel, &'static str) {
        let project_only = self.frame.flags & shared::types::FLAG_BVH == 0 || self.layout == Layout::Wide;
        self.accel
            .resolve(gpu.ray_tracing.is_ok(), self.data.instancing.is_some(), project_only)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_pairs_at_every_size() {
        assert!(Pairs::Auto.resolve() && Pairs::On.resolve() && !Pairs::Off.resolve());
    }

    #[test]
    fn auto_treelets_need_many_samples_and_enough_of_them_per_primitive() {
        let px = 800 * 800;
        // The Cornell box and the bunny at 32 spp restructure; the sixteen bunnies and the
        // herd do not; below 16 spp nothing does.
        assert!(Treelets::Auto.resolve(32, px, 36));
        assert!(Treelets::Auto.resolve(32, px, 69_678));
        assert!(!Treelets::Auto.resolve(32, px, 1_114_659));
        assert!(!Treelets::Auto.resolve(32, px, 10_031_907));
        assert!(!Treelets::Auto.resolve(8, px, 36));
        assert!(Treelets::On.resolve(1, 1, u64::MAX / 64) && !Treelets::Off.resolve(64, px, 1));
    }

    #[test]
    fn auto_trees_by_h_ploc_from_a_hundred_million_segments_or_up_to_64_primitives() {
        let frame = |depth, flags| Frame {
            max_depth: depth,
            flags,
            ..Default::default()
        };
        let hd = |spp| segments(&frame(4, 0), 1920 * 1080, spp);
        let table2 = segments(&frame(16, FLAG_NEE), 800 * 800, 32);
        let closed_box = segments(&frame(16, 0), 800 * 800, 32);
        assert_eq!(table2, 800 * 800 * 32 * 16 * 2);
        assert_eq!(segments(&frame(64, FLAG_NEE), 16384 * 16384, u32::MAX), u64::MAX);
        let auto = |segments, prims| Tree::Auto.builds_ploc(Treelets::Auto, segments, prims);
        // Real-time frames of the bunny at 1920x1080, depth 4: the radix tree up to 12
        // samples a frame, H-PLOC from 13; table 2's frame and the closed box's by H-PLOC,
        // the herd's too; the Cornell box's 36 primitives at any sample count.
        let bunny = 69_678;
        assert!(!auto(hd(1), bunny) && !auto(hd(8), bunny) && !auto(hd(12), bunny));
        assert!(auto(hd(13), bunny) && auto(hd(16), bunny) && !auto(hd(8), 10_031_907));
        assert!(auto(table2, bunny) && auto(closed_box, bunny) && auto(table2, 10_031_907));
        assert!(auto(hd(1), 36) && auto(1, 64) && !auto(hd(1), 65));
        // --treelets on and off decide for `auto`; karras and ploc decide alone.
        assert!(Tree::Auto.builds_ploc(Treelets::On, 1, u64::MAX));
        assert!(!Tree::Auto.builds_ploc(Treelets::Off, u64::MAX, 1));
        assert!(Tree::Ploc.builds_ploc(Treelets::Off, 1, u64::MAX));
        assert!(!Tree::Karras.builds_ploc(Treelets::On, u64::MAX, 1));
    }

    #[test]
    fn camera_option_parses_and_bad_ones_are_named() {
        let (p, l, f) = parse_camera("0,1,5:0,0.5,0:40").unwrap();
        assert_eq!(
            (p, l, f),
            (Vec3::new(0.0, 1.0, 5.0), Vec3::new(0.0, 0.5, 0.0), Some(40.0))
        );
        assert_eq!(parse_camera(" 1, 2, 3 : 0,0,0").unwrap().2, None);
        for (bad, says) in [
            ("1,2:0,0,0", "three finite numbers"),
            ("1,2,3", "POSITION:LOOK_AT"),
            ("1,2,3:0,0,0:200", "(0, 180)"),
            ("1,2,3:1,2,3", "the same"),
            ("1,2,nan:0,0,0", "three finite numbers"),
        ] {
            let e = parse_camera(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
        // The scene's camera is replaced, its up kept unless parallel to the view.
        let args =
            <SceneArgs as clap::Parser>::parse_from(["raytrace", "cornell", "--camera", "278,900,278:278,0,278:30"]);
        let p = args.prepare().unwrap();
        let c = p.scene.camera;
        assert_eq!(
            (c.position, c.look_at, c.vfov_deg),
            (Vec3::new(278.0, 900.0, 278.0), Vec3::new(278.0, 0.0, 278.0), 30.0)
        );
        assert!(c.up.cross(c.look_at - c.position).length() > 0.0);
    }
}
