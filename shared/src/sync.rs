//! The seam between kernels and GPU-only intrinsics. On SPIR-V these are real atomics; on the
//! CPU executor, which runs one invocation at a time, plain reads and writes have the same
//! meaning. Also unchecked indexing ([`at`], [`at_mut`], [`elem`], [`elem_mut`]), checked on the CPU.
use spirv_std::glam::UVec4;
#[cfg(target_arch = "spirv")]
use spirv_std::memory::{Scope, Semantics};

#[cfg(target_arch = "spirv")]
const DEVICE: u32 = Scope::Device as u32;
#[cfg(target_arch = "spirv")]
const WORKGROUP: u32 = Scope::Workgroup as u32;
#[cfg(target_arch = "spirv")]
const RELAXED: u32 = Semantics::NONE.bits();
/// Acquire-release on storage-buffer memory: orders the atomic loads and stores around the
/// refit's visit counter, what Karras's `__threadfence()` does. (No availability or
/// visibility operations: everything the counter publishes is itself accessed atomically.)
#[cfg(target_arch = "spirv")]
const ACQ_REL: u32 = Semantics::ACQUIRE_RELEASE.bits() | Semantics::UNIFORM_MEMORY.bits();
/// [`ACQ_REL`] for a counter in workgroup memory that publishes storage-buffer writes.
#[cfg(target_arch = "spirv")]
const WG_ACQ_REL: u32 = ACQ_REL | Semantics::WORKGROUP_MEMORY.bits();

/// How many of the subgroup's active invocations have `waiting` (`GroupNonUniformBallot`);
/// every active invocation must call it. On the CPU executor: `waiting` as 0 or 1.
pub fn count_waiting(waiting: bool) -> u32 {
    #[cfg(target_arch = "spirv")]
    {
        spirv_std::arch::subgroup_ballot_bit_count(spirv_std::arch::subgroup_ballot(waiting))
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        waiting as u32
    }
}

/// Relaxed device-scope `min`; returns the old value.
pub fn atomic_min(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_u_min::<u32, DEVICE, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.min(v);
        old
    }
}

/// Relaxed device-scope `max`; returns the old value.
pub fn atomic_max(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_u_max::<u32, DEVICE, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.max(v);
        old
    }
}

/// Relaxed workgroup-scope `min` on workgroup memory.
pub fn workgroup_min(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_u_min::<u32, WORKGROUP, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.min(v);
        old
    }
}

/// Relaxed workgroup-scope `max` on workgroup memory.
pub fn workgroup_max(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_u_max::<u32, WORKGROUP, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.max(v);
        old
    }
}

/// Workgroup-scope add on workgroup memory; returns the old value. With `ORDERED` it is
/// acquire-release on workgroup and storage-buffer memory (it orders this workgroup's
/// accesses to both around it); without, relaxed.
pub fn workgroup_add_ordered<const ORDERED: bool>(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        if ORDERED {
            spirv_std::arch::atomic_i_add::<u32, WORKGROUP, WG_ACQ_REL>(p, v)
        } else {
            spirv_std::arch::atomic_i_add::<u32, WORKGROUP, RELAXED>(p, v)
        }
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.wrapping_add(v);
        old
    }
}

/// Acquire-release on workgroup memory alone: orders this invocation's workgroup-memory
/// accesses around a workgroup-memory atomic (the fit's arrival flags, see `refit::fit`).
#[cfg(target_arch = "spirv")]
const WG_ONLY_ACQ_REL: u32 = Semantics::ACQUIRE_RELEASE.bits() | Semantics::WORKGROUP_MEMORY.bits();

/// Workgroup-scope `or` on workgroup memory; returns the old value. With `ORDERED` it is
/// acquire-release on workgroup memory; without, relaxed.
pub fn workgroup_or_ordered<const ORDERED: bool>(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        if ORDERED {
            spirv_std::arch::atomic_or::<u32, WORKGROUP, WG_ONLY_ACQ_REL>(p, v)
        } else {
            spirv_std::arch::atomic_or::<u32, WORKGROUP, RELAXED>(p, v)
        }
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old | v;
        old
    }
}

