//! The GPU LBVH build: bounds, Morton codes, multi-workgroup radix sort, Karras tree and
//! refit, recorded into one command buffer, with a timestamp after every stage or only around
//! the whole build. Buffers grow to the largest input seen and are reused by every later build.
use super::{BindingSets, Buffer, Commands, Gpu, Kernel, Kernels, BINDINGS};
use crate::bvh::{BuildOptions, BuildResult, MortonBits, Sort, STAGES};
use anyhow::{Context, Result};
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::MemoryLocation;
use shared::merge_sort;
use shared::ploc;
use shared::radix_sort as sort;
use shared::traverse;
use shared::types::{grid, item_groups, BuildParams, Node, OrderedBounds, Sphere, Triangle, WORKGROUP};
use shared::wide::{self, WideNode};
use std::sync::Arc;

/// The build set's binding of the nodes (`shared::types`' table).
const NODES: u32 = 8;

/// Device buffers of the build, sized for `capacity` primitives.
struct Buffers {
    tris: Buffer,
    spheres: Buffer,
    bounds: Buffer,
    keys_a: Buffer,
    vals_a: Buffer,
    keys_b: Buffer,
    vals_b: Buffer,
    /// The sort's status tables (its look-back).
    table: Buffer,
    /// The sort's digit totals and tile counters.
    totals: Buffer,
    nodes: Buffer,
    parents: Buffer,
    visits: Buffer,
    /// The wide BVH (a slot per binary internal node: wide nodes take their binary roots'
    /// indices) and the collapse's scratch, `shared::wide::slots` each, where wide builds were asked for
    /// (`has_wide`); else a word each, for the bindings (132 bytes a primitive saved).
    wide: Buffer,
    wide_scratch: Buffer,
    has_wide: bool,
    /// Whether `nodes` was made with room for the pairs after the tree
    /// (`traverse::traced_nodes`) where builds with pairs were asked for (`pairs_asked`):
    /// unless the device's storage-buffer binding cannot hold them (then the tracers walk
    /// the tree alone, `VARIANT_NO_PAIRS`).
    pairs_asked: bool,
    has_pairs: bool,
    /// Unsorted Morton codes, copied out when a build is captured for comparison; and the
    /// host-visible copy of primitives `upload` writes. Made on first use: the renderer's
    /// builds need neither (56 bytes a primitive).
    capture: Option<Buffer>,
    staging: Option<Buffer>,
    /// Ping-pong sets: set 0 sorts A -> B, set 1 sorts B -> A.
    sets: BindingSets,
    tri_capacity: usize,
    sphere_capacity: usize,
    capacity: usize,
}

impl Buffers {
    fn new(
        gpu: &Arc<Gpu>,
        kernels: &Kernels,
        n_tris: usize,
        n_spheres: usize,
        has_wide: bool,
        pairs_asked: bool,
    ) -> Result<Buffers> {
        let n = (n_tris + n_spheres).max(1) as u64;
        let dev = |name: &str, bytes: u64| Buffer::new(gpu, name, bytes, MemoryLocation::GpuOnly);
        let tris = dev("triangles", (n_tris * size_of::<Triangle>()) as u64)?;
        let spheres = dev("spheres", (n_spheres * size_of::<Sphere>()) as u64)?;
        // The reduction's and the last build's (see `shared::bounds`).
        let bounds = dev("bounds", 2 * size_of::<OrderedBounds>() as u64)?;
        let keys_a = dev("keys A", n * 8)?;
        let vals_a = dev("values A", n * 4)?;
        let keys_b = dev("keys B", n * 8)?;
        let vals_b = dev("values B", n * 4)?;
        let table = dev("sort status tables", sort::table_words(n as u32) as u64 * 4)?;
        let totals = dev("sort digit totals", sort::TOTALS_WORDS as u64 * 4)?;
        // The tree's nodes, then the pairs the binary walk reads (`traverse::write_pairs`)
        // where asked for and one binding can hold them.
        let node = size_of::<Node>() as u64;
        let traced = traverse::traced_nodes(n as u32).max(1) as u64 * node;
        let has_pairs = pairs_asked && traced <= gpu.max_binding;
        let nodes = dev("nodes", if has_pairs { traced } else { (2 * n - 1) * node })?;
        let parents = dev("parents", (2 * n - 1) * 4)?;
        let visits = dev("visit counters and node ranges", 2 * n * 4)?;
        let slots = wide::slots(n as u32) as u64;
        let (wide_bytes, scratch_bytes) = if has_wide {
            (slots * size_of::<WideNode>() as u64, slots * 4)
        } else {
            (4, 4)
        };
        let wide = dev("wide BVH", wide_bytes)?;
        let wide_scratch = dev("wide collapse scratch", scratch_bytes)?;
        let a_to_b: [&Buffer; BINDINGS] = [
            &tris,
            &spheres,
            &bounds,
            &keys_a,
            &vals_a,
            &keys_b,
            &vals_b,
            &table,
            &nodes,
            &parents,
            &visits,
            &totals,
            &wide,
            &wide_scratch,
        ];
        let mut b_to_a = a_to_b;
        b_to_a[3..7].copy_from_slice(&[&keys_b, &vals_b, &keys_a, &vals_a]);
        let sets = BindingSets::new(gpu, kernels, 0, &[&a_to_b, &b_to_a])?;
        Ok(Buffers {
            tris,
            spheres,
            bounds,
            keys_a,
            vals_a,
            keys_b,
            vals_b,
            table,
            totals,
            nodes,
            parents,
            visits,
            wide,
            wide_scratch,
            has_wide,
            pairs_asked,
            has_pairs,
            capture: None,
            staging: None,
            sets,
            tri_capacity: n_tris,
            sphere_capacity: n_spheres,
            capacity: n as usize,
        })
    }
}

