//! Two-level BVHs (instancing, `shared::instance`): every mesh's own BVH in its model space
//! (the bottom level), and a top-level BVH over the instances' world boxes, both made by the
//! one builder. The CPU executor builds them here; `validate_levels` checks both.
use super::{validate, BuildOptions};
use shared::glam::{DMat3, DVec3, Vec3};
use shared::instance::{instance_box, Instance, IDENTITY};
use shared::traverse::Scene;
use shared::types::{prim_box, Node, Object, OrderedBounds, Sphere, Triangle, FEATURE_INSTANCES, INVALID};

/// A mesh's primitives in its model space.
#[derive(Clone, Debug, Default)]
pub struct MeshPrims {
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
}

/// An instance: which mesh, shown by which object, placed by which transform (model to
/// world, 3x4 row-major). An instance of no object ([`INVALID`]) is the world-space group
/// of a mixed scene ([`Placement::world`]): its mesh is in world space, its `rows`
/// [`IDENTITY`] (what the `instance_boxes` kernel places it by).
#[derive(Copy, Clone, Debug)]
pub struct Placement {
    pub mesh: usize,
    pub object: u32,
    pub rows: [[f32; 4]; 3],
}

impl Placement {
    /// The world-space group: mesh `mesh`, in world space.
    pub fn world(mesh: usize) -> Placement {
        Placement {
            mesh,
            object: INVALID,
            rows: IDENTITY,
        }
    }
}

/// Both levels: the meshes' primitives and BVHs one after another (bottom level), the
/// instances and the BVH over their world boxes (top level).
#[derive(Clone, Debug, Default)]
pub struct Levels {
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
    /// Every mesh's BVH, each numbered from 0, at its instances' `nodes`, then the top
    /// level's from `top`.
    pub nodes: Vec<Node>,
    pub top: u32,
    pub instances: Vec<Instance>,
    /// The objects the instances show, by object number (here only their transforms, what
    /// the top level's boxes are made from).
    pub objects: Vec<Object>,
    /// The top level's inputs: each instance's world box as a degenerate triangle.
    pub boxes: Vec<Triangle>,
    pub top_parents: Vec<u32>,
    /// Each mesh's first node, and the parents of its BVH (for the validator).
    pub mesh_nodes: Vec<u32>,
    pub mesh_parents: Vec<Vec<u32>>,
}

impl Levels {
    /// The top level's nodes.
    pub fn top_nodes(&self) -> &[Node] {
        &self.nodes[self.top as usize..]
    }

    /// The scene the traversal walks, with `features` (plus [`FEATURE_INSTANCES`]).
    pub fn scene(&self, features: u32) -> Scene<'_> {
        Scene {
            tris: bytemuck::cast_slice(&self.tris),
            spheres: &self.spheres,
            nodes: bytemuck::cast_slice(&self.nodes),
            wide: &[],
            order: &[],
            n_tris: self.tris.len() as u32,
            n_prims: (self.tris.len() + self.spheres.len()) as u32,
            top: self.top,
            instances: &self.instances,
            n_instances: self.instances.len() as u32,
            coverage: shared::alpha::Coverage::NONE,
            features: features | FEATURE_INSTANCES,
        }
    }
}

/// The inverse of the affine transform `rows` (3x4, row-major), computed in f64 and rounded;
/// an error names what makes it unusable (a non-finite entry, a singular matrix).
pub fn inverse_rows(rows: &[[f32; 4]; 3]) -> Result<[[f32; 4]; 3], String> {
    if rows.iter().flatten().any(|x| !x.is_finite()) {
        return Err(format!("its transform has a non-finite entry: {rows:?}"));
    }
    let col = |c: usize| DVec3::new(rows[0][c] as f64, rows[1][c] as f64, rows[2][c] as f64);
    let m = DMat3::from_cols(col(0), col(1), col(2));
    let det = m.determinant();
    // Singular relative to the matrix's scale (a zero scale, two equal axes).
    let scale = col(0).length() * col(1).length() * col(2).length();
    if det.abs() <= 1e-12 * scale || scale == 0.0 {
        return Err(format!("its transform is singular (determinant {det:e}): {rows:?}"));
    }
    let inv = m.inverse();
    let t = -(inv * col(3));
    let mut out = [[0f32; 4]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        let v = inv.row(r);
        *row = [v.x as f32, v.y as f32, v.z as f32, t[r] as f32];
    }
    Ok(out)
}

