//! What a BVH build produces, on either backend, the choice of Morton code width, and the
//! check that a built BVH is sound (`validate`).
mod levels;
mod validate;

pub use levels::{
    build_levels, build_levels_coded, inverse_rows, layout, mesh_build, top_build, validate_levels, LayoutError,
    Levels, LevelsLayout, MeshPrims, Placement, TOP_ROUNDS,
};
pub use validate::{validate, validate_wide, BvhStats, WideStats};

use shared::traverse;
use shared::types::{Node, OrderedBounds, INVALID};
use shared::wide::WideNode;

/// Morton code width: 30 bits in `u32` keys (Karras 2012) or 63 bits in `u64` keys.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub enum MortonBits {
    B30,
    B63,
}

impl MortonBits {
    pub fn key_bits(self) -> u32 {
        match self {
            MortonBits::B30 => 30,
            MortonBits::B63 => 63,
        }
    }
}

/// How a BVH is built: the Morton code width; whether the refit also restructures treelets
/// for surface-area cost (`shared::treelet`; Karras & Aila 2013), which makes the build
/// slower and the tree cheaper to trace; and whether the binary tree is then collapsed into
/// the 4-wide BVH that the tracer walks instead (`shared::wide`). The collapse needs the
/// Karras tree's key ranges, so a wide build never restructures treelets.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BuildOptions {
    pub bits: MortonBits,
    pub treelets: bool,
    pub wide: bool,
    /// Rounds of treelet restructuring (with `treelets`): the refit's own, then each further
    /// one a refit of the restructured tree that restructures it again (its counters all
    /// device-scope: `shared::refit::refit` without `BLOCKS`).
    pub rounds: u32,
    /// The tree and its boxes built by H-PLOC (`shared::ploc`: agglomerative clustering
    /// within the radix tree's subtrees, one dispatch) instead of the Karras kernel and the
    /// fit. Not with `wide` (the collapse needs the Karras tree's key ranges), and never
    /// restructured by treelets.
    pub ploc: bool,
    /// Each internal node's children copied as one 64-byte pair after the tree, which the
    /// binary walk then reads a step instead of the node's links and each child
    /// (`shared::traverse::write_pairs`); without them the walk reads the tree alone
    /// (`VARIANT_NO_PAIRS`). A pass over the tree at every build, and the node bytes doubled
    /// (see `cli::Pairs` for when they pay).
    pub pairs: bool,
}

impl BuildOptions {
    /// The thesis's build: Karras 2012 and a plain refit.
    pub fn lbvh(bits: MortonBits) -> BuildOptions {
        BuildOptions {
            bits,
            treelets: false,
            wide: false,
            rounds: 1,
            ploc: false,
            pairs: true,
        }
    }

    /// The binary LBVH collapsed into the 4-wide BVH.
    pub fn wide(bits: MortonBits) -> BuildOptions {
        BuildOptions {
            wide: true,
            ..BuildOptions::lbvh(bits)
        }
    }

    /// Whether the refit restructures treelets (never for a wide or an H-PLOC build).
    pub fn restructures(&self) -> bool {
        self.treelets && !self.wide && !self.ploc
    }

    /// Whether H-PLOC builds the tree (never for a wide build).
    pub fn builds_ploc(&self) -> bool {
        self.ploc && !self.wide
    }

    /// Whether a refit of the tree is the counter refit (`refit_restructured`): the tree has
    /// no Karras leaf ranges for the build's fit (restructured, or built by H-PLOC).
    pub fn counter_refit(&self) -> bool {
        self.restructures() || self.builds_ploc()
    }
}

/// How a build sorts its Morton keys, by their number and width (both backends alike).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Sort {
    /// Runs sorted by workgroups, then merged (`shared::merge_sort`), at most its `max`;
    /// one run (at most `RUN` keys) needs no merge.
    Merge,
    /// The radix passes (`shared::radix_sort`).
    Radix,
}

impl Sort {
    /// The sort of `n` keys of width `bits` (the threshold measured on the H100: see
    /// `shared::merge_sort::max`).
    pub fn of(n: u32, bits: MortonBits) -> Sort {
        if n <= shared::merge_sort::max(bits.key_bits()) {
            Sort::Merge
        } else {
            Sort::Radix
        }
    }

    /// The build parameters' `passes`: the radix passes' number, else zero.
    pub fn passes(self, bits: MortonBits) -> u32 {
        match self {
            Sort::Radix => shared::radix_sort::passes(bits.key_bits()),
            Sort::Merge => 0,
        }
    }
}

