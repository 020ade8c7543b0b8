//! The transform stage: every primitive from its object's model space to world space, each
//! frame, before the BVH build (the thesis's per-object model matrix: translation,
//! Tait-Bryan Y-X-Z rotation, scale). Explicit [`fma`] chains round identically on the CPU
//! and the GPU, so both backends build the same BVH from the same scene.
use crate::math::fma;
use crate::types::{BuildParams, Object, Sphere, Triangle};

/// `rows * [v, 1]`; `w` of the result is 0.
pub fn apply(o: &Object, v: [f32; 4]) -> [f32; 4] {
    [row(o.rows[0], v), row(o.rows[1], v), row(o.rows[2], v), 0.0]
}

/// `r . [v.xyz, 1]` by the explicit `fma` chain every transform of a point uses.
pub fn row(r: [f32; 4], v: [f32; 4]) -> f32 {
    fma(r[0], v[0], fma(r[1], v[1], fma(r[2], v[2], r[3])))
}

/// World-space copy of primitive `i` (triangles `0..n_tris`, then spheres).
#[allow(clippy::too_many_arguments)]
pub fn transform(
    i: u32,
    p: &BuildParams,
    objects: &[Object],
    prim_object: &[u32],
    model_tris: &[Triangle],
    model_spheres: &[Sphere],
    tris: &mut [Triangle],
    spheres: &mut [Sphere],
) {
    if i >= p.n {
        return;
    }
    let o = objects[prim_object[i as usize] as usize];
    if i < p.n_tris {
        tris[i as usize] = world_triangle(&o, &model_tris[i as usize]);
    } else {
        let k = (i - p.n_tris) as usize;
        spheres[k] = world_sphere(&o, &model_spheres[k]);
    }
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