/// The box of primitives `prims` of a mesh.
fn mesh_box(m: &MeshPrims) -> (Vec3, Vec3) {
    let n_tris = m.tris.len() as u32;
    (0..n_tris + m.spheres.len() as u32).fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), i| {
        let (a, b) = prim_box(i, n_tris, &m.tris, &m.spheres);
        (lo.min(a), hi.max(b))
    })
}

/// Where an instanced scene's data goes, whichever backend builds it: each mesh's first
/// node (a mesh of `m` primitives has `2m - 1`; [`INVALID`] for an empty mesh), triangle
/// and sphere in the bottom level's buffers, the instances and the objects they show
/// (their transforms, by object number), and the top level's first node (after every
/// mesh's).
#[derive(Clone, Debug, Default)]
pub struct LevelsLayout {
    pub mesh_nodes: Vec<u32>,
    pub mesh_tris: Vec<u32>,
    pub mesh_spheres: Vec<u32>,
    pub instances: Vec<Instance>,
    pub objects: Vec<Object>,
    pub top: u32,
    pub n_tris: u32,
    pub n_spheres: u32,
}

impl LevelsLayout {
    /// Nodes of both levels.
    pub fn nodes(&self) -> u32 {
        self.top + (2 * self.instances.len() as u32).saturating_sub(1)
    }
}

/// An instance [`layout`] cannot place, and why.
#[derive(Clone, Debug, PartialEq)]
pub struct LayoutError {
    pub instance: usize,
    pub problem: String,
}

impl std::fmt::Display for LayoutError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "instance {}: {}", self.instance, self.problem)
    }
}

/// The [`LevelsLayout`] of `placements` of `meshes`. Errors name the instance and its problem: a
/// mesh that does not exist or is empty, a transform that cannot be inverted.
pub fn layout(meshes: &[MeshPrims], placements: &[Placement]) -> Result<LevelsLayout, LayoutError> {
    let mut l = LevelsLayout::default();
    let mut boxes = Vec::with_capacity(meshes.len());
    for m in meshes {
        let n = (m.tris.len() + m.spheres.len()) as u32;
        l.mesh_nodes.push(if n == 0 { INVALID } else { l.top });
        l.mesh_tris.push(l.n_tris);
        l.mesh_spheres.push(l.n_spheres);
        boxes.push(mesh_box(m));
        l.top += (2 * n).saturating_sub(1);
        l.n_tris += m.tris.len() as u32;
        l.n_spheres += m.spheres.len() as u32;
    }
    for (k, p) in placements.iter().enumerate() {
        let Some(m) = meshes.get(p.mesh) else {
            return Err(LayoutError {
                instance: k,
                problem: format!("it shows mesh {}, and there are {} meshes", p.mesh, meshes.len()),
            });
        };
        if m.tris.is_empty() && m.spheres.is_empty() {
            return Err(LayoutError {
                instance: k,
                problem: format!("it shows mesh {}, which has no primitives", p.mesh),
            });
        }
        let to_model = inverse_rows(&p.rows).map_err(|problem| LayoutError { instance: k, problem })?;
        let (lo, hi) = boxes[p.mesh];
        l.instances.push(Instance {
            to_model,
            lo: lo.to_array(),
            object: p.object,
            hi: hi.to_array(),
            nodes: l.mesh_nodes[p.mesh],
            tri0: l.mesh_tris[p.mesh],
            n_tris: m.tris.len() as u32,
            sphere0: l.mesh_spheres[p.mesh],
            n_spheres: m.spheres.len() as u32,
        });
        if p.object != INVALID {
            let o = p.object as usize;
            if l.objects.len() <= o {
                l.objects.resize(o + 1, Object::default());
            }
            l.objects[o].rows = p.rows;
        }
    }
    Ok(l)
}

