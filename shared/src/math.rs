//! The seam between kernels and floating-point functions: on SPIR-V the GLSL.std.450
//! instructions, on the CPU the hardware `fma`/`sqrt` and libm for the rest. `fma` is the one
//! way kernels fuse a multiply and an add, so both backends round the same expressions the
//! same way wherever bit-exact agreement matters (transforms, edge functions).
use spirv_std::glam::Vec3;
#[cfg(target_arch = "spirv")]
use spirv_std::num_traits::Float;

/// `a * b + c` with one rounding.
pub fn fma(a: f32, b: f32, c: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        a.mul_add(b, c)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        core::f32::math::mul_add(a, b, c)
    }
}

pub fn sqrt(x: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        x.sqrt()
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        core::f32::math::sqrt(x)
    }
}

/// `1 / sqrt(x)`: on the GPU GLSL's `inversesqrt` (one special-function instruction, within
/// 2 ulp; a division after a square root takes a dozen), on the CPU exact.
pub fn inverse_sqrt(x: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        let mut r = 0.0f32;
        // SAFETY: the instruction reads a float and writes one.
        unsafe {
            core::arch::asm! {
                "%glsl = OpExtInstImport \"GLSL.std.450\"",
                "%r = OpExtInst typeof*{r} %glsl 32 {x}",
                "OpStore {r} %r",
                x = in(reg) x,
                r = in(reg) &mut r,
            }
        }
        r
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        1.0 / core::f32::math::sqrt(x)
    }
}

pub fn sin_cos(x: f32) -> (f32, f32) {
    spirv_std::num_traits::Float::sin_cos(x)
}

pub fn powf(x: f32, y: f32) -> f32 {
    spirv_std::num_traits::Float::powf(x, y)
}

/// `e^x`.
pub fn exp(x: f32) -> f32 {
    spirv_std::num_traits::Float::exp(x)
}

/// `a` and `b` as half-precision floats, `a` in the low 16 bits (GLSL `packHalf2x16`).
pub fn pack_half2(a: f32, b: f32) -> u32 {
    #[cfg(target_arch = "spirv")]
    {
        spirv_std::float::vec2_to_f16x2(spirv_std::glam::Vec2::new(a, b))
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        half::f16::from_f32(a).to_bits() as u32 | ((half::f16::from_f32(b).to_bits() as u32) << 16)
    }
}

/// The two floats of [`pack_half2`].
pub fn unpack_half2(x: u32) -> (f32, f32) {
    #[cfg(target_arch = "spirv")]
    {
        let v = spirv_std::float::f16x2_to_vec2(x);
        (v.x, v.y)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        (
            half::f16::from_bits(x as u16).to_f32(),
            half::f16::from_bits((x >> 16) as u16).to_f32(),
        )
    }
}

/// The angle of `(x, y)` from the x axis, in `(-pi, pi]`.
pub fn atan2(y: f32, x: f32) -> f32 {
    spirv_std::num_traits::Float::atan2(y, x)
}

/// The largest integer not above `x`.
pub fn floor(x: f32) -> f32 {
    spirv_std::num_traits::Float::floor(x)
}

/// Arc cosine of `x` clamped to `[-1, 1]`.
pub fn acos(x: f32) -> f32 {
    spirv_std::num_traits::Float::acos(x.clamp(-1.0, 1.0))
}

/// `a * b - c * d` with its sign exact: Kahan's difference of products (error at most
/// 1.5 ulp, so zero exactly when the products are equal). Contraction-proof: every
/// multiply-add is an explicit [`fma`].
pub fn difference_of_products(a: f32, b: f32, c: f32, d: f32) -> f32 {
    let cd = c * d;
    let err = fma(-c, d, cd);
    let dop = fma(a, b, -cd);
    dop + err
}

/// `a + b` as the unevaluated sum `s + e` of two floats, exactly (Knuth's TwoSum: any
/// order of magnitude, no branch; it relies on additions not being reassociated).
pub fn two_sum(a: f32, b: f32) -> (f32, f32) {
    let s = a + b;
    let b_part = s - a;
    let a_part = s - b_part;
    (s, (a - a_part) + (b - b_part))
}

/// `a * b` as the unevaluated sum `p + e` of two floats, exactly (one [`fma`]).
pub fn two_product(a: f32, b: f32) -> (f32, f32) {
    let p = a * b;
    (p, fma(a, b, -p))
}