/// Builds BVHs on the GPU.
pub struct GpuLbvh {
    gpu: Arc<Gpu>,
    kernels: Arc<Kernels>,
    cmds: Commands,
    bufs: Option<Buffers>,
    /// A wide build was asked for: the buffers keep room for wide BVHs from then on.
    wide: bool,
    /// Builds with pairs were asked for: the buffers keep room for them from then on.
    pairs: bool,
    n_tris: u32,
    n: u32,
    /// Where the build writes its nodes when not in its own buffer ([`GpuLbvh::place_nodes`]):
    /// a buffer of the caller's, from a byte offset, with room for so many nodes.
    nodes_at: Option<(ash::vk::Buffer, u64, u64)>,
}

/// Where a build's first stages take the primitives' bounds and summaries from.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Inputs {
    /// The bounds kernel reduces them (and stores the summaries).
    Reduce,
    /// A kernel of the caller's did, as the bounds kernel does (`instance_bounds`).
    Reduced,
    /// The merge sort's runs kernel over instances (`instance_runs_*`, with this set of
    /// objects and instances) makes the primitives and codes them in the last build's bounds.
    Instances(vk::DescriptorSet),
}

impl GpuLbvh {
    pub fn new(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>) -> Result<GpuLbvh> {
        Ok(GpuLbvh {
            gpu: gpu.clone(),
            kernels: kernels.clone(),
            cmds: Commands::new(gpu)?,
            bufs: None,
            wide: false,
            pairs: false,
            n_tris: 0,
            n: 0,
            nodes_at: None,
        })
    }