/// How both backends build the top level in two levels whose frames build with `opts`:
/// restructured by treelets in one round; the frames after a build restructure it again
/// while they refit it, [`TOP_ROUNDS`] rounds in all (`GpuLevels::record_top`, `TOP_REFITS`).
/// H100: one round took the forest's frame 7.94 -> 7.78 ms (NEE 10.02 -> 9.85), three 7.64
/// (9.69), herd's the same; a build of 10,000 instances 0.51 ms, in three rounds 1.42 (its
/// frame's p99: 8.32 -> 9.17 ms), once every 60 frames (bench/NOTES.md, session 34): the
/// rounds spread over three frames instead (session 35).
pub fn top_build(opts: BuildOptions) -> BuildOptions {
    BuildOptions {
        wide: false,
        treelets: true,
        rounds: 1,
        ploc: false,
        pairs: false,
        ..opts
    }
}

/// Rounds of treelet restructuring the top level gets: its build's, then one in each of the
/// next `TOP_ROUNDS - 1` frames' refits (`GpuLbvh::record_refit` with `again`; fewer where the
/// frames build it again sooner, `--top-refits`).
pub const TOP_ROUNDS: u32 = 3;

/// Rounds of treelet restructuring of the meshes built once (`BuildOptions::rounds`): 3
/// against 1 lowered the surface-area cost of the bunny's tree 35.9 -> 34.8 and the forest's
/// canopy's 44.2 -> 43.2 (4: 34.7, 43.2), and took the two-level frames on the H100 0.7-1.0%
/// faster (`bench realtime --instancing on --nee`, two passes: forest 8.02 -> 7.95 ms, NEE 10.12
/// -> 10.03; herd 5.14 -> 5.10, 6.52 -> 6.48; sixteen bunnies 3.11 -> 3.08, 4.34 -> 4.30;
/// bench/NOTES.md, session 34), for two more refits' time each at load (a few ms).
pub const MESH_ROUNDS: u32 = 3;

/// How both backends build mesh `mesh`'s BVH in two levels whose frames build with `opts`:
/// binary (the two-level walk does not read the wide layout); the world-space group's, built
/// (or refit: `GpuLbvh::record_refit`) every frame, as the frame's; every other mesh's, built once when the scene is loaded
/// and traced by every frame after, restructured by treelets in [`MESH_ROUNDS`] rounds whatever the frame asks (H100,
/// `bench realtime --instancing on`: the herd's, the sixteen bunnies' and the forest's frames
/// 5% faster; bench/NOTES.md, session 29).
pub fn mesh_build(placements: &[Placement], mesh: usize, opts: BuildOptions) -> BuildOptions {
    let group = placements.iter().any(|p| p.mesh == mesh && p.object == INVALID);
    BuildOptions {
        wide: false,
        treelets: opts.treelets || !group,
        rounds: if group { opts.rounds } else { MESH_ROUNDS },
        ploc: opts.ploc && group,
        pairs: false,
        ..opts
    }
}

/// Builds both levels on the CPU executor with `opts` (the meshes as [`mesh_build`] says, the
/// top level as [`top_build`] does),
/// in the [`layout`] of `placements`, whose errors it returns.
pub fn build_levels(meshes: &[MeshPrims], placements: &[Placement], opts: BuildOptions) -> Result<Levels, String> {
    build_levels_coded(meshes, placements, opts, None)
}

