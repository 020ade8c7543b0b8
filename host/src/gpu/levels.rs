//! Both levels of an instanced scene on the GPU (`shared::instance`): every mesh's BVH built
//! once by the builder ([`GpuLbvh`]) and kept, with the meshes' model-space primitives, in
//! buffers of their own (what the tracers' set 0 names: [`GpuLevels::trace_set`]); the
//! top level built again whenever instances move, by the same builder over the instances'
//! world boxes (the `instance_bounds` kernel, which also reduces their bounds; a refit's
//! `instance_boxes`), its nodes written after the meshes' (in place where the device binds
//! the buffer from there, else copied). The same
//! [`LevelsLayout`] as the CPU executor's (`bvh::build_levels`), and the same bits.
use super::{BindingSets, Buffer, Commands, Gpu, GpuLbvh, Kernel, Kernels, BINDINGS};
use crate::bvh::{
    inverse_rows, layout, mesh_build, top_build, BuildOptions, LevelsLayout, MeshPrims, Placement, TOP_ROUNDS,
};
use anyhow::{anyhow, ensure, Context, Result};
use gpu_allocator::MemoryLocation;
use shared::instance::Instance;
use shared::types::{
    grid, item_groups, BuildParams, Node, Object, OrderedBounds, Sphere, Triangle, INVALID, RENDER_BINDINGS, WORKGROUP,
};
use std::sync::Arc;

pub struct GpuLevels {
    gpu: Arc<Gpu>,
    kernels: Arc<Kernels>,
    cmds: Commands,
    /// The top level's builder (its primitives: the instances' box triangles).
    top: GpuLbvh,
    layout: LevelsLayout,
    opts: BuildOptions,
    tris: Buffer,
    spheres: Buffer,
    /// Both levels' nodes: every mesh's, then the top level's from `layout.top`.
    nodes: Buffer,
    /// Host-visible, rewritten when instances move.
    objects: Buffer,
    instances: Buffer,
    /// Set 0 of the tracers (bindings 0, 1 and 8 the buffers above) and set 1 of
    /// `instance_boxes` (bindings 0 and 17); every other binding names `_empty`.
    trace: BindingSets,
    boxes: BindingSets,
    _empty: Buffer,
    /// Each mesh's [`MeshKey`] (what a later [`GpuLevels::keeping`] matches).
    keys: Vec<MeshKey>,
    /// Meshes whose BVH was built here, and those copied from the levels before.
    pub built: usize,
    pub kept: usize,
    /// Top-level refits since its last build (`None` before the first build), and how many
    /// the frames make between two builds.
    top_refits: Option<u32>,
    top_refits_max: u32,
    /// The top level built as a plain LBVH instead of [`top_build`]'s (`bench levels`).
    top_plain: bool,
    /// The top level's builder holds its last build's bounds (its `b[1]`), in which the next
    /// build codes the instances ([`GpuLbvh::record_instanced`]).
    top_bounds: bool,
    /// The top level's builder writes its nodes into `nodes` (`GpuLbvh::place_nodes`), else
    /// they are copied there after each build or refit.
    top_in_place: bool,
}

/// Frames that refit the top level (its instances' boxes taken again, the tree kept: the
/// counter refit of a restructured tree, `refit_restructured`) between two builds of it
/// (`bvh::top_build`: restructured by treelets), unless [`GpuLevels::set_top_refits`] says
/// otherwise. H100, `bench realtime --instancing on --nee`, two passes, built plain every
/// frame -> restructured and refit by 59: forest 7.94 -> 7.75 ms (NEE 10.02 -> 9.81; its p99
/// 8.03 -> 8.27, the frame of the build), herd 5.08 -> 4.99 (NEE 6.44 -> 6.35); refit by 15
/// the same medians; restructured every frame the forest's build took 0.63 ms (bench/NOTES.md,
/// session 34). The first `bvh::TOP_ROUNDS - 1` refits restructure it again (the build's
/// further rounds spread over frames: `bench realtime --frames 600`, p99 forest 9.17 -> 8.32
/// ms, herd 5.71 -> 5.27, sixteen bunnies 3.40 -> 3.15, medians unchanged; session 35).
pub const TOP_REFITS: u32 = 59;

