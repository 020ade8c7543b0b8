//! The transform stage: every primitive from its object's model space to world space, each
//! frame, before the BVH build (the thesis's per-object model matrix: translation,
//! Tait-Bryan Y-X-Z rotation, scale). Explicit [`fma`] chains round identically on the CPU
//! and the GPU, so both backends build the same BVH from the same scene.
use crate::math::fma;
use crate::types::{BuildParams, Object, Sphere, Triangle};

/// `rows * [v, 1]`; `w` of the result is 0.
fn apply(o: &Object, v: [f32; 4]) -> [f32; 4] {
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
        let t = model_tris[i as usize];
        tris[i as usize] = Triangle {
            v0: apply(&o, t.v0),
            v1: apply(&o, t.v1),
            v2: apply(&o, t.v2),
        };
    } else {
        let k = (i - p.n_tris) as usize;
        let s = model_spheres[k].center_radius;
        let c = apply(&o, s);
        spheres[k] = Sphere {
            center_radius: [c[0], c[1], c[2], s[3] * o.radius_scale],
        };
    }
}