/// [`build_levels`] with the top level's Morton codes taken in `top_code_bounds` where given
/// (`cpu::build_coded`): the GPU's levels from the top level's second build on
/// (`GpuLevels::top_code_bounds`).
pub fn build_levels_coded(
    meshes: &[MeshPrims],
    placements: &[Placement],
    opts: BuildOptions,
    top_code_bounds: Option<&OrderedBounds>,
) -> Result<Levels, String> {
    let layout = layout(meshes, placements).map_err(|e| e.to_string())?;
    let opts = BuildOptions { wide: false, ..opts };
    let mut l = Levels {
        mesh_nodes: layout.mesh_nodes.clone(),
        top: layout.top,
        instances: layout.instances,
        objects: layout.objects,
        ..Default::default()
    };
    for (k, m) in meshes.iter().enumerate() {
        if m.tris.is_empty() && m.spheres.is_empty() {
            l.mesh_parents.push(Vec::new());
            continue;
        }
        let r = crate::cpu::build(&m.tris, &m.spheres, mesh_build(placements, k, opts)).0;
        l.nodes.extend_from_slice(&r.nodes);
        l.mesh_parents.push(r.parents);
        l.tris.extend_from_slice(&m.tris);
        l.spheres.extend_from_slice(&m.spheres);
    }
    debug_assert_eq!(l.nodes.len() as u32, l.top);
    // The top level's inputs, by the kernel the GPU runs.
    let n = l.instances.len() as u32;
    l.boxes = vec![Triangle::default(); l.instances.len()];
    for i in 0..n {
        instance_box(i, n, &l.instances, &l.objects, &mut l.boxes);
    }
    if !l.boxes.is_empty() {
        let r = crate::cpu::build_coded(&l.boxes, &[], top_build(opts), top_code_bounds).0;
        l.nodes.extend_from_slice(&r.nodes);
        l.top_parents = r.parents;
    }
    Ok(l)
}

/// Checks both levels: every mesh's BVH and the top level (the validator's checks: every
/// box holds its subtree, every primitive in one leaf), and that every instance's world box
/// holds its mesh's vertices (and its spheres' boxes) taken to world space.
pub fn validate_levels(l: &Levels, meshes: &[MeshPrims], placements: &[Placement]) -> Result<(), String> {
    for (m, mesh) in meshes.iter().enumerate() {
        let first = l.mesh_nodes[m];
        if first == INVALID {
            continue;
        }
        let n = mesh.tris.len() + mesh.spheres.len();
        let nodes = &l.nodes[first as usize..first as usize + 2 * n - 1];
        validate(nodes, &l.mesh_parents[m], &mesh.tris, &mesh.spheres).map_err(|e| format!("mesh {m}'s BVH: {e}"))?;
    }
    if !l.boxes.is_empty() {
        validate(l.top_nodes(), &l.top_parents, &l.boxes, &[]).map_err(|e| format!("the top level: {e}"))?;
    }
    for (k, (p, b)) in placements.iter().zip(&l.boxes).enumerate() {
        let (lo, hi) = prim_box(0, 1, std::slice::from_ref(b), &[]);
        let mesh = &meshes[p.mesh];
        // Triangles' vertices, and the corners of spheres' boxes (which hold the sphere under
        // any transform).
        let vertices = mesh
            .tris
            .iter()
            .flat_map(|t| [t.v0, t.v1, t.v2])
            .map(|v| Vec3::new(v[0], v[1], v[2]));
        let n_tris = mesh.tris.len() as u32;
        let sphere_corners = (0..mesh.spheres.len() as u32).flat_map(|i| {
            let (a, b) = prim_box(n_tris + i, n_tris, &mesh.tris, &mesh.spheres);
            (0..8).map(move |c| Vec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), b, a))
        });
        for c in vertices.chain(sphere_corners) {
            let w = DVec3::from_array(std::array::from_fn(|r| {
                let q = p.rows[r];
                q[0] as f64 * c.x as f64 + q[1] as f64 * c.y as f64 + q[2] as f64 * c.z as f64 + q[3] as f64
            }));
            if w.cmplt(lo.as_dvec3()).any() || w.cmpgt(hi.as_dvec3()).any() {
                return Err(format!(
                    "instance {k}'s world box [{lo}, {hi}] does not hold its point at {w}"
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::MortonBits;

    #[test]
    fn meshes_built_once_are_restructured_and_the_group_builds_as_the_frame() {
        let placed = Placement {
            mesh: 1,
            object: 0,
            rows: IDENTITY,
        };
        let placements = [Placement::world(0), placed];
        let frame = BuildOptions::wide(MortonBits::B30);
        let group = mesh_build(&placements, 0, frame);
        assert!(!group.treelets && !group.wide, "{group:?}");
        let mesh = mesh_build(&placements, 1, frame);
        assert!(mesh.treelets && !mesh.wide, "{mesh:?}");
        let restructuring = BuildOptions {
            treelets: true,
            ..frame
        };
        assert!(mesh_build(&placements, 0, restructuring).treelets);
    }
}
