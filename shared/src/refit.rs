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

/// Climbs from leaf `i`, fitting every internal node this invocation arrives at second.
///
/// `ORDERED` selects the acquire-release counter that real GPUs need. Mesa 22.3's lavapipe
/// (Debian 12, our CI device) loses the second arrival when any acquire/release semantics or
/// memory barrier sits in this divergent loop (its coroutine barrier lowering); there the
/// host runs the relaxed variant, which is sound on lavapipe's coherent x86 memory.
pub fn refit<const ORDERED: bool>(
    i: u32,
    p: &BuildParams,
    parents: &[u32],
    visits: &mut [u32],
    words: &mut [u32],
) {
    let n = p.n;
    if i >= n {
        return;
    }
    let mut node = n - 1 + i;
    let mut climbing = true;
    while climbing {
        let parent = parents[node as usize];
        // The first arrival at a node stops; the second fits it and climbs on.
        if parent == INVALID
            || sync::atomic_add_device::<ORDERED>(&mut visits[parent as usize], 1) == 0
        {
            climbing = false;
        } else {
            fit(parent, words);
            node = parent;
        }
    }
}

/// Sets the box of internal node `parent` to the union of its children's boxes.
fn fit(parent: u32, words: &mut [u32]) {
    let base = parent * WORDS;
    let l = words[(base + 3) as usize] * WORDS;
    let r = words[(base + 7) as usize] * WORDS;
    let mut k = 0;
    while k < 3 {
        let lo = load_f(words, l + k).min(load_f(words, r + k));
        let hi = load_f(words, l + 4 + k).max(load_f(words, r + 4 + k));
        sync::atomic_store(&mut words[(base + k) as usize], lo.to_bits());
        sync::atomic_store(&mut words[(base + 4 + k) as usize], hi.to_bits());
        k += 1;
    }
}