/// What identifies a mesh's primitives: their counts and a hash of their bits.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
struct MeshKey {
    tris: usize,
    spheres: usize,
    hash: u64,
}

impl MeshKey {
    fn of(m: &MeshPrims) -> MeshKey {
        use std::hash::{Hash, Hasher};
        let mut h = std::hash::DefaultHasher::new();
        bytemuck::cast_slice::<_, u8>(&m.tris).hash(&mut h);
        bytemuck::cast_slice::<_, u8>(&m.spheres).hash(&mut h);
        MeshKey {
            tris: m.tris.len(),
            spheres: m.spheres.len(),
            hash: h.finish(),
        }
    }
}

impl GpuLevels {
    /// Lays out `placements` of `meshes` (errors name the instance, as `bvh::layout`'s),
    /// builds every mesh's BVH and the top level with `opts` (binary: the walk does not read
    /// the wide layout).
    pub fn new(
        gpu: &Arc<Gpu>,
        kernels: &Arc<Kernels>,
        meshes: &[MeshPrims],
        placements: &[Placement],
        opts: BuildOptions,
    ) -> Result<GpuLevels> {
        Self::keeping(None, gpu, kernels, meshes, placements, opts)
    }

    /// [`Self::new`], keeping the BVHs of `previous` (the levels of the scene before an edit:
    /// objects added, removed or moved): a mesh whose primitives have the same bits as one
    /// of `previous`'s, built with the same options, has its primitives and nodes copied
    /// over instead of built again. Adding an instance of a mesh the scene shows already, or
    /// removing one, builds no mesh: only the top level.
    pub fn keeping(
        previous: Option<&GpuLevels>,
        gpu: &Arc<Gpu>,
        kernels: &Arc<Kernels>,
        meshes: &[MeshPrims],
        placements: &[Placement],
        opts: BuildOptions,
    ) -> Result<GpuLevels> {
        let layout = layout(meshes, placements).map_err(|e| anyhow!(e))?;
        ensure!(!layout.instances.is_empty(), "an instanced scene of no instances");
        let opts = BuildOptions { wide: false, ..opts };
        let dev = |name: &str, bytes: u64| Buffer::new(gpu, name, bytes, MemoryLocation::GpuOnly);
        let host = |name: &str, bytes: u64| Buffer::new(gpu, name, bytes, MemoryLocation::CpuToGpu);
        let tris = dev("mesh triangles", layout.n_tris as u64 * size_of::<Triangle>() as u64)?;
        let spheres = dev("mesh spheres", layout.n_spheres as u64 * size_of::<Sphere>() as u64)?;
        let nodes = dev("both levels' nodes", layout.nodes() as u64 * size_of::<Node>() as u64)?;
        let objects = host("instanced objects", (layout.objects.len() * size_of::<Object>()) as u64)?;
        let instances = host("instances", (layout.instances.len() * size_of::<Instance>()) as u64)?;
        let empty = dev("empty binding", 16)?;
        let mut set0: Vec<&Buffer> = vec![&empty; BINDINGS];
        (set0[0], set0[1], set0[8]) = (&tris, &spheres, &nodes);
        let trace = BindingSets::new(gpu, kernels, 0, &[&set0])?;
        let mut set1: Vec<&Buffer> = vec![&empty; RENDER_BINDINGS as usize];
        (set1[0], set1[17]) = (&objects, &instances);
        let boxes = BindingSets::new(gpu, kernels, 1, &[&set1])?;
        let mut top = GpuLbvh::new(gpu, kernels)?;
        top.reserve(layout.instances.len(), 0)?;
        let top_in_place = top.place_nodes(&nodes, layout.top)?;
        let mut l = GpuLevels {
            gpu: gpu.clone(),
            kernels: kernels.clone(),
            cmds: Commands::new(gpu)?,
            top,
            layout,
            opts,
            tris,
            spheres,
            nodes,
            objects,
            instances,
            trace,
            boxes,
            _empty: empty,
            keys: meshes.iter().map(MeshKey::of).collect(),
            built: 0,
            kept: 0,
            top_refits: None,
            top_refits_max: TOP_REFITS,
            top_plain: false,
            top_bounds: false,
            top_in_place,
        };
        l.objects.write(&l.layout.objects)?;
        l.instances.write(&l.layout.instances)?;
        l.build_meshes(meshes, placements, previous.filter(|p| p.opts == opts))?;
        l.rebuild_top()?;
        Ok(l)
    }

