//! Bottom-up box fitting (Karras 2012, sec. 4; the thesis's refit): one invocation per leaf
//! climbs towards the root. At each internal node an acquire-release visit counter lets the
//! first arrival stop and the second, which then sees both children's boxes, fit the node
//! and go on. Boxes are read and written through device-scope atomics, so no stale cache
//! line of another workgroup's write can be seen.
//!
//! The kernel sees the node buffer as words, 8 per [`crate::types::Node`]:
//! `[min.x, min.y, min.z, a, max.x, max.y, max.z, b]`.
use crate::sync;
use crate::types::{BuildParams, INVALID};

const WORDS: u32 = 8;

fn load_f(words: &[u32], at: u32) -> f32 {
    f32::from_bits(sync::atomic_load(&words[at as usize]))
}

/// Climbs from leaf `i`, fitting every internal node this invocation arrives at second. The
/// invocation carries the box it just fitted and reads only the sibling's; children are
/// combined in (left, right) order so that `min(-0.0, +0.0)` is the same on every backend.
///
/// `ORDERED` selects the acquire-release counter that real GPUs need. Mesa 22.3's lavapipe
/// (Debian 12, our CI device) loses the second arrival when any acquire/release semantics or
/// memory barrier sits in this divergent loop (its coroutine barrier lowering); there the
/// host runs the relaxed variant, which is sound on lavapipe's coherent x86 memory.
pub fn refit<const ORDERED: bool>(i: u32, p: &BuildParams, parents: &[u32], visits: &mut [u32], words: &mut [u32]) {
    let n = p.n;
    if i >= n {
        return;
    }
    let mut node = n - 1 + i;
    let base = node * WORDS;
    let mut lo = [
        f32::from_bits(words[base as usize]),
        f32::from_bits(words[(base + 1) as usize]),
        f32::from_bits(words[(base + 2) as usize]),
    ];
    let mut hi = [
        f32::from_bits(words[(base + 4) as usize]),
        f32::from_bits(words[(base + 5) as usize]),
        f32::from_bits(words[(base + 6) as usize]),
    ];
    let mut parent = parents[node as usize];
    while parent != INVALID {
        // Immutable during the refit, so loaded before the counter, in its shadow.
        let pb = parent * WORDS;
        let left = words[(pb + 3) as usize];
        let right = words[(pb + 7) as usize];
        let grandparent = parents[parent as usize];
        // The first arrival at a node stops; the second fits it and climbs on.
        if sync::atomic_add_device::<ORDERED>(&mut visits[parent as usize], 1) == 0 {
            return;
        }
        let sb = if left == node { right } else { left } * WORDS;
        for k in 0..3 {
            let s_lo = load_f(words, sb + k);
            let s_hi = load_f(words, sb + 4 + k);
            let (l_lo, r_lo, l_hi, r_hi) = if left == node {
                (lo[k as usize], s_lo, hi[k as usize], s_hi)
            } else {
                (s_lo, lo[k as usize], s_hi, hi[k as usize])
            };
            lo[k as usize] = l_lo.min(r_lo);
            hi[k as usize] = l_hi.max(r_hi);
            sync::atomic_store(&mut words[(pb + k) as usize], lo[k as usize].to_bits());
            sync::atomic_store(&mut words[(pb + 4 + k) as usize], hi[k as usize].to_bits());
        }
        node = parent;
        parent = grandparent;
    }
}