/// Relaxed device-scope float `min` on the bits of a non-NaN `f32` held in a `u32`: a
/// signed integer `min` where `v` is non-negative, an unsigned `max` where it is negative
/// (negative floats order backwards as integers, and above every non-negative one
/// unsigned). The result is the minimum under the order in which -0.0 < +0.0 whatever the
/// order of the updates. Its value is not used: a reduction the GPU need not wait for.
pub fn atomic_fmin_bits(p: &mut u32, v: f32) {
    let b = v.to_bits();
    if (b as i32) >= 0 {
        smin_u32(p, b);
    } else {
        atomic_max(p, b);
    }
}

/// Relaxed device-scope float `max`, the partner of [`atomic_fmin_bits`] (+0.0 > -0.0).
pub fn atomic_fmax_bits(p: &mut u32, v: f32) {
    let b = v.to_bits();
    if (b as i32) >= 0 {
        smax_u32(p, b);
    } else {
        atomic_min(p, b);
    }
}

/// Relaxed device-scope signed `min` and `max` on a `u32` (spirv-std types `OpAtomicSMin`
/// and `OpAtomicSMax` by signed integers only, and the node words are unsigned).
macro_rules! signed_atomic {
    ($name:ident, $op:literal, $cpu:ident) => {
        fn $name(p: &mut u32, v: u32) {
            #[cfg(target_arch = "spirv")]
            unsafe {
                core::arch::asm! {
                    "%u32 = OpTypeInt 32 0",
                    "%scope = OpConstant %u32 {scope}",
                    "%semantics = OpConstant %u32 {semantics}",
                    "%value = OpLoad _ {value}",
                    concat!("%old = ", $op, " %u32 {ptr} %scope %semantics %value"),
                    scope = const DEVICE,
                    semantics = const RELAXED,
                    ptr = in(reg) p,
                    value = in(reg) &v,
                }
            }
            #[cfg(not(target_arch = "spirv"))]
            {
                *p = (*p as i32).$cpu(v as i32) as u32;
            }
        }
    };
}
signed_atomic!(smin_u32, "OpAtomicSMin", min);
signed_atomic!(smax_u32, "OpAtomicSMax", max);

/// Relaxed workgroup-scope add on workgroup memory; returns the old value.
pub fn workgroup_add(p: &mut u32, v: u32) -> u32 {
    workgroup_add_ordered::<false>(p, v)
}

/// Device-scope add on storage-buffer memory; returns the old value. With `ORDERED` it is
/// acquire-release; without, relaxed (see `refit` for the one driver that needs that).
pub fn atomic_add_device<const ORDERED: bool>(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        if ORDERED {
            spirv_std::arch::atomic_i_add::<u32, DEVICE, ACQ_REL>(p, v)
        } else {
            spirv_std::arch::atomic_i_add::<u32, DEVICE, RELAXED>(p, v)
        }
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        let old = *p;
        *p = old.wrapping_add(v);
        old
    }
}

/// Device-scope exchange on storage-buffer memory; returns the old value. With `ORDERED` it
/// is acquire-release; without, relaxed (see `refit` for the one driver that needs that).
pub fn atomic_exchange_device<const ORDERED: bool>(p: &mut u32, v: u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        if ORDERED {
            spirv_std::arch::atomic_exchange::<u32, DEVICE, ACQ_REL>(p, v)
        } else {
            spirv_std::arch::atomic_exchange::<u32, DEVICE, RELAXED>(p, v)
        }
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        core::mem::replace(p, v)
    }
}

/// Relaxed device-scope 32-bit load: reads what another workgroup stored or merged in this
/// dispatch, past any non-coherent cache.
pub fn atomic_load_u32(p: &u32) -> u32 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_load::<u32, DEVICE, RELAXED>(p)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *p
    }
}

/// Relaxed device-scope 64-bit load: two neighbouring words in one memory operation; reads
/// what another workgroup stored in this dispatch, past any non-coherent cache.
pub fn atomic_load_u64(p: &u64) -> u64 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_load::<u64, DEVICE, RELAXED>(p)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *p
    }
}

