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
    coverage("node", &seen_node, &seen_prim, &mut report);
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

/// Reports the first node (`what`) not reached from the root, and the first primitive not
/// in exactly one leaf.
fn coverage(what: &str, seen_node: &[bool], seen_prim: &[u32], report: &mut impl FnMut(String)) {
    if let Some(i) = seen_node.iter().position(|s| !s) {
        report(format!("{what} {i} is not reachable from the root"));
    }
    if let Some((p, c)) = seen_prim.iter().enumerate().find(|(_, &c)| c != 1) {
        report(format!("primitive {p} is in {c} leaves"));
    }
}

/// Facts about a valid wide BVH.
#[derive(Clone, Debug, PartialEq)]
pub struct WideStats {
    pub nodes: usize,
    pub leaves: usize,
    pub depth: u32,
    /// Mean children of a node, and mean primitives of a leaf.
    pub children: f64,
    pub leaf_size: f64,
}

/// Checks a wide BVH (`shared::wide`) over `tris` then `spheres`, its leaves naming sorted
/// positions of `order`: every node reached once from node 0 (a slot no node takes is
/// empty: [`super::clear_unreached`]), children packed before the
/// empty slots (whose boxes are empty), every child's box containing every primitive below it
/// (the boxes of its subtree's primitives, not only its children's), and every primitive in
/// exactly one leaf of 1..=`LEAF_MAX` primitives (a leaf of one names the primitive itself).
pub fn validate_wide(
    wide: &[shared::wide::WideNode],
    order: &[u32],
    tris: &[Triangle],
    spheres: &[Sphere],
) -> Result<WideStats, String> {
    use shared::wide::{leaf_range, LEAF, LEAF_MAX, WIDTH};
    let n = tris.len() + spheres.len();
    let mut problems = String::new();
    let mut report = |s: String| {
        if problems.len() < 2000 {
            let _ = writeln!(problems, "{s}");
        }
    };
    if n == 0 {
        return Ok(WideStats {
            nodes: wide.len(),
            leaves: 0,
            depth: 0,
            children: 0.0,
            leaf_size: 0.0,
        });
    }
    if wide.is_empty() {
        return Err(format!("no wide nodes for {n} primitives"));
    }
    if order.len() != n {
        return Err(format!("{} sorted positions for {n} primitives", order.len()));
    }
    let mut seen_node = vec![false; wide.len()];
    let mut seen_prim = vec![0u32; n];
    let (mut depth, mut leaves, mut children, mut in_leaves) = (0, 0usize, 0usize, 0usize);
    let mut stack = vec![(0usize, 1u32)];
    let inside =
        |b: &([f32; 3], [f32; 3]), lo: [f32; 3], hi: [f32; 3]| (0..3).all(|k| b.0[k] <= lo[k] && b.1[k] >= hi[k]);
    while let Some((i, d)) = stack.pop() {
        if i >= wide.len() {
            report(format!("wide node {i} out of range ({} nodes)", wide.len()));
            continue;
        }
        if seen_node[i] {
            report(format!("wide node {i} reached twice (cycle or shared child)"));
            continue;
        }
        seen_node[i] = true;
        depth = depth.max(d);
        let w = &wide[i];
        let mut empty = false;
        for k in 0..WIDTH {
            let c = w.child[k];
            let b = w.child_box(k);
            if c == INVALID {
                empty = true;
                if b.0.iter().chain(&b.1).any(|&x| x != f32::INFINITY) {
                    report(format!("wide node {i} slot {k} is empty but its box is {b:?}"));
                }
                continue;
            }
            if empty {
                report(format!("wide node {i} slot {k} follows an empty slot"));
            }
            children += 1;
            if c & LEAF != 0 {
                let (first, count) = leaf_range(c);
                leaves += 1;
                in_leaves += count as usize;
                if count > LEAF_MAX || first as usize + count as usize > n {
                    report(format!("wide node {i} slot {k}: leaf {first}+{count} of {n}"));
                    continue;
                }
                for pos in first..first + count {
                    let prim = if count == 1 { pos } else { order[pos as usize] };
                    if prim as usize >= n {
                        report(format!("sorted position {pos} names primitive {prim} of {n}"));
                        continue;
                    }
                    seen_prim[prim as usize] += 1;
                    let (lo, hi) = prim_box(prim, tris.len() as u32, tris, spheres);
                    if !inside(&b, lo.to_array(), hi.to_array()) {
                        report(format!("wide node {i} slot {k} box does not contain primitive {prim}"));
                    }
                }
            } else {
                // Every primitive below lies in this slot's box: the child's slots lie in it,
                // and theirs in them, down to the leaves' primitives.
                let child = c as usize;
                if let Some(cw) = wide.get(child) {
                    for kk in 0..WIDTH {
                        if cw.child[kk] != INVALID {
                            let (lo, hi) = cw.child_box(kk);
                            if !inside(&b, lo, hi) {
                                report(format!(
                                    "wide node {i} slot {k} box does not contain node {child} slot {kk}"
                                ));
                            }
                        }
                    }
                }
                stack.push((child, d + 1));
            }
        }
        if w.child[0] == INVALID || (i > 0 && w.child[1] == INVALID) {
            report(format!("wide node {i} has fewer than two children"));
        }
    }
    // Slots that no wide node takes hold nothing.
    let accounted: Vec<bool> = (seen_node.iter().zip(wide))
        .map(|(&seen, w)| seen || *w == shared::wide::WideNode::EMPTY)
        .collect();
    coverage("wide node", &accounted, &seen_prim, &mut report);
    let nodes = seen_node.iter().filter(|&&s| s).count();
    if problems.is_empty() {
        Ok(WideStats {
            nodes,
            leaves,
            depth,
            children: children as f64 / nodes as f64,
            leaf_size: in_leaves as f64 / leaves.max(1) as f64,
        })
    } else {
        Err(problems)
    }
}