/// Which BVH the tracer walks (`--bvh`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum Layout {
    /// The binary LBVH: 32-byte nodes, one primitive per leaf.
    Binary,
    /// The 4-wide BVH collapsed from it every build: 128-byte nodes holding their children's
    /// boxes, up to two primitives per leaf.
    Wide,
}

/// Every stage's output of one build, for comparing backends and validating.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildResult {
    pub bounds: OrderedBounds,
    /// Morton code of each primitive, in primitive order (widened to `u64`).
    pub morton: Vec<u64>,
    /// Codes after the sort.
    pub sorted_keys: Vec<u64>,
    /// Primitive of each sorted position.
    pub sorted_prims: Vec<u32>,
    /// Internal nodes `0..n-1`, then leaves.
    pub nodes: Vec<Node>,
    pub parents: Vec<u32>,
    /// The wide BVH (wide builds only): a slot per binary internal node, wide node `i`
    /// rooted at binary node `i` (the root at 0), the slots no wide node takes empty
    /// ([`clear_unreached`]).
    pub wide: Vec<WideNode>,
    /// Binary builds of two or more primitives: each internal node's pair, its two children
    /// as the binary walk reads them (`shared::traverse::write_pairs`), node `i`'s at
    /// `2 i` and `2 i + 1`.
    pub pairs: Vec<Node>,
}

impl BuildResult {
    /// The nodes a flattened scene's binary walk reads (`shared::traverse::traced_nodes`):
    /// the tree's, a node of padding and the pairs, as the GPU's node buffer holds them.
    pub fn traced_nodes(&self) -> Vec<Node> {
        let mut nodes = self.nodes.clone();
        if !self.pairs.is_empty() {
            nodes.push(Node::default());
            nodes.extend_from_slice(&self.pairs);
        }
        nodes
    }
}

/// Empties the slots of `wide` that no wide node takes (those not reached from the root),
/// which the GPU's collapse never writes (`shared::wide`): a build's result holds its tree
/// and nothing left from an earlier one.
pub fn clear_unreached(wide: &mut [WideNode]) {
    use shared::wide::{LEAF, WIDTH};
    let mut reached = vec![false; wide.len()];
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        match reached.get_mut(i) {
            Some(r) if !*r => *r = true,
            _ => continue,
        }
        let w = &wide[i];
        stack.extend(
            (0..WIDTH)
                .map(|k| w.child[k])
                .filter(|&c| c != INVALID && c & LEAF == 0)
                .map(|c| c as usize),
        );
    }
    for (w, _) in wide.iter_mut().zip(reached).filter(|(_, r)| !r) {
        *w = WideNode::EMPTY;
    }
}

/// Completes the tree `nodes` of a fit that wrote the boxes of the leaves and of the nodes
/// inside its blocks into their parents' pairs only (`shared::refit::FIT_PAIRS`): each
/// child's box (and a leaf's primitive) copied back from its entry in `pairs`, so that the
/// build's result holds the whole tree, as a fit without it writes it.
pub fn boxes_from_pairs(nodes: &mut [Node], pairs: &[Node]) {
    let first_leaf = nodes.len() / 2;
    for e in pairs {
        let Some(node) = nodes.get_mut(e.a as usize) else {
            continue;
        };
        (node.min, node.max) = (e.min, e.max);
        if e.a as usize >= first_leaf {
            (node.a, node.b) = (e.b, INVALID);
        }
    }
}

/// The pairs a build with `opts` writes after its binary tree `nodes` ([`pairs`]; none for a
/// wide build or without [`BuildOptions::pairs`]).
pub fn pairs_if(opts: BuildOptions, nodes: &[Node]) -> Vec<Node> {
    if opts.pairs && !opts.wide {
        pairs(nodes)
    } else {
        Vec::new()
    }
}

/// The pairs of the binary tree `nodes` (`2n - 1` nodes; see [`BuildResult::pairs`]),
/// written by the kernel the GPU's `pairs_write` pass runs; none under two primitives.
pub fn pairs(nodes: &[Node]) -> Vec<Node> {
    let n = (nodes.len() as u32).div_ceil(2);
    if n < 2 {
        return Vec::new();
    }
    let mut all = nodes.to_vec();
    all.resize(traverse::traced_nodes(n) as usize, Node::default());
    let words: &mut [glam::UVec4] = bytemuck::cast_slice_mut(&mut all);
    (0..n - 1).for_each(|i| traverse::write_pairs(i, n, words));
    all.split_off(traverse::pairs_at(n) as usize)
}

/// Stage names in build order, as reported by both backends.
pub const STAGES: [&str; 5] = ["bounds", "morton", "sort", "tree", "refit"];
