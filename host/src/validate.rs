//! Structural check of a built BVH: every primitive in exactly one leaf, every node reached
//! once from the root (no cycles, no orphans), parents consistent, every box containing its
//! children's boxes and its primitives. Reports the depth.
use shared::types::{prim_box, Node, Sphere, Triangle, INVALID};
use std::fmt::Write;

/// Facts about a valid BVH.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhStats {
    pub nodes: usize,
    pub leaves: usize,
    pub depth: u32,
}

fn contains(outer: &Node, min: [f32; 3], max: [f32; 3]) -> bool {
    (0..3).all(|k| outer.min[k] <= min[k] && outer.max[k] >= max[k])
}

/// Checks the BVH over `tris` then `spheres`; the error lists the first problems found.
pub fn validate(nodes: &[Node], parents: &[u32], tris: &[Triangle], spheres: &[Sphere]) -> Result<BvhStats, String> {
    let n = tris.len() + spheres.len();
    let mut problems = String::new();
    let mut report = |s: String| {
        if problems.len() < 2000 {
            let _ = writeln!(problems, "{s}");
        }
    };
    if n == 0 {
        return if nodes.is_empty() {
            Ok(BvhStats {
                nodes: 0,
                leaves: 0,
                depth: 0,
            })
        } else {
            Err("nodes present for no primitives".into())
        };
    }
    if nodes.len() != 2 * n - 1 {
        return Err(format!(
            "{} nodes for {n} primitives (expected {})",
            nodes.len(),
            2 * n - 1
        ));
    }
    let mut seen_node = vec![false; nodes.len()];
    let mut seen_prim = vec![0u32; n];
    let mut depth = 0;
    let mut leaves = 0;
    let mut stack = vec![(0usize, 1u32)];
    while let Some((i, d)) = stack.pop() {
        if seen_node[i] {
            report(format!("node {i} reached twice (cycle or shared child)"));
            continue;
        }
        seen_node[i] = true;
        depth = depth.max(d);
        let node = &nodes[i];
        if node.is_leaf() {
            leaves += 1;
            let prim = node.a as usize;
            if prim >= n {
                report(format!("leaf {i} names primitive {prim} of {n}"));
                continue;
            }
            seen_prim[prim] += 1;
            let (lo, hi) = prim_box(prim as u32, tris.len() as u32, tris, spheres);
            if !contains(node, lo.to_array(), hi.to_array()) {
                report(format!(
                    "leaf {i} box {:?}..{:?} does not contain primitive {prim}",
                    node.min, node.max
                ));
            }
        } else {
            for c in [node.a, node.b] {
                let c = c as usize;
                if c >= nodes.len() {
                    report(format!("node {i} has child {c} out of range"));
                    continue;
                }
                if parents.get(c) != Some(&(i as u32)) {
                    report(format!("node {c} has parent {:?}, expected {i}", parents.get(c)));
                }
                if !contains(node, nodes[c].min, nodes[c].max) {
                    report(format!("node {i} box does not contain child {c}"));
                }
                stack.push((c, d + 1));
            }
        }
    }
    if parents.first() != Some(&INVALID) {
        report(format!("root parent is {:?}, expected none", parents.first()));
    }
    if let Some(i) = seen_node.iter().position(|s| !s) {
        report(format!("node {i} is not reachable from the root"));
    }
    for (p, &c) in seen_prim.iter().enumerate() {
        if c != 1 {
            report(format!("primitive {p} is in {c} leaves"));
            break;
        }
    }
    if problems.is_empty() {
        Ok(BvhStats {
            nodes: nodes.len(),
            leaves,
            depth,
        })
    } else {
        Err(problems)
    }
}