/// `a * b` as `p + e` exactly without a fused multiply-add (Dekker 1971 with Veltkamp's
/// split), for devices whose GLSL `Fma` rounds twice: Vulkan allows it and llvmpipe's does.
/// Exact as long as no multiply or add is fused or reordered, which the `NoContraction`
/// decoration of every float operation in the kernels (`host/build.rs`) guarantees.
pub fn two_product_split(a: f32, b: f32) -> (f32, f32) {
    let p = a * b;
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    (p, al * bl - (((p - ah * bh) - al * bh) - ah * bl))
}

/// `a` as `hi + lo` with 12 significant bits in `hi` (Veltkamp).
fn split(a: f32) -> (f32, f32) {
    let c = 4097.0 * a;
    let hi = c - (c - a);
    (hi, a - hi)
}

/// [`two_product`], or [`two_product_split`] where `fma` is not fused (`split`).
pub fn exact_product(a: f32, b: f32, split: bool) -> (f32, f32) {
    if split {
        two_product_split(a, b)
    } else {
        two_product(a, b)
    }
}

/// [`difference_of_products`], or the same from [`two_product_split`]s where `fma` is not
/// fused (`split`): error a few ulps of the result.
pub fn difference_of_products_exact(a: f32, b: f32, c: f32, d: f32, split: bool) -> f32 {
    if !split {
        return difference_of_products(a, b, c, d);
    }
    let (ab, ab_err) = two_product_split(a, b);
    let (cd, cd_err) = two_product_split(c, d);
    (ab - cd) + (ab_err - cd_err)
}

/// The larger of `a` and `b`, or the one that is not NaN (IEEE 754 `maxNum`, as
/// `f32::max`): GLSL.std.450 `NMax`, one instruction on GPUs, where rust-gpu compiles
/// `f32::max` to compares and branches. Which zero `nmax(0.0, -0.0)` gives is left open, as
/// by `f32::max`.
pub fn nmax(a: f32, b: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        gl_binary::<80>(a, b)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        a.max(b)
    }
}

/// The smaller of `a` and `b`, or the one that is not NaN (`minNum`, `f32::min`; see
/// [`nmax`]).
pub fn nmin(a: f32, b: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        gl_binary::<79>(a, b)
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        a.min(b)
    }
}

/// GLSL.std.450 instruction `OP` of two floats.
#[cfg(target_arch = "spirv")]
fn gl_binary<const OP: u32>(a: f32, b: f32) -> f32 {
    let mut r = 0.0f32;
    // SAFETY: the instruction reads two floats and writes one.
    unsafe {
        core::arch::asm! {
            "%glsl = OpExtInstImport \"GLSL.std.450\"",
            "%r = OpExtInst typeof*{r} %glsl {op} {a} {b}",
            "OpStore {r} %r",
            op = const OP,
            a = in(reg) a,
            b = in(reg) b,
            r = in(reg) &mut r,
        }
    }
    r
}

/// `if c { a } else { b }` as one `OpSelect`: NVIDIA's compiler keeps a branch where a
/// choice between values is written as `if` or `match` in more than one place (the triangle
/// test's `permute` compiled to branches around moves, which lanes of different rays take
/// apart: SASS, bench/NOTES.md session 53).
#[inline(always)]
pub fn select(c: bool, a: f32, b: f32) -> f32 {
    #[cfg(target_arch = "spirv")]
    {
        let mut r = 0.0f32;
        // SAFETY: the instructions read a bool and two floats and write a float.
        unsafe {
            core::arch::asm! {
                "%c = OpLoad _ {c}",
                "%r = OpSelect typeof*{r} %c {a} {b}",
                "OpStore {r} %r",
                c = in(reg) &c,
                a = in(reg) a,
                b = in(reg) b,
                r = in(reg) &mut r,
            }
        }
        r
    }
    #[cfg(not(target_arch = "spirv"))]
    {
        if c {
            a
        } else {
            b
        }
    }
}

/// Largest component.
pub fn max3(v: Vec3) -> f32 {
    v.x.max(v.y).max(v.z)
}

/// `1 + 2 * gamma(3)`: widening of a slab test's far distance that covers the rounding of
/// `(bound - origin) * inv_dir` (Ize 2013; pbrt-v4 `Bounds3::IntersectP`).
pub const SLAB_WIDEN: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Whether every component is finite.
pub fn finite3(v: Vec3) -> bool {
    v.x.is_finite() && v.y.is_finite() && v.z.is_finite()
}