    /// Every mesh's primitives and BVH into the bottom level: copied from `previous` where
    /// it holds the same mesh, else built (one build each, as [`mesh_build`] says).
    fn build_meshes(
        &mut self,
        meshes: &[MeshPrims],
        placements: &[Placement],
        previous: Option<&GpuLevels>,
    ) -> Result<()> {
        let old: std::collections::HashMap<MeshKey, usize> = previous
            .map(|p| p.keys.iter().enumerate().map(|(j, k)| (*k, j)).collect())
            .unwrap_or_default();
        let mut builder = None;
        for (m, mesh) in meshes.iter().enumerate() {
            let n = mesh.tris.len() + mesh.spheres.len();
            if n == 0 {
                continue;
            }
            // Where the mesh's primitives and nodes come from: the levels before, or a build.
            let (from, src) = match (previous, old.get(&self.keys[m])) {
                (Some(p), Some(&j)) => {
                    self.kept += 1;
                    let l = &p.layout;
                    let from = (l.mesh_tris[j], l.mesh_spheres[j], l.mesh_nodes[j]);
                    (from, (&p.tris, &p.spheres, &p.nodes))
                }
                _ => {
                    self.built += 1;
                    let b = match &mut builder {
                        Some(b) => b,
                        None => builder.insert(GpuLbvh::new(&self.gpu, &self.kernels)?),
                    };
                    b.upload(&mesh.tris, &mesh.spheres)?;
                    b.build(mesh_build(placements, m, self.opts), false)?;
                    ((0, 0, 0), b.buffers()?)
                }
            };
            let (tri, sphere) = (size_of::<Triangle>() as u64, size_of::<Sphere>() as u64);
            let node = size_of::<Node>() as u64;
            self.cmds.begin()?;
            let c = &self.cmds;
            c.copy_range(
                src.0,
                from.0 as u64 * tri,
                &self.tris,
                self.layout.mesh_tris[m] as u64 * tri,
                mesh.tris.len() as u64 * tri,
            );
            c.copy_range(
                src.1,
                from.1 as u64 * sphere,
                &self.spheres,
                self.layout.mesh_spheres[m] as u64 * sphere,
                mesh.spheres.len() as u64 * sphere,
            );
            c.copy_range(
                src.2,
                from.2 as u64 * node,
                &self.nodes,
                self.layout.mesh_nodes[m] as u64 * node,
                (2 * n as u64 - 1) * node,
            );
            c.barrier();
            self.cmds.submit_wait().context("copying a mesh's BVH")?;
        }
        Ok(())
    }

    /// New transforms of the objects (model to world, 3x4 row-major, by object number): every
    /// instance moves with its object; the top level is built again by the next
    /// [`Self::record_top`]. A transform that cannot be inverted is refused by the instance's
    /// and the object's number, and nothing changes.
    pub fn set_transforms(&mut self, rows: &[[[f32; 4]; 3]]) -> Result<()> {
        // Inverted again only where moved: most of a large scene's instances stand still.
        let mut moved = Vec::new();
        for (k, inst) in self.layout.instances.iter().enumerate() {
            if inst.object == INVALID {
                continue;
            }
            let o = inst.object as usize;
            let rows = *rows
                .get(o)
                .with_context(|| format!("instance {k} shows object {o}, and {} transforms are given", rows.len()))?;
            if self.layout.objects[o].rows != rows {
                let inv = inverse_rows(&rows).map_err(|e| anyhow!("instance {k} (object {o}): {e}"))?;
                moved.push((k, o, rows, inv));
            }
        }
        for (k, o, rows, inv) in moved {
            self.layout.instances[k].to_model = inv;
            self.layout.objects[o].rows = rows;
        }
        self.objects.write(&self.layout.objects)?;
        self.instances.write(&self.layout.instances)
    }

