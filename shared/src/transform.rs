//! The transform stage: every primitive from its object's model space to world space, each
//! frame, before the BVH build (the thesis's per-object model matrix: translation,
//! Tait-Bryan Y-X-Z rotation, scale). Explicit [`fma`] chains round identically on the CPU
//! and the GPU, so both backends build the same BVH from the same scene.
use crate::math::{floor, fma};
use crate::sync::{at, at_mut};
use crate::types::{sphere_summary, tri_summary, BuildParams, Object, Sphere, Triangle};
use spirv_std::glam::UVec4;

/// `rows * [v, 1]`; `w` of the result is 0.
pub fn apply(o: &Object, v: [f32; 4]) -> [f32; 4] {
    [row(o.rows[0], v), row(o.rows[1], v), row(o.rows[2], v), 0.0]
}

/// `r . [v.xyz, 1]` by the explicit `fma` chain every transform of a point uses.
pub fn row(r: [f32; 4], v: [f32; 4]) -> f32 {
    fma(r[0], v[0], fma(r[1], v[1], fma(r[2], v[2], r[3])))
}

/// World-space copy of primitive `i` (triangles `0..n_tris`, then spheres). The world
/// triangles are written as 16-byte words, three to a triangle (`tris` is the triangle
/// buffer seen as `[UVec4]`): NVIDIA's compiler stores a `Triangle` value as narrow words,
/// which made the stage four times its bytes' time (H200, 10M triangles 0.90 ms; see
/// bench/NOTES.md, session 46).
#[allow(clippy::too_many_arguments)]
pub fn transform(
    i: u32,
    p: &BuildParams,
    objects: &[Object],
    prim_object: &[u32],
    model_tris: &[Triangle],
    model_spheres: &[Sphere],
    tris: &mut [UVec4],
    spheres: &mut [Sphere],
) {
    if i < p.n {
        transformed(i, p, objects, prim_object, model_tris, model_spheres, tris, spheres);
    }
}

/// [`transform`] of primitive `i < p.n`, returning its [`prim_summary`](crate::types::prim_summary)
/// (the same bits as the summary of the primitive stored): the transform stage of a frame
/// that builds reduces the bounds on the way (`crate::bounds::accumulate_transformed`).
#[allow(clippy::too_many_arguments)]
pub fn transformed(
    i: u32,
    p: &BuildParams,
    objects: &[Object],
    prim_object: &[u32],
    model_tris: &[Triangle],
    model_spheres: &[Sphere],
    tris: &mut [UVec4],
    spheres: &mut [Sphere],
) -> [f32; 4] {
    // By reference: a copy of the object would load all its 128 bytes.
    let o = at(objects, *at(prim_object, i));
    if i < p.n_tris {
        let t = at(model_tris, i);
        let world = Triangle {
            v0: apply(o, waved(o, t.v0)),
            v1: apply(o, waved(o, t.v1)),
            v2: apply(o, waved(o, t.v2)),
        };
        let word = |w: [f32; 4]| UVec4::new(w[0].to_bits(), w[1].to_bits(), w[2].to_bits(), w[3].to_bits());
        *at_mut(tris, 3 * i) = word(world.v0);
        *at_mut(tris, 3 * i + 1) = word(world.v1);
        *at_mut(tris, 3 * i + 2) = word(world.v2);
        tri_summary(&world)
    } else {
        let k = i - p.n_tris;
        let world = world_sphere(o, at(model_spheres, k));
        *at_mut(spheres, k) = world;
        sphere_summary(&world)
    }
}

/// Model-space vertex `v` of object `o` moved along y by the object's wave (`Object::wave`:
/// amplitude `a`, waves per unit `kx` and `kz`, phase `p`): `a (8 g^2 - 1)` with `g` the
/// fraction of `kx x + kz z - p` less 1/2, a crest of height `a` at every whole wave and a trough
/// of `-a` between (a parabola each side: no `sin`, whose GPU and CPU bits differ; floor,
/// products and sums are the same bits everywhere, so deformed meshes build equal on both).
/// Objects without a wave (`a = 0`) keep `v`: only the transform stage calls this, so a
/// waving object is always flattened (its shape changes every frame).
pub fn waved(o: &Object, v: [f32; 4]) -> [f32; 4] {
    let [a, kx, kz, phase] = o.wave;
    if a == 0.0 {
        return v;
    }
    // Plain products and sums, which the kernels never fuse (`NoContraction`), not `fma`:
    // a device may round its `fma` twice (llvmpipe does), and the wave must move every
    // vertex by the same bits everywhere. 1 - 8 f (1 - f) is 8 g^2 - 1 with g = f - 1/2.
    let s = v[0] * kx + (v[2] * kz - phase);
    let g = (s - floor(s)) - 0.5;
    let h = 8.0 * (g * g) - 1.0;
    [v[0], a * h + v[1], v[2], v[3]]
}

/// Model-space triangle `t` of object `o` in world space (the same bits wherever it is
/// computed: the transform stage, or the shading of an instance's hit).
pub fn world_triangle(o: &Object, t: &Triangle) -> Triangle {
    Triangle {
        v0: apply(o, t.v0),
        v1: apply(o, t.v1),
        v2: apply(o, t.v2),
    }
}

/// Model-space sphere `s` of object `o` in world space: its centre moved, its radius scaled
/// by the transform's largest scale.
pub fn world_sphere(o: &Object, s: &Sphere) -> Sphere {
    let c = apply(o, s.center_radius);
    Sphere {
        center_radius: [c[0], c[1], c[2], s.center_radius[3] * o.radius_scale],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn waving(wave: [f32; 4]) -> Object {
        Object {
            wave,
            ..Default::default()
        }
    }

    #[test]
    fn a_wave_has_crests_at_whole_waves_and_troughs_between() {
        // Amplitude 0.5, two waves a unit along x, a quarter wave on.
        let o = waving([0.5, 2.0, 0.0, 0.25]);
        let y = |x: f32, z: f32| waved(&o, [x, 1.0, z, 0.0])[1];
        // Crests where 2x - 0.25 is whole, troughs half a wave on; along z nothing changes.
        for (x, want) in [(0.125, 1.5), (0.625, 1.5), (0.375, 0.5), (-0.125, 0.5)] {
            assert_eq!(y(x, 0.0), want, "x {x}");
            assert_eq!(y(x, 7.0), want, "x {x}, z 7");
        }
        // A quarter wave from the crest: the parabola 8 g^2 - 1 at g = -1/4 is -1/2;
        // and the same a wave later (it repeats).
        assert_eq!(y(0.25, 0.0), 0.75);
        assert!((y(0.2, 0.0) - y(0.7, 0.0)).abs() < 1e-6);
        // x and z never move, and no wave leaves the vertex as it was.
        let v = [0.3, -2.0, 0.9, 0.0];
        assert_eq!(waved(&o, v)[0], 0.3);
        assert_eq!(waved(&o, v)[2], 0.9);
        assert_eq!(waved(&waving([0.0, 2.0, 1.0, 0.5]), v), v);
    }
}