/// Relaxed workgroup-scope 64-bit load of storage-buffer memory that an invocation of the
/// same workgroup stored (with [`atomic_store_u64`]): the SM's own cache may serve it.
pub fn workgroup_load_u64(p: &u64) -> u64 {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_load::<u64, WORKGROUP, RELAXED>(p)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *p
    }
}

/// Relaxed device-scope 32-bit store, the partner of [`atomic_load_u32`].
pub fn atomic_store_u32(p: &mut u32, v: u32) {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_store::<u32, DEVICE, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *p = v;
    }
}

/// Relaxed device-scope 64-bit store, the partner of [`atomic_load_u64`].
pub fn atomic_store_u64(p: &mut u64, v: u64) {
    #[cfg(target_arch = "spirv")]
    unsafe {
        spirv_std::arch::atomic_store::<u64, DEVICE, RELAXED>(p, v)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *p = v;
    }
}

// Unchecked indexing on the GPU, checked on the CPU.
//
// rust-gpu turns every failed index check into an early return, so each checked access is a
// branch out of every enclosing loop: the GPU compiler then unrolls none of them, and a kernel
// made of small workgroup-memory steps spends its time on control flow (the radix scatter's
// phases took ~1 us each on the H100 for eight stores per lane, measured with SM-clock marks).
// The functions below index without the check on the GPU where every index is in range by
// construction: an index the builder or the host's checked scene wrote (node links, primitive
// indices below `n`, object and material indices), a slot of the traversal's fixed stack
// (pushes check its size, pops follow pushes), or arithmetic on lane, tile and digit numbers
// that the CPU executor runs through the same code with the checks on, so a bad index still
// fails loudly in the tests. In the traversal the checks cost the H100 2-5% of its frame time
// and 8 registers.

/// Element `i` of a buffer (see above).
#[inline(always)]
pub fn at<T>(v: &[T], i: u32) -> &T {
    #[cfg(target_arch = "spirv")]
    // SAFETY: see above.
    unsafe {
        use spirv_std::arch::IndexUnchecked;
        v.index_unchecked(i as usize)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        &v[i as usize]
    }
}

/// Element `i` of a buffer of 16-byte words, read whole: one `OpLoad` of the vector, which
/// NVIDIA's compiler makes one 16-byte load. (`*at(v, i)` whose components are used one by
/// one becomes a load per component in rustc's MIR, and the driver keeps them apart: four
/// loads, each with its own address register.)
#[inline(always)]
pub fn word_at(v: &[UVec4], i: u32) -> UVec4 {
    #[cfg(target_arch = "spirv")]
    {
        let p = at(v, i);
        let mut w = UVec4::ZERO;
        // SAFETY: the instruction reads the vector `p` points at and writes it to `w`.
        unsafe {
            core::arch::asm! {
                "%w = OpLoad _ {p}",
                "OpStore {w} %w",
                p = in(reg) p,
                w = in(reg) &mut w,
            }
        }
        w
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        *at(v, i)
    }
}

/// Element `i` of a buffer, to write (see above).
#[inline(always)]
pub fn at_mut<T>(v: &mut [T], i: u32) -> &mut T {
    #[cfg(target_arch = "spirv")]
    // SAFETY: see above.
    unsafe {
        use spirv_std::arch::IndexUnchecked;
        v.index_unchecked_mut(i as usize)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        &mut v[i as usize]
    }
}

/// Element `i` of a fixed array (workgroup memory, a stack; see above).
#[inline(always)]
pub fn elem<T, const N: usize>(a: &[T; N], i: u32) -> &T {
    #[cfg(target_arch = "spirv")]
    // SAFETY: see above.
    unsafe {
        use spirv_std::arch::IndexUnchecked;
        a.index_unchecked(i as usize)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        &a[i as usize]
    }
}

/// Element `i` of a fixed array, to write (see above).
#[inline(always)]
pub fn elem_mut<T, const N: usize>(a: &mut [T; N], i: u32) -> &mut T {
    #[cfg(target_arch = "spirv")]
    // SAFETY: see above.
    unsafe {
        use spirv_std::arch::IndexUnchecked;
        a.index_unchecked_mut(i as usize)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        &mut a[i as usize]
    }
}