    /// Records the copy of a mixed scene's world-space group, just built by `builder` over
    /// its `n` world-space triangles (`n > 0`), into the bottom level: its triangles and
    /// nodes where the layout put mesh 0 (the group's, shown by instance 0), its root box as
    /// instance 0's model box. The top level's build ([`Self::record_top`]) follows.
    pub fn record_world(&self, cmds: &mut Commands, builder: &GpuLbvh, n: u32) -> Result<()> {
        let (b_tris, _, b_nodes) = builder.buffers()?;
        let (tri, node) = (size_of::<Triangle>() as u64, size_of::<Node>() as u64);
        let n = n as u64;
        cmds.copy_range(b_tris, 0, &self.tris, self.layout.mesh_tris[0] as u64 * tri, n * tri);
        let first = self.layout.mesh_nodes[0] as u64 * node;
        cmds.copy_range(b_nodes, 0, &self.nodes, first, (2 * n - 1) * node);
        // The root's `min` and `max` (bytes 0..12, 16..28 of a node) as the instance's `lo`
        // and `hi` (bytes 48..60, 64..76).
        cmds.copy_range(b_nodes, 0, &self.instances, 48, 12);
        cmds.copy_range(b_nodes, 16, &self.instances, 64, 12);
        cmds.barrier();
        cmds.timestamp("group copy");
        Ok(())
    }

    /// Records the copy of a mixed scene's world-space group's `n` triangles, just
    /// transformed into `builder`'s world buffer, to where the layout put mesh 0 (the driver
    /// tracer builds its own structure over them; [`Self::record_world`] for the project's).
    pub fn record_world_tris(&self, cmds: &mut Commands, builder: &GpuLbvh, n: u32) -> Result<()> {
        let (b_tris, _, _) = builder.buffers()?;
        let tri = size_of::<Triangle>() as u64;
        cmds.copy_range(
            b_tris,
            0,
            &self.tris,
            self.layout.mesh_tris[0] as u64 * tri,
            n as u64 * tri,
        );
        cmds.barrier();
        Ok(())
    }

    /// The meshes' model-space triangles (set 0's binding 0 of the tracers).
    pub fn triangles(&self) -> &Buffer {
        &self.tris
    }

    /// Records the top level's update into `cmds` (which must be recording): the instances'
    /// world boxes, then the build over them ([`top_build`]) or, the [`TOP_REFITS`] frames
    /// after one, a refit of its tree (the first [`TOP_ROUNDS`]` - 1` restructuring it again);
    /// its nodes copied after the meshes'.
    pub fn record_top(&mut self, cmds: &mut Commands) -> Result<()> {
        let n = self.layout.instances.len() as u32;
        let p = BuildParams {
            n_tris: n,
            n,
            ..Default::default()
        };
        let sets = [self.top.set()?, self.boxes.sets[0]];
        let top = if self.top_plain {
            BuildOptions::lbvh(self.opts.bits)
        } else {
            top_build(self.opts)
        };
        let refit = matches!(self.top_refits, Some(r) if r < self.top_refits_max);
        // A build after the first, sorted by merging, makes the boxes in its runs kernel and
        // codes them in the last build's bounds (this build's are reduced for the next).
        if !refit && self.top_bounds && self.top.merges(top.bits) {
            self.top.record_instanced(cmds, top, false, sets[1])?;
            self.top_refits = Some(0);
        } else {
            // Else the boxes first, a build taking their bounds in the same kernel; a refit
            // keeps the tree (and the bounds' reduction untouched: the next build's starts
            // empty).
            let (kernel, groups) = if refit {
                (Kernel::InstanceBoxes, n.div_ceil(WORKGROUP))
            } else {
                (Kernel::InstanceBounds, item_groups(n))
            };
            let (x, y) = grid(groups);
            cmds.dispatch_sets(&self.kernels, &sets, kernel, bytemuck::bytes_of(&p), x, y)?;
            cmds.barrier();
            // Every interval a frame's timings report ends at a named timestamp (the
            // builder's follow this one).
            cmds.timestamp("top level");
            self.record_top_update(cmds, top, refit)?;
        }
        self.top_bounds = true;
        if !self.top_in_place {
            let (_, _, top_nodes) = self.top.buffers()?;
            let node = size_of::<Node>() as u64;
            cmds.copy_range(
                top_nodes,
                0,
                &self.nodes,
                self.layout.top as u64 * node,
                (2 * n as u64 - 1) * node,
            );
            cmds.barrier();
            cmds.timestamp("top level");
        }
        Ok(())
    }

