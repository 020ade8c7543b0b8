//! The node buffer as 64-bit words, 4 per [`crate::types::Node`]:
//! `[min.x | min.y, min.z | a, max.x | max.y, max.z | b]` (low half first), read and written
//! through atomics (another invocation of the same dispatch may have written a node), so a
//! box is read or written with four atomic operations instead of six. The counter refit
//! ([`crate::refit::refit`]) and the treelet restructuring ([`crate::treelet`]) both see the
//! nodes this way.
use crate::sync::{self, at, at_mut};

/// Words per node.
pub const WORDS: u32 = 4;

/// The two floats of a word.
fn split(w: u64) -> (f32, f32) {
    (f32::from_bits(w as u32), f32::from_bits((w >> 32) as u32))
}

/// A word of two 32-bit halves.
fn join(lo: u32, hi: u32) -> u64 {
    lo as u64 | (hi as u64) << 32
}

/// A node's box `(lo, hi)` from its four words.
fn unpack(w: [u64; 4]) -> ([f32; 3], [f32; 3]) {
    let ((x0, y0), (z0, _)) = (split(w[0]), split(w[1]));
    let ((x1, y1), (z1, _)) = (split(w[2]), split(w[3]));
    ([x0, y0, z0], [x1, y1, z1])
}

/// Node `node`'s box through atomic loads (another invocation may have written it in this
/// dispatch): workgroup-scope ones when `LOCAL` (an invocation of this workgroup wrote it:
/// the SM's cache may serve them), else device-scope.
pub fn load_box<const LOCAL: bool>(words: &[u64], node: u32) -> ([f32; 3], [f32; 3]) {
    let b = node * WORDS;
    let load = |k: u32| {
        if LOCAL {
            sync::workgroup_load_u64(at(words, b + k))
        } else {
            sync::atomic_load_u64(at(words, b + k))
        }
    };
    unpack([load(0), load(1), load(2), load(3)])
}

/// Internal node `node`'s children `(a, b)` through atomic loads.
pub fn load_children(words: &[u64], node: u32) -> (u32, u32) {
    let b = node * WORDS;
    let (w1, w3) = (
        sync::atomic_load_u64(at(words, b + 1)),
        sync::atomic_load_u64(at(words, b + 3)),
    );
    ((w1 >> 32) as u32, (w3 >> 32) as u32)
}

/// Writes internal node `node` (box and children) through atomic stores.
pub fn store(words: &mut [u64], node: u32, lo: [f32; 3], hi: [f32; 3], a: u32, b: u32) {
    let w = node * WORDS;
    sync::atomic_store_u64(at_mut(words, w), join(lo[0].to_bits(), lo[1].to_bits()));
    sync::atomic_store_u64(at_mut(words, w + 1), join(lo[2].to_bits(), a));
    sync::atomic_store_u64(at_mut(words, w + 2), join(hi[0].to_bits(), hi[1].to_bits()));
    sync::atomic_store_u64(at_mut(words, w + 3), join(hi[2].to_bits(), b));
}

/// A node and its box.
#[derive(Copy, Clone)]
pub struct Boxed {
    pub node: u32,
    pub lo: [f32; 3],
    pub hi: [f32; 3],
}
