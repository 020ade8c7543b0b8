//! rust-gpu entry points, each a few lines calling into `shared`, in two modules: the
//! compute kernels (`compute`, every device) and, built again with the `driver` feature and
//! the ray-tracing capability, the shaders of the driver's ray-tracing pipeline (`driver`,
//! only on devices with VK_KHR_ray_tracing_pipeline: a module declaring the capability would
//! not load elsewhere). Bindings follow the table in `shared::types`.
#![cfg_attr(target_arch = "spirv", no_std)]

/// The scene as the render kernels see it (set 0: world primitives and BVH; set 1: the rest).
macro_rules! world {
    ($tris:ident, $spheres:ident, $nodes:ident, $wide:ident, $order:ident, $instances:ident, $objects:ident, $prim_object:ident, $materials:ident, $lights:ident, $frame:ident, $attrs:ident, $punctual:ident, $env:ident, $textures:ident, $texels:ident, $features:expr) => {
        shared::path::World {
            scene: shared::traverse::Scene {
                tris: $tris,
                spheres: $spheres,
                nodes: $nodes,
                wide: $wide,
                order: $order,
                n_tris: $frame.n_tris,
                n_prims: $frame.n_prims,
                top: $frame.top_nodes,
                instances: $instances,
                n_instances: $frame.n_instances,
                coverage: shared::alpha::Coverage {
                    objects: $objects,
                    prim_object: $prim_object,
                    materials: $materials,
                    attrs: $attrs,
                    textures: $textures,
                    texels: $texels,
                },
                features: $features,
            },
            objects: $objects,
            prim_object: $prim_object,
            materials: $materials,
            lights: $lights,
            frame: $frame,
            attrs: $attrs,
            punctual: $punctual,
            env: $env,
            textures: $textures,
            texels: $texels,
        }
    };
}

#[cfg(not(feature = "driver"))]
pub mod compute;
#[cfg(feature = "driver")]
pub mod driver;
