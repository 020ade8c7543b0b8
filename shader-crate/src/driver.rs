//! The driver module's entry points (`--accel driver`, `shared::driver`): the ray-tracing
//! pipeline's shaders and the compute kernel that boxes the spheres for its bottom level.
//! Sets 0 and 1 are the compute kernels' (the world primitives, the scene); set 2 holds the
//! top-level acceleration structure (binding 0) and the spheres' boxes (binding 1).
use shared::driver::{self, Driver, Payload};
use shared::envmap::EnvEntry;
use shared::instance::Instance;
use shared::path;
use shared::texture::TextureInfo;
use shared::types::{
    flat_index, Frame, Hit, Material, Object, PunctualLight, Ray, RenderPush, Sphere, VertexAttrs, INVALID,
};
use spirv_std::glam::{UVec3, UVec4, Vec2, Vec3};
use spirv_std::ray_tracing::AccelerationStructure;
use spirv_std::spirv;

/// Ray generation: `path::render_pixel` for the launch's pixel, its rays traced by the
/// driver (the compute module's `path_trace` with another [`path::Trace`]).
#[spirv(ray_generation)]
#[allow(clippy::too_many_arguments)]
pub fn path_trace_driver(
    #[spirv(launch_id)] id: UVec3,
    #[spirv(push_constant)] p: &RenderPush,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] nodes: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] wide: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 4)] materials: &[Material],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 5)] lights: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 7)] accum: &mut [[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 8)] image: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 11)] attrs: &[VertexAttrs],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 12)] punctual: &[PunctualLight],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 13)] env: &[EnvEntry],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 14)] textures: &[TextureInfo],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 15)] texels: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 16)] guides: &mut [[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(descriptor_set = 2, binding = 0)] accel: &AccelerationStructure,
    #[spirv(ray_payload)] payload: &mut Payload,
    #[spirv(spec_constant(id = 0, default = 130111))] features: u32,
) {
    let w = world!(
        tris,
        spheres,
        nodes,
        wide,
        order,
        instances,
        objects,
        prim_object,
        materials,
        lights,
        frame,
        attrs,
        punctual,
        env,
        textures,
        texels,
        features
    );
    let mut tracer = Driver { accel, payload };
    path::render_pixel(id.x, id.y, p, &w, &mut tracer, accum, guides, image);
}

/// Ray generation of the ray casts (`path::cast`: picking, the tests' ray sets): one
/// launch per query, `launch_id.x`.
#[spirv(ray_generation)]
#[allow(clippy::too_many_arguments)]
pub fn cast_rays_driver(
    #[spirv(launch_id)] id: UVec3,
    #[spirv(push_constant)] p: &RenderPush,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] tris: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] order: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] nodes: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] wide: &[UVec4],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 4)] materials: &[Material],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 5)] lights: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 9)] rays: &[Ray],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 10)] hits: &mut [Hit],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 11)] attrs: &[VertexAttrs],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 12)] punctual: &[PunctualLight],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 13)] env: &[EnvEntry],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 14)] textures: &[TextureInfo],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 15)] texels: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(descriptor_set = 2, binding = 0)] accel: &AccelerationStructure,
    #[spirv(ray_payload)] payload: &mut Payload,
    #[spirv(spec_constant(id = 0, default = 130111))] features: u32,
) {
    let w = world!(
        tris,
        spheres,
        nodes,
        wide,
        order,
        instances,
        objects,
        prim_object,
        materials,
        lights,
        frame,
        attrs,
        punctual,
        env,
        textures,
        texels,
        features
    );
    let mut tracer = Driver { accel, payload };
    path::cast(id.x, p, &w, &mut tracer, rays, hits);
}

#[spirv(miss)]
pub fn miss_driver(#[spirv(incoming_ray_payload)] out: &mut Payload) {
    *out = Payload {
        hit: Hit::MISS,
        instance: INVALID,
    };
}

#[spirv(closest_hit)]
pub fn triangle_hit_driver(
    #[spirv(primitive_id)] local: u32,
    #[spirv(instance_custom_index)] custom: u32,
    #[spirv(ray_tmax)] t: f32,
    #[spirv(hit_attribute)] bary: &mut Vec2,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(incoming_ray_payload)] out: &mut Payload,
) {
    *out = driver::closest_hit(instances, frame, custom, local, false, t, *bary);
}

/// Alpha-tested triangles (their levels are not opaque where the scene has them).
#[spirv(any_hit)]
#[allow(clippy::too_many_arguments)]
pub fn triangle_alpha_driver(
    #[spirv(primitive_id)] local: u32,
    #[spirv(instance_custom_index)] custom: u32,
    #[spirv(world_ray_origin)] origin: Vec3,
    #[spirv(world_ray_direction)] dir: Vec3,
    #[spirv(hit_attribute)] bary: &mut Vec2,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 0)] objects: &[Object],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 3)] prim_object: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 4)] materials: &[Material],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 11)] attrs: &[VertexAttrs],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 14)] textures: &[TextureInfo],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 15)] texels: &[u32],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(spec_constant(id = 0, default = 130111))] features: u32,
) {
    let c = shared::alpha::Coverage {
        objects,
        prim_object,
        materials,
        attrs,
        textures,
        texels,
    };
    if !driver::covers(&c, instances, frame, custom, local, *bary, origin, dir, features) {
        // SAFETY: called from an any-hit shader.
        unsafe { spirv_std::arch::ignore_intersection() };
    }
}

/// Spheres, tested in their level's space (an instance's model space).
#[spirv(intersection)]
#[allow(clippy::too_many_arguments)]
pub fn sphere_test_driver(
    #[spirv(primitive_id)] local: u32,
    #[spirv(instance_custom_index)] custom: u32,
    #[spirv(object_ray_origin)] origin: Vec3,
    #[spirv(object_ray_direction)] dir: Vec3,
    #[spirv(ray_tmax)] t_max: f32,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(spec_constant(id = 0, default = 130111))] features: u32,
) {
    let t = driver::sphere_t(instances, frame, spheres, custom, local, origin, dir, t_max, features);
    if t < t_max {
        // SAFETY: called from an intersection shader.
        unsafe { spirv_std::arch::report_intersection(t, 0) };
    }
}

#[spirv(closest_hit)]
pub fn sphere_hit_driver(
    #[spirv(primitive_id)] local: u32,
    #[spirv(instance_custom_index)] custom: u32,
    #[spirv(ray_tmax)] t: f32,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 1, binding = 17)] instances: &[Instance],
    #[spirv(incoming_ray_payload)] out: &mut Payload,
) {
    *out = driver::closest_hit(instances, frame, custom, local, true, t, Vec2::ZERO);
}

/// Every sphere's box for the bottom levels of spheres, after the transform stage (a
/// flattened scene's world-space spheres, or the meshes' model-space ones).
#[spirv(compute(threads(256)))]
pub fn sphere_boxes(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] spheres: &[Sphere],
    #[spirv(storage_buffer, descriptor_set = 1, binding = 6)] frame: &Frame,
    #[spirv(storage_buffer, descriptor_set = 2, binding = 1)] boxes: &mut [[f32; 6]],
) {
    let i = flat_index(id.x, id.y);
    let n = frame.n_prims - frame.n_tris;
    if i < n {
        boxes[i as usize] = driver::sphere_box(&spheres[i as usize]);
    }
}