    /// Number of primitives of the current input.
    pub fn len(&self) -> u32 {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Bytes of device memory held: (BVH nodes, everything else).
    pub fn memory(&self) -> (u64, u64) {
        match &self.bufs {
            None => (0, 0),
            Some(b) => {
                let all = [
                    &b.tris,
                    &b.spheres,
                    &b.bounds,
                    &b.keys_a,
                    &b.vals_a,
                    &b.keys_b,
                    &b.vals_b,
                    &b.table,
                    &b.totals,
                    &b.parents,
                    &b.visits,
                    &b.wide_scratch,
                ];
                let made = [&b.capture, &b.staging].map(|x| x.as_ref().map_or(0, |x| x.size));
                (
                    b.nodes.size + b.wide.size,
                    all.iter().map(|x| x.size).sum::<u64>() + made.iter().sum::<u64>(),
                )
            }
        }
    }

    /// Sizes the build for `n_tris` triangles and `n_spheres` spheres, growing the buffers
    /// only when they are too small. The primitives are then written by [`GpuLbvh::upload`]
    /// or by a kernel (the renderer's transform stage) into set 0's bindings 0 and 1.
    pub fn reserve(&mut self, n_tris: usize, n_spheres: usize) -> Result<()> {
        let fits = self.bufs.as_ref().is_some_and(|b| {
            b.tri_capacity >= n_tris && b.sphere_capacity >= n_spheres && b.capacity >= n_tris + n_spheres
        });
        if !fits {
            let grow = |x: usize| x + x / 4;
            self.allocate(grow(n_tris), grow(n_spheres), false)?;
        }
        self.n_tris = n_tris as u32;
        self.n = (n_tris + n_spheres) as u32;
        Ok(())
    }

    /// Makes room for what builds with `opts` write besides the tree: wide BVHs, or the
    /// pairs (once: the room is kept; none for pairs where the nodes are placed elsewhere,
    /// [`Self::place_nodes`]). Buffers not made yet are made with it; existing ones are
    /// made again at the same capacity, the primitives already there copied over (anything
    /// recorded before that names the old buffers must have finished). Whether the buffers
    /// were made again.
    pub fn reserve_room(&mut self, opts: BuildOptions) -> Result<bool> {
        self.wide |= opts.wide;
        self.pairs |= opts.pairs && !opts.wide && self.nodes_at.is_none();
        match &self.bufs {
            Some(b) if (self.wide && !b.has_wide) || (self.pairs && !b.pairs_asked) => {
                let (t, s) = (b.tri_capacity, b.sphere_capacity);
                self.allocate(t, s, true)?;
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    /// New buffers for `n_tris` triangles and `n_spheres` spheres (and wide BVHs where asked
    /// for), cleared as every build expects; with `keep`, the old buffers' primitives copied.
    fn allocate(&mut self, n_tris: usize, n_spheres: usize, keep: bool) -> Result<()> {
        // The old buffers may still be read by a frame in flight (the viewer's).
        // SAFETY: plain wait on the live device.
        unsafe { self.gpu.device.device_wait_idle() }.context("waiting for the GPU")?;
        if !keep {
            // Freed before the new ones are made: a scene near the memory's size fits once.
            self.bufs = None;
        }
        let mut b = Buffers::new(&self.gpu, &self.kernels, n_tris, n_spheres, self.wide, self.pairs)?;
        // What every build expects to find and leaves behind (see `record`).
        self.cmds.begin()?;
        Self::empty_bounds(&self.cmds, &b, 0);
        Self::empty_bounds(&self.cmds, &b, 1);
        self.cmds.fill_range(&b.totals, 0, b.totals.size, 0);
        self.cmds.fill_range(&b.table, 0, b.table.size, 0);
        // The collapse's arrival flags start clear; every wide build leaves them so.
        self.cmds.fill_range(&b.wide_scratch, 0, b.wide_scratch.size, 0);
        if let Some(old) = self.bufs.as_mut().filter(|_| keep) {
            for (from, to) in [(&old.tris, &b.tris), (&old.spheres, &b.spheres)] {
                let bytes = from.size.min(to.size);
                if bytes > 4 {
                    self.cmds.copy_range(from, 0, to, 0, bytes);
                }
            }
            // The same capacity: what was made on first use serves the new buffers too.
            (b.staging, b.capture) = (old.staging.take(), old.capture.take());
        }
        self.cmds.barrier();
        self.cmds.submit_wait().context("clearing the build's buffers")?;
        if let Some((raw, offset, _)) = self.nodes_at {
            for set in 0..b.sets.sets.len() {
                b.sets.rebind(set, NODES, raw, offset);
            }
        }
        self.bufs = Some(b);
        Ok(())
    }

    /// Makes the builds write their nodes into `nodes` from node `first` on instead of the
    /// builder's own buffer, which then holds nothing ([`Self::result`] and
    /// [`Self::buffers`] name it still): the top level of two levels writes where the
    /// tracers read it, and no copy follows the build. Builds of more primitives than the
    /// room there holds trees of are refused. False (nothing changed) where the device
    /// cannot bind a buffer from that offset.
    pub fn place_nodes(&mut self, nodes: &Buffer, first: u32) -> Result<bool> {
        let node = size_of::<Node>() as u64;
        let offset = first as u64 * node;
        anyhow::ensure!(offset < nodes.size, "node {first} is past the end of {}", nodes.name);
        let room = (nodes.size - offset) / node;
        if !offset.is_multiple_of(self.gpu.offset_alignment) || nodes.size - offset > self.gpu.max_binding {
            return Ok(false);
        }
        // The sets may name the builder's own buffer in commands still running.
        // SAFETY: plain wait on the live device.
        unsafe { self.gpu.device.device_wait_idle() }.context("waiting for the GPU")?;
        self.nodes_at = Some((nodes.raw, offset, room));
        if let Some(b) = &self.bufs {
            for set in 0..b.sets.sets.len() {
                b.sets.rebind(set, NODES, nodes.raw, offset);
            }
        }
        Ok(true)
    }

    /// Descriptor set 0 of the build (world primitives in bindings 0 and 1, the BVH in 8).
    pub fn set(&self) -> Result<ash::vk::DescriptorSet> {
        Ok(self.bufs.as_ref().context("no primitives reserved")?.sets.sets[0])
    }

    /// Uploads world-space primitives, growing the buffers only when they are too small.
    pub fn upload(&mut self, tris: &[Triangle], spheres: &[Sphere]) -> Result<()> {
        self.reserve(tris.len(), spheres.len())?;
        let b = self.bufs.as_mut().context("buffers missing")?;
        let tri_bytes = std::mem::size_of_val(tris) as u64;
        let mut data: Vec<u8> = bytemuck::cast_slice(tris).to_vec();
        data.extend_from_slice(bytemuck::cast_slice(spheres));
        if b.staging.as_ref().is_none_or(|s| s.size < data.len() as u64) {
            // Room for every primitive the buffers hold, so that it is made once.
            let room = b.tri_capacity * size_of::<Triangle>() + b.sphere_capacity * size_of::<Sphere>();
            b.staging = Some(Buffer::new(
                &self.gpu,
                "staging",
                room as u64,
                MemoryLocation::CpuToGpu,
            )?);
        }
        let staging = b.staging.as_mut().context("staging missing")?;
        staging.write(&data)?;
        self.cmds.begin()?;
        if tri_bytes > 0 {
            self.cmds.copy_range(staging, 0, &b.tris, 0, tri_bytes);
        }
        if !spheres.is_empty() {
            self.cmds
                .copy_range(staging, tri_bytes, &b.spheres, 0, std::mem::size_of_val(spheres) as u64);
        }
        self.cmds.barrier();
        self.cmds.submit_wait().context("uploading primitives")
    }

    /// The buffers of the primitives (triangles, spheres) and of the nodes.
    pub fn buffers(&self) -> Result<(&Buffer, &Buffer, &Buffer)> {
        let b = self.bufs.as_ref().context("no primitives reserved")?;
        Ok((&b.tris, &b.spheres, &b.nodes))
    }

    /// Writes `nodes` at the start of the node buffer: BVHs built elsewhere (the bottom
    /// level of an instanced scene, `GpuRenderer::load_levels`).
    pub fn upload_nodes(&mut self, nodes: &[Node]) -> Result<()> {
        let b = self.bufs.as_ref().context("no primitives reserved")?;
        let bytes = std::mem::size_of_val(nodes) as u64;
        anyhow::ensure!(
            bytes <= b.nodes.size,
            "{} nodes do not fit the node buffer ({} bytes)",
            nodes.len(),
            b.nodes.size
        );
        if nodes.is_empty() {
            return Ok(());
        }
        let mut staging = Buffer::new(&self.gpu, "staging", bytes, MemoryLocation::CpuToGpu)?;
        staging.write(nodes)?;
        self.cmds.begin()?;
        self.cmds.copy_range(&staging, 0, &b.nodes, 0, bytes);
        self.cmds.barrier();
        self.cmds.submit_wait().context("uploading nodes")
    }

    /// Records a fill of entry `k` of the bounds buffer with [`OrderedBounds::EMPTY`].
    fn empty_bounds(cmds: &Commands, b: &Buffers, k: u64) {
        let at = k * size_of::<OrderedBounds>() as u64;
        cmds.fill_range(&b.bounds, at, 16, u32::MAX);
        cmds.fill_range(&b.bounds, at + 16, 16, 0);
    }

    /// Records the whole build into `cmds` (which must be recording), with a timestamp
    /// before the first stage and, with `stages`, after each stage (labelled by `STAGES` and
    /// the sort's kernels), else one after the last labelled "build". Each timestamp costs
    /// about a microsecond of GPU time (H100: the bunny's build 228 us without, 242 with).
    pub fn record(&self, cmds: &mut Commands, opts: BuildOptions, capture: bool, stages: bool) -> Result<()> {
        self.record_stages(cmds, opts, capture, stages, Inputs::Reduce)
    }

    /// [`Self::record`] of a build whose bounds a kernel of the caller's reduced, and whose
    /// primitives' summaries it stored, as the bounds stage does (`transform_bounds`: the
    /// renderer's transform stage; `instance_bounds`: the top level of two levels); its
    /// stages from the Morton codes on.
    pub fn record_bounded(&self, cmds: &mut Commands, opts: BuildOptions, stages: bool) -> Result<()> {
        self.record_stages(cmds, opts, false, stages, Inputs::Reduced)
    }

    /// [`Self::record`] of a top level's build after a first (whose bounds are the last
    /// build's, `b[1]`), sorted by merging ([`Self::merges`]): the runs kernel makes the
    /// instances' world boxes (`instances`: the set with their objects and instances) and
    /// codes them in those bounds, reducing this build's for the next (`instance_runs_*`).
    pub fn record_instanced(
        &self,
        cmds: &mut Commands,
        opts: BuildOptions,
        stages: bool,
        instances: vk::DescriptorSet,
    ) -> Result<()> {
        anyhow::ensure!(
            self.merges(opts.bits),
            "a build of {} primitives by the instances' runs kernel, which only a merge sort has",
            self.n
        );
        self.record_stages(cmds, opts, false, stages, Inputs::Instances(instances))
    }

    /// Whether a build of the primitives sorts them by merging (`shared::merge_sort`).
    pub fn merges(&self, bits: MortonBits) -> bool {
        Sort::of(self.n, bits) == Sort::Merge
    }

    fn record_stages(
        &self,
        cmds: &mut Commands,
        opts: BuildOptions,
        capture: bool,
        stages: bool,
        inputs: Inputs,
    ) -> Result<()> {
        let bits = opts.bits;
        let b = self.bufs.as_ref().context("no primitives uploaded")?;
        let n = self.n;
        if let Some((_, _, room)) = self.nodes_at {
            anyhow::ensure!(
                (2 * n as u64).saturating_sub(1) <= room,
                "a build of {n} primitives into room for {room} nodes (GpuLbvh::place_nodes)"
            );
        }
        anyhow::ensure!(
            !opts.wide || b.has_wide,
            "a wide build without room for it (GpuLbvh::reserve_room first)"
        );
        anyhow::ensure!(
            !opts.wide || n <= wide::MAX_PRIMITIVES,
            "the wide BVH holds at most {} primitives ({n} given): use --bvh binary",
            wide::MAX_PRIMITIVES
        );
        let items = n.div_ceil(WORKGROUP);
        let k = &self.kernels;
        let sorting = Sort::of(n, bits);
        let mut p = BuildParams {
            n_tris: self.n_tris,
            n,
            shift: 0,
            passes: sorting.passes(bits),
        };
        let tiles = p.tiles();
        let (set_ab, set_ba) = (b.sets.sets[0], b.sets.sets[1]);
        let many = sort::items(n) != sort::FEW;
        let (morton_counted, scatter, runs, instance_runs, merge, build) = match bits {
            MortonBits::B30 => (
                Kernel::Morton30Counted,
                if many {
                    Kernel::SortScatterManyU32
                } else {
                    Kernel::SortScatterU32
                },
                Kernel::SortRunsU32,
                Kernel::InstanceRunsU32,
                Kernel::SortMergeU32,
                Kernel::KarrasBuildU32,
            ),
            MortonBits::B63 => (
                Kernel::Morton63Counted,
                if many {
                    Kernel::SortScatterManyU64
                } else {
                    Kernel::SortScatterU64
                },
                Kernel::SortRunsU64,
                Kernel::InstanceRunsU64,
                Kernel::SortMergeU64,
                Kernel::KarrasBuildU64,
            ),
        };
        let stamp = |cmds: &mut Commands, label| {
            if stages {
                cmds.timestamp(label);
            }
        };
        // No fills: the bounds' reduction starts empty and the sort's tables zero because the
        // tree kernel of the build before (or `reserve`) left them so. A build of the top
        // level follows a timestamp of its caller's, so stamps no "start" of its own (two
        // stamps fewer: the top level of 10,000 instances built in 56.1 us instead of 57.2,
        // H200).
        if inputs == Inputs::Reduce {
            cmds.timestamp("start");
        }
        if n == 0 {
            Self::empty_bounds(cmds, b, 1);
            cmds.barrier();
            for s in STAGES {
                stamp(cmds, s);
            }
            if !stages {
                cmds.timestamp("build");
            }
            return Ok(());
        }
        if opts.builds_ploc() {
            // H-PLOC's links start empty: a Karras build leaves leaf ranges past `n - 1` of
            // its own `n` (read by its refits), an H-PLOC build cluster lists there. Nothing
            // before the tree stage touches the visits, and the stages' barriers order the fill.
            cmds.fill_range(&b.visits, 0, (n as u64 - 1) * 4, 0);
        }
        if inputs == Inputs::Reduce {
            cmds.dispatch(k, set_ab, Kernel::BoundsReduce, &p, item_groups(n))?;
            cmds.barrier();
        }
        stamp(cmds, STAGES[0]);
        // The radix passes take their digit totals from the Morton stage. The merge sort's
        // runs kernel is its Morton stage: its runs go to the second pair, merged into the
        // first (where the tree kernel reads), its codes to the first's keys meanwhile; a
        // single run, sorted whole, goes to the first, its codes to the second's keys.
        let single = n <= merge_sort::RUN;
        let run_set = if single { set_ab } else { set_ba };
        match (sorting, inputs) {
            (Sort::Radix, _) => cmds.dispatch(k, set_ab, morton_counted, &p, item_groups(n))?,
            (Sort::Merge, Inputs::Instances(set)) => {
                let (x, y) = grid(items);
                cmds.dispatch_sets(k, &[run_set, set], instance_runs, bytemuck::bytes_of(&p), x, y)?
            }
            (Sort::Merge, _) => cmds.dispatch(k, run_set, runs, &p, items)?,
        }
        cmds.barrier();
        if capture {
            let to = b
                .capture
                .as_ref()
                .context("a captured build without room (run makes it)")?;
            let codes = if sorting == Sort::Merge && single {
                &b.keys_b
            } else {
                &b.keys_a
            };
            cmds.copy_range(codes, 0, to, 0, n as u64 * 8);
            cmds.barrier();
        }
        stamp(cmds, STAGES[1]);
        match sorting {
            Sort::Merge if single => {}
            Sort::Merge => {
                cmds.dispatch(k, set_ba, merge, &p, items)?;
                cmds.barrier();
                stamp(cmds, "sort.merge");
            }
            Sort::Radix => {
                for pass in 0..p.passes {
                    p.shift = pass * sort::RADIX_BITS;
                    let set = if pass % 2 == 0 { set_ab } else { set_ba };
                    cmds.dispatch(k, set, scatter, &p, tiles)?;
                    cmds.barrier();
                    stamp(cmds, "sort.scatter");
                }
            }
        }
        if opts.builds_ploc() {
            // The tree and its boxes in one dispatch.
            let kernel = match bits {
                MortonBits::B30 => Kernel::PlocU32,
                MortonBits::B63 => Kernel::PlocU64,
            };
            let tree = k.specialised(kernel, u32::from(!self.gpu.is_lavapipe()))?;
            let (x, y) = grid(n.div_ceil(ploc::GROUP));
            cmds.dispatch_pipeline(k, tree, &[set_ab], bytemuck::bytes_of(&p), x, y);
            cmds.barrier();
            stamp(cmds, STAGES[3]);
            // Its "refit" stage: the pairs.
            self.record_pairs(cmds, &p, opts)?;
            cmds.timestamp(if stages { STAGES[4] } else { "build" });
            return Ok(());
        }
        cmds.dispatch(k, set_ab, build, &p, items)?;
        cmds.barrier();
        stamp(cmds, STAGES[3]);
        let refit = match self.gpu.refit_kernel(opts.restructures()) {
            // The wide collapse's nodes are decided by the fit on the way.
            (Kernel::Fit, Some(constant)) if opts.wide => k.specialised(Kernel::FitWide, constant)?,
            (Kernel::Fit, Some(constant)) => k.specialised(Kernel::Fit, constant | self.fit_pairs(opts))?,
            (kernel, Some(constant)) => k.specialised(kernel, constant)?,
            (kernel, None) => k.pipeline(kernel)?,
        };
        let (x, y) = grid(items);
        cmds.dispatch_pipeline(k, refit, &[set_ab], bytemuck::bytes_of(&p), x, y);
        cmds.barrier();
        if opts.restructures() && n > 1 {
            // Further rounds (the refit left every visit counter zero).
            let (kernel, constant) = self.gpu.restructured_kernel(true);
            let again = k.specialised(kernel, constant)?;
            for _ in 1..opts.rounds {
                cmds.dispatch_pipeline(k, again, &[set_ab], bytemuck::bytes_of(&p), x, y);
                cmds.barrier();
            }
        }
        if opts.wide {
            stamp(cmds, STAGES[4]);
            cmds.dispatch(k, set_ab, Kernel::WideWrite, &p, wide::slots(n).div_ceil(WORKGROUP))?;
            cmds.barrier();
            cmds.timestamp(if stages { "wide" } else { "build" });
        } else {
            // The pairs' pass is timed in the refit stage: after a fit that wrote the boxes
            // into the pairs, only the entries of the nodes above its blocks.
            self.record_pairs(cmds, &p, opts)?;
            cmds.timestamp(if stages { STAGES[4] } else { "build" });
        }
        Ok(())
    }

    /// Whether builds with `BuildOptions::pairs` write the pairs after the tree (their own
    /// node buffer, made with room for them within one binding: [`Self::reserve_room`]);
    /// else the tracers walk the tree alone (`VARIANT_NO_PAIRS`).
    pub fn has_pairs(&self) -> bool {
        self.nodes_at.is_none() && self.bufs.as_ref().is_some_and(|b| b.has_pairs)
    }

    /// Whether builds with `opts` write pairs ([`Self::has_pairs`]; none under two
    /// primitives, none for a wide BVH).
    fn writes_pairs(&self, opts: BuildOptions) -> bool {
        opts.pairs && !opts.wide && self.has_pairs() && self.n >= 2
    }

    /// The `fit` kernel's constant bit for a build or refit with `opts` of a Karras tree (not
    /// restructured): where the build writes pairs, the fit writes the boxes into them
    /// (`shared::refit::FIT_PAIRS`; H200, the sixteen bunnies' rebuild 0.427 -> 0.375 ms:
    /// the full pass after the fit took 0.057).
    fn fit_pairs(&self, opts: BuildOptions) -> u32 {
        if self.writes_pairs(opts) && !opts.counter_refit() {
            shared::refit::FIT_PAIRS
        } else {
            0
        }
    }

    /// Records the pairs' pass after the tree's boxes are final (`pairs_write`: each internal
    /// node's children copied as a flattened scene's binary walk reads them,
    /// `traverse::write_pairs`); after a fit that wrote the boxes into the pairs
    /// ([`Self::fit_pairs`]), only the entries of the nodes above its blocks
    /// (`shared::refit::pair_entry_above`). Not for nodes placed in another buffer (the levels
    /// of a scene in two levels, whose walk reads the tree itself).
    fn record_pairs(&self, cmds: &mut Commands, p: &BuildParams, opts: BuildOptions) -> Result<()> {
        if !self.writes_pairs(opts) {
            return Ok(());
        }
        let b = self.bufs.as_ref().context("no primitives uploaded")?;
        let k = &self.kernels;
        let above = self.fit_pairs(opts) != 0;
        let pass = k.specialised(Kernel::PairsWrite, u32::from(above))?;
        let (x, y) = grid((self.n - 1).div_ceil(WORKGROUP));
        cmds.dispatch_pipeline(k, pass, &[b.sets.sets[0]], bytemuck::bytes_of(p), x, y);
        cmds.barrier();
        Ok(())
    }

    /// Records a refit into `cmds` (which must be recording): the tree the last build made
    /// with `opts` over the same number of primitives is kept (its sorted order, links,
    /// parents and leaf ranges, all in the buffers still) and fitted again over the
    /// primitives as they are now: the bounds, Morton codes, sort and tree stages are
    /// skipped. A Karras tree has every internal box emptied (`empty_boxes`) and the build's
    /// fit run again; a tree restructured by treelets (whose leaf ranges the fit cannot use)
    /// the counter refit with every counter device-scope (`refit_restructured`; each counter
    /// zero as the build or the refit before left it), which with `again` restructures the
    /// treelets once more (a further round of the build's). A timestamp before and one after,
    /// labelled "refit". A wide BVH cannot be refit (it would be collapsed again).
    pub fn record_refit(&self, cmds: &mut Commands, opts: BuildOptions, again: bool) -> Result<()> {
        anyhow::ensure!(!opts.wide, "a wide BVH cannot be refit: a binary build");
        anyhow::ensure!(
            !again || opts.restructures(),
            "a refit restructures again only a tree restructured by treelets"
        );
        let b = self.bufs.as_ref().context("no primitives uploaded")?;
        let p = BuildParams {
            n_tris: self.n_tris,
            n: self.n,
            shift: 0,
            passes: 0,
        };
        cmds.timestamp("start");
        if self.n > 0 {
            let k = &self.kernels;
            let set = b.sets.sets[0];
            let items = self.n.div_ceil(WORKGROUP);
            let refit = if opts.counter_refit() {
                // Every visit counter zero: the build's refit or H-PLOC links, or the refit
                // before, left it so.
                let (kernel, constant) = self.gpu.restructured_kernel(again);
                k.specialised(kernel, constant)?
            } else {
                cmds.dispatch(k, set, Kernel::EmptyBoxes, &p, items)?;
                cmds.barrier();
                match self.gpu.refit_kernel(false) {
                    (kernel, Some(constant)) => k.specialised(kernel, constant | self.fit_pairs(opts))?,
                    (kernel, None) => k.pipeline(kernel)?,
                }
            };
            let (x, y) = grid(items);
            cmds.dispatch_pipeline(k, refit, &[set], bytemuck::bytes_of(&p), x, y);
            cmds.barrier();
            self.record_pairs(cmds, &p, opts)?;
        }
        cmds.timestamp("refit");
        Ok(())
    }

    /// Refits the last build's tree over the primitives as they are now (see
    /// [`Self::record_refit`]); returns its GPU nanoseconds.
    pub fn refit(&mut self, opts: BuildOptions) -> Result<f64> {
        let mut cmds = std::mem::replace(&mut self.cmds, Commands::none(&self.gpu));
        let r = (|| {
            cmds.begin()?;
            self.record_refit(&mut cmds, opts, false)?;
            cmds.submit_wait().context("running the BVH refit")?;
            cmds.timings()
        })();
        self.cmds = cmds;
        Ok(r?.iter().filter(|(l, _)| *l == "refit").map(|(_, ns)| ns).sum())
    }

    /// Builds the BVH of the uploaded primitives; returns each stage's GPU nanoseconds.
    pub fn build(&mut self, opts: BuildOptions, capture: bool) -> Result<Vec<(&'static str, f64)>> {
        self.run(opts, capture, true, 1)
    }

    /// Builds the BVH of the uploaded primitives with no timestamp between the stages;
    /// returns the GPU nanoseconds of the whole build.
    pub fn build_total(&mut self, opts: BuildOptions) -> Result<f64> {
        Ok(self.build_streamed(opts, 1)?.iter().sum())
    }

    /// Runs `count` builds back to back in one submission, keeping the GPU busy (see
    /// `bench::bench_build`'s warm-up).
    pub fn build_repeated(&mut self, opts: BuildOptions, count: usize) -> Result<()> {
        self.run(opts, false, false, count).map(|_| ())
    }

    /// Builds `count` times back to back in one submission, each between two timestamps (the
    /// renderer's case: no CPU wait between builds, the GPU's clocks up); returns each
    /// build's GPU nanoseconds. At most [`GpuLbvh::STREAM_MAX`] builds.
    pub fn build_streamed(&mut self, opts: BuildOptions, count: usize) -> Result<Vec<f64>> {
        anyhow::ensure!(
            count <= Self::STREAM_MAX,
            "at most {} streamed builds per submission",
            Self::STREAM_MAX
        );
        let t = self.run(opts, false, false, count)?;
        Ok(t.iter().filter(|(l, _)| *l == "build").map(|(_, ns)| *ns).collect())
    }

    /// Builds one submission can time back to back (two timestamps each).
    pub const STREAM_MAX: usize = super::MAX_TIMESTAMPS as usize / 2;

    /// Records `count` builds into one submission, runs it and returns its timings (the
    /// timestamps of the first builds, where there are more than the query pool holds).
    fn run(
        &mut self,
        opts: BuildOptions,
        capture: bool,
        stages: bool,
        count: usize,
    ) -> Result<Vec<(&'static str, f64)>> {
        self.reserve_room(opts)?;
        if let Some(b) = self.bufs.as_mut().filter(|b| capture && b.capture.is_none()) {
            b.capture = Some(Buffer::new(
                &self.gpu,
                "captured codes",
                b.capacity as u64 * 8,
                MemoryLocation::GpuOnly,
            )?);
        }
        let mut cmds = std::mem::replace(&mut self.cmds, Commands::none(&self.gpu));
        let r = (|| {
            cmds.begin()?;
            for _ in 0..count {
                self.record(&mut cmds, opts, capture, stages)?;
            }
            cmds.submit_wait().context("running the BVH build")?;
            cmds.timings()
        })();
        self.cmds = cmds;
        r
    }

    fn download<T: Pod>(&mut self, which: fn(&Buffers) -> &Buffer, count: usize) -> Result<Vec<T>> {
        let b = self.bufs.as_ref().context("no primitives uploaded")?;
        self.cmds.read_back(which(b), count)
    }

    /// The bounds buffer: the reduction's (empty between builds) and the last build's.
    pub fn bounds(&mut self) -> Result<[OrderedBounds; 2]> {
        let v = self.download::<OrderedBounds>(|b| &b.bounds, 2)?;
        Ok([v[0], v[1]])
    }

    /// The world-space primitives the last build ran on.
    pub fn primitives(&mut self) -> Result<(Vec<Triangle>, Vec<Sphere>)> {
        let (tris, spheres) = (self.n_tris as usize, (self.n - self.n_tris) as usize);
        Ok((
            self.download(|b| &b.tris, tris)?,
            self.download(|b| &b.spheres, spheres)?,
        ))
    }

    /// Reads back every stage's output of the last build (run it with `capture` to get the
    /// unsorted Morton codes; else they are empty).
    pub fn result(&mut self, opts: BuildOptions) -> Result<BuildResult> {
        let bits = opts.bits;
        let n = self.n as usize;
        let widen = |v: Vec<u32>| v.into_iter().map(u64::from).collect::<Vec<u64>>();
        let keys = |s: &mut Self, which: fn(&Buffers) -> &Buffer| -> Result<Vec<u64>> {
            match bits {
                MortonBits::B30 => Ok(widen(s.download::<u32>(which, n)?)),
                MortonBits::B63 => s.download::<u64>(which, n),
            }
        };
        let total = (2 * n).saturating_sub(1);
        // The tree's nodes and, where the build wrote them, its pairs: one read.
        let (nodes, pairs) = if opts.wide || !opts.pairs || n < 2 || !self.has_pairs() {
            (self.download(|b| &b.nodes, total)?, Vec::new())
        } else {
            let mut nodes: Vec<Node> = self.download(|b| &b.nodes, traverse::traced_nodes(n as u32) as usize)?;
            let pairs = nodes.split_off(traverse::pairs_at(n as u32) as usize);
            nodes.truncate(total);
            if self.fit_pairs(opts) != 0 {
                // The fit wrote the boxes of the leaves and of the nodes inside its blocks
                // into the pairs only.
                crate::bvh::boxes_from_pairs(&mut nodes, &pairs);
            }
            (nodes, pairs)
        };
        Ok(BuildResult {
            bounds: self
                .download::<OrderedBounds>(|b| &b.bounds, 2)?
                .get(1)
                .copied()
                .unwrap_or_default(),
            morton: if self.bufs.as_ref().is_some_and(|b| b.capture.is_some()) {
                keys(self, |b| b.capture.as_ref().unwrap_or(&b.keys_a))?
            } else {
                Vec::new()
            },
            sorted_keys: keys(self, |b| &b.keys_a)?,
            sorted_prims: self.download(|b| &b.vals_a, n)?,
            nodes,
            pairs,
            parents: self.download(|b| &b.parents, total)?,
            wide: if opts.wide && n > 0 {
                // The slots of binary nodes that root no wide node were never written.
                let mut wide = self.download(|b| &b.wide, wide::slots(n as u32) as usize)?;
                crate::bvh::clear_unreached(&mut wide);
                wide
            } else {
                Vec::new()
            },
        })
    }
}