    /// The top level's build or refit after its instances' boxes.
    fn record_top_update(&mut self, cmds: &mut Commands, top: BuildOptions, refit: bool) -> Result<()> {
        match self.top_refits {
            Some(r) if refit => {
                // The first `TOP_ROUNDS - 1` refits after a build restructure it again.
                let again = top.restructures() && r + 1 < TOP_ROUNDS;
                self.top.record_refit(cmds, top, again)?;
                self.top_refits = Some(r + 1);
            }
            _ => {
                self.top.record_bounded(cmds, top, false)?;
                self.top_refits = Some(0);
            }
        }
        Ok(())
    }

    /// Frames that refit the top level between two builds of it ([`TOP_REFITS`] unless set;
    /// 0 builds it every frame).
    pub fn set_top_refits(&mut self, refits: u32) {
        self.top_refits_max = refits;
    }

    /// Builds the top level as a plain LBVH (Karras's tree and the fit, no treelets) from the
    /// next update on, or again as [`top_build`] says (what the CPU executor's levels do):
    /// `bench levels` times both.
    pub fn set_top_plain(&mut self, plain: bool) {
        self.top_plain = plain;
        self.top_refits = None;
    }

    /// The next update of the top level builds it (instead of refitting it), coding the
    /// instances in their own bounds as the CPU executor's levels do (not the last build's).
    pub fn build_top_next(&mut self) {
        self.top_refits = None;
        self.top_bounds = false;
    }

    /// The bounds the next build of the top level codes its instances in when it takes the
    /// last build's ([`GpuLbvh::record_instanced`]; `None` when it reduces its own): what
    /// the CPU executor's build needs to equal it (`cpu::build_coded`).
    pub fn top_code_bounds(&mut self) -> Result<Option<OrderedBounds>> {
        let n = self.layout.instances.len() as u32;
        if !self.top_bounds || !self.top.merges(self.opts.bits) || n == 0 {
            return Ok(None);
        }
        Ok(Some(self.top.bounds()?[1]))
    }

    /// Top-level refits since its last build (`None` before the first).
    pub fn top_refits(&self) -> Option<u32> {
        self.top_refits
    }

    /// Brings the top level up to date as a frame does ([`Self::record_top`]: built, or
    /// refit); returns its GPU milliseconds (boxes, build or refit, and copy: every interval
    /// of the submission).
    pub fn rebuild_top(&mut self) -> Result<f64> {
        let mut cmds = Commands::new(&self.gpu)?;
        cmds.begin()?;
        cmds.timestamp("begin");
        self.record_top(&mut cmds)?;
        cmds.submit_wait().context("building the top level")?;
        Ok(cmds.timings()?.iter().map(|(_, ns)| ns * 1e-6).sum())
    }

    /// Both levels' nodes (every mesh's, then the top level's from `layout().top`).
    pub fn nodes(&mut self) -> Result<Vec<Node>> {
        self.cmds.read_back(&self.nodes, self.layout.nodes() as usize)
    }

    /// The meshes' model-space primitives.
    pub fn primitives(&mut self) -> Result<(Vec<Triangle>, Vec<Sphere>)> {
        let (t, s) = (self.layout.n_tris as usize, self.layout.n_spheres as usize);
        Ok((
            self.cmds.read_back(&self.tris, t)?,
            self.cmds.read_back(&self.spheres, s)?,
        ))
    }

    /// The top level's inputs: each instance's world box as a box triangle.
    pub fn boxes(&mut self) -> Result<Vec<Triangle>> {
        Ok(self.top.primitives()?.0)
    }

    pub fn layout(&self) -> &LevelsLayout {
        &self.layout
    }

    /// Set 0 of the tracers: the meshes' primitives and both levels' nodes.
    pub fn trace_set(&self) -> ash::vk::DescriptorSet {
        self.trace.sets[0]
    }

    /// The instances (render binding 17), rewritten by [`Self::set_transforms`].
    pub fn instances(&self) -> &Buffer {
        &self.instances
    }

    /// Device bytes of both levels: the meshes' primitives and nodes, the instances and the
    /// top level's builder.
    pub fn memory(&self) -> u64 {
        let (top_nodes, top_rest) = self.top.memory();
        self.tris.size
            + self.spheres.size
            + self.nodes.size
            + self.objects.size
            + self.instances.size
            + top_nodes
            + top_rest
    }
}
