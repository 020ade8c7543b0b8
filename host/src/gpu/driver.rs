//! The driver's acceleration structures as a second tracer (`--accel driver`,
//! `shared::driver`): every frame a bottom-level structure over the transform stage's
//! world-space triangles (geometry 0, read in place: 16-byte vertices, no index buffer) and
//! the spheres' boxes (geometry 1, written by `sphere_boxes`), a top-level structure of one
//! instance over it, and a ray-tracing pipeline whose ray generation runs `shared`'s path
//! loop. Needs VK_KHR_acceleration_structure and VK_KHR_ray_tracing_pipeline (the device
//! opened with `GpuOptions::ray_tracing`); elsewhere [`DriverTracer::new`] says what is
//! missing.
use super::{Buffer, Commands, Gpu, Kernels, DRIVER_SPV};
use anyhow::{anyhow, bail, ensure, Context, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;
use shared::types::{grid, RenderPush, WORKGROUP};
use std::collections::HashMap;
use std::sync::Arc;

/// The shader stages of the ray-tracing pipeline (they read sets 0 and 1 too).
pub const STAGES: vk::ShaderStageFlags = vk::ShaderStageFlags::from_raw(
    vk::ShaderStageFlags::RAYGEN_KHR.as_raw()
        | vk::ShaderStageFlags::MISS_KHR.as_raw()
        | vk::ShaderStageFlags::CLOSEST_HIT_KHR.as_raw()
        | vk::ShaderStageFlags::ANY_HIT_KHR.as_raw()
        | vk::ShaderStageFlags::INTERSECTION_KHR.as_raw(),
);

/// How the driver builds its bottom-level structure every frame (`--driver-build`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum DriverBuild {
    /// `PREFER_FAST_BUILD`: rebuilt from scratch.
    #[default]
    FastBuild,
    /// `PREFER_FAST_TRACE`: rebuilt from scratch.
    FastTrace,
    /// `ALLOW_UPDATE | PREFER_FAST_BUILD`: built once, then updated in place (a refit: the
    /// topology of the first frame's tree is kept).
    Update,
}

/// The entry points of the driver module, in the pipeline's stage order.
/// Ray generation of the path tracer, and of the ray casts.
pub const PATH_TRACE: &str = "driver::path_trace_driver";
pub const CAST_RAYS: &str = "driver::cast_rays_driver";
const MISS: &str = "driver::miss_driver";
const TRIANGLE_HIT: &str = "driver::triangle_hit_driver";
const TRIANGLE_ALPHA: &str = "driver::triangle_alpha_driver";
const SPHERE_TEST: &str = "driver::sphere_test_driver";
const SPHERE_HIT: &str = "driver::sphere_hit_driver";
const SPHERE_BOXES: &str = "driver::sphere_boxes";

/// A ray-tracing pipeline specialised to one feature set, and its shader binding table.
struct Pipeline {
    raw: vk::Pipeline,
    /// Kept while the pipeline is (the regions point into it).
    _sbt: Buffer,
    /// Raygen, miss and hit regions of `sbt` (the callable one is empty).
    regions: [vk::StridedDeviceAddressRegionKHR; 3],
}

/// An acceleration structure and the buffer holding it.
struct Accel {
    raw: vk::AccelerationStructureKHR,
    buffer: Buffer,
    address: vk::DeviceAddress,
}

/// Hit groups, and the bottom levels' kinds.
const TRIANGLES: u32 = 0;
const SPHERES: u32 = 1;

/// A mesh of the bottom levels: its triangles in the triangle buffer and its spheres in set
/// 0's sphere buffer (whose boxes `sphere_boxes` writes), and whether it changes every frame
/// (a flattened scene's world, an instanced scene's world-space group: built every frame;
/// the rest once).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DriverMesh {
    pub tri0: u32,
    pub n_tris: u32,
    pub sphere0: u32,
    pub n_spheres: u32,
    pub dynamic: bool,
}

/// An instance of the top level: a mesh placed by `rows` (model to world, 3x4 row-major),
/// the custom index the hit shaders read (`shared::driver::FLAT`, or the instance's number).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DriverInstance {
    pub mesh: usize,
    pub rows: [[f32; 4]; 3],
    pub custom: u32,
}

/// What the structures are made of.
pub struct DriverScene<'a> {
    /// The triangles the meshes index (world space, or the meshes' model space).
    pub tris: &'a Buffer,
    pub meshes: Vec<DriverMesh>,
    pub instances: Vec<DriverInstance>,
    /// Spheres in set 0's sphere buffer (all boxed).
    pub n_spheres: u32,
    /// The scene has alpha-tested materials: triangles are not opaque (the any-hit shader).
    pub alpha: bool,
}

impl DriverScene<'_> {
    /// A flattened scene: the world-space `n_tris` triangles of `tris` and `n_spheres`
    /// spheres, one mesh built every frame, placed by the identity.
    pub fn flattened(tris: &Buffer, n_tris: u32, n_spheres: u32, alpha: bool) -> DriverScene<'_> {
        DriverScene {
            tris,
            meshes: vec![DriverMesh {
                tri0: 0,
                n_tris,
                sphere0: 0,
                n_spheres,
                dynamic: true,
            }],
            instances: vec![DriverInstance {
                mesh: 0,
                rows: shared::instance::IDENTITY,
                custom: shared::driver::FLAT,
            }],
            n_spheres,
            alpha,
        }
    }
}

/// A bottom level of one kind of primitive (triangles or spheres' boxes) of one mesh.
struct Bottom {
    accel: Accel,
    /// Its kind: [`TRIANGLES`] or [`SPHERES`], its instances' hit group.
    group: u32,
    count: u32,
    /// The device address of its first vertex or box.
    data: vk::DeviceAddress,
    dynamic: bool,
    /// Where its part of the scratch buffer starts (after the aligned start).
    scratch_at: u64,
}

/// The structures of the scene loaded, and what building them needs.
struct SceneAccel {
    bottoms: Vec<Bottom>,
    /// Each mesh's bottom levels (indices into `bottoms`).
    mesh_bottoms: Vec<Vec<usize>>,
    instances: Vec<DriverInstance>,
    tlas: Accel,
    /// Top-level instances (one per instance and bottom level of its mesh).
    n_top: u32,
    scratch: Buffer,
    /// The top level's instances (host-visible, `VkAccelerationStructureInstanceKHR`).
    instance: Buffer,
    /// The spheres' boxes (`VkAabbPositionsKHR`, 24 bytes each): the bottom levels of
    /// spheres read them, set 2 names them; kept while they are.
    _boxes: Buffer,
    /// Set 2: the top level (binding 0), the boxes (binding 1).
    pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
    n_spheres: u32,
    alpha: bool,
    build: DriverBuild,
    /// Whether the bottom levels were built once (the static ones are then kept; an update
    /// needs a first build).
    built: bool,
    /// Where the top level's part of `scratch` starts (after the aligned start).
    top_scratch_at: u64,
}

/// The driver tracer of one device.
pub struct DriverTracer {
    gpu: Arc<Gpu>,
    accel: ash::khr::acceleration_structure::Device,
    rt: ash::khr::ray_tracing_pipeline::Device,
    module: vk::ShaderModule,
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    boxes_pipeline: vk::Pipeline,
    /// Ray-tracing pipelines by ray generation ([`PATH_TRACE`], [`CAST_RAYS`]) and
    /// specialisation constant.
    pipelines: HashMap<(&'static str, u32), Pipeline>,
    scene: Option<SceneAccel>,
    handle_size: u32,
    handle_align: u32,
    base_align: u32,
    scratch_align: u64,
}

/// `x` rounded up to a multiple of `a` (a power of two).
fn align(x: u64, a: u64) -> u64 {
    x.div_ceil(a.max(1)) * a.max(1)
}

impl DriverTracer {
    /// The driver tracer on `gpu`, or an error naming what the device lacks.
    pub fn new(gpu: &Arc<Gpu>, kernels: &Kernels) -> Result<DriverTracer> {
        if let Err(why) = &gpu.ray_tracing {
            bail!(
                "--accel driver needs the driver's acceleration structures and ray-tracing pipelines: {why} (lavapipe in Debian 12 has none); --accel lbvh traces with the project's own BVH"
            );
        }
        let d = &gpu.device;
        let mut rt_props = vk::PhysicalDeviceRayTracingPipelinePropertiesKHR::default();
        let mut as_props = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
        let mut props = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut rt_props)
            .push_next(&mut as_props);
        // SAFETY: a physical device of this instance.
        unsafe { gpu.instance.get_physical_device_properties2(gpu.physical, &mut props) };
        let mut t = DriverTracer {
            gpu: gpu.clone(),
            accel: ash::khr::acceleration_structure::Device::new(&gpu.instance, d),
            rt: ash::khr::ray_tracing_pipeline::Device::new(&gpu.instance, d),
            module: vk::ShaderModule::null(),
            set_layout: vk::DescriptorSetLayout::null(),
            layout: vk::PipelineLayout::null(),
            boxes_pipeline: vk::Pipeline::null(),
            pipelines: HashMap::new(),
            scene: None,
            handle_size: rt_props.shader_group_handle_size,
            handle_align: rt_props.shader_group_handle_alignment,
            base_align: rt_props.shader_group_base_alignment,
            scratch_align: as_props.min_acceleration_structure_scratch_offset_alignment as u64,
        };
        let words =
            ash::util::read_spv(&mut std::io::Cursor::new(DRIVER_SPV)).context("reading the driver module's SPIR-V")?;
        // SAFETY (all below): valid create infos on a live device; each object is owned by
        // `t` as soon as it exists, so an early return frees it.
        t.module = unsafe { d.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }
            .context("creating the driver module")?;
        let bindings = [
            vk::DescriptorSetLayoutBinding::default()
                .binding(0)
                .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::RAYGEN_KHR),
            vk::DescriptorSetLayoutBinding::default()
                .binding(1)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::COMPUTE),
        ];
        t.set_layout = unsafe {
            d.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings), None)
        }
        .context("creating the driver tracer's set layout")?;
        let sets = [kernels.set_layouts[0], kernels.set_layouts[1], t.set_layout];
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::RAYGEN_KHR)
            .size(size_of::<RenderPush>() as u32)];
        t.layout = unsafe {
            d.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(&sets)
                    .push_constant_ranges(&ranges),
                None,
            )
        }
        .context("creating the driver tracer's pipeline layout")?;
        let name = std::ffi::CString::new(SPHERE_BOXES)?;
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(t.module)
            .name(&name);
        let mut unchecked = gpu.unchecked_buffers();
        let mut one = vk::ComputePipelineCreateInfo::default().stage(stage).layout(t.layout);
        if let Some(u) = unchecked.as_mut() {
            one = one.push_next(u);
        }
        let info = [one];
        t.boxes_pipeline = unsafe { d.create_compute_pipelines(vk::PipelineCache::null(), &info, None) }
            .map_err(|(_, e)| e)
            .context("creating the sphere-box pipeline")?[0];
        Ok(t)
    }

    /// The ray-tracing pipeline of ray generation `raygen` with specialisation constant
    /// `features`, made on first use.
    fn pipeline(&mut self, raygen: &'static str, features: u32) -> Result<&Pipeline> {
        let key = (raygen, features);
        if !self.pipelines.contains_key(&key) {
            let p = self.make_pipeline(raygen, features)?;
            self.pipelines.insert(key, p);
        }
        self.pipelines.get(&key).context("pipeline cache")
    }

    fn make_pipeline(&self, raygen: &str, features: u32) -> Result<Pipeline> {
        let names: Vec<std::ffi::CString> = [raygen, MISS, TRIANGLE_HIT, TRIANGLE_ALPHA, SPHERE_TEST, SPHERE_HIT]
            .iter()
            .map(|n| std::ffi::CString::new(*n))
            .collect::<Result<_, _>>()?;
        let kinds = [
            vk::ShaderStageFlags::RAYGEN_KHR,
            vk::ShaderStageFlags::MISS_KHR,
            vk::ShaderStageFlags::CLOSEST_HIT_KHR,
            vk::ShaderStageFlags::ANY_HIT_KHR,
            vk::ShaderStageFlags::INTERSECTION_KHR,
            vk::ShaderStageFlags::CLOSEST_HIT_KHR,
        ];
        let entries = [vk::SpecializationMapEntry::default().constant_id(0).offset(0).size(4)];
        let data = features.to_ne_bytes();
        let spec = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
        let stages: Vec<_> = names
            .iter()
            .zip(kinds)
            .map(|(n, k)| {
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(k)
                    .module(self.module)
                    .name(n)
                    .specialization_info(&spec)
            })
            .collect();
        let general = |s: u32| {
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::GENERAL)
                .general_shader(s)
                .closest_hit_shader(vk::SHADER_UNUSED_KHR)
                .any_hit_shader(vk::SHADER_UNUSED_KHR)
                .intersection_shader(vk::SHADER_UNUSED_KHR)
        };
        let groups = [
            general(0),
            general(1),
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::TRIANGLES_HIT_GROUP)
                .general_shader(vk::SHADER_UNUSED_KHR)
                .closest_hit_shader(2)
                .any_hit_shader(3)
                .intersection_shader(vk::SHADER_UNUSED_KHR),
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::PROCEDURAL_HIT_GROUP)
                .general_shader(vk::SHADER_UNUSED_KHR)
                .closest_hit_shader(5)
                .any_hit_shader(vk::SHADER_UNUSED_KHR)
                .intersection_shader(4),
        ];
        let mut unchecked = self.gpu.unchecked_buffers();
        let mut one = vk::RayTracingPipelineCreateInfoKHR::default()
            .stages(&stages)
            .groups(&groups)
            .max_pipeline_ray_recursion_depth(1)
            .layout(self.layout);
        if let Some(u) = unchecked.as_mut() {
            one = one.push_next(u);
        }
        let info = [one];
        // SAFETY: valid create info on a device with ray-tracing pipelines.
        let raw = unsafe {
            self.rt.create_ray_tracing_pipelines(
                vk::DeferredOperationKHR::null(),
                vk::PipelineCache::null(),
                &info,
                None,
            )
        }
        .map_err(|(_, e)| e)
        .context("creating the driver tracer's ray-tracing pipeline")?[0];
        // The shader binding table: raygen, miss, two hit groups, each region aligned to the
        // base alignment, records to the handle alignment.
        let (hs, ha, ba) = (
            self.handle_size as u64,
            self.handle_align as u64,
            self.base_align as u64,
        );
        let stride = align(hs, ha);
        let handles = match unsafe {
            self.rt
                .get_ray_tracing_shader_group_handles(raw, 0, groups.len() as u32, groups.len() * hs as usize)
        } {
            Ok(h) => h,
            Err(e) => {
                // SAFETY: the pipeline is unused.
                unsafe { self.gpu.device.destroy_pipeline(raw, None) };
                return Err(anyhow!("reading the shader group handles: {e}"));
            }
        };
        let raygen_at = 0;
        let miss_at = align(stride, ba);
        let hit_at = miss_at + align(stride, ba);
        let size = hit_at + 2 * stride;
        let mut table = vec![0u8; size as usize];
        let handle = |g: usize| &handles[g * hs as usize..(g + 1) * hs as usize];
        for (g, at) in [(0, raygen_at), (1, miss_at), (2, hit_at), (3, hit_at + stride)] {
            table[at as usize..(at + hs) as usize].copy_from_slice(handle(g));
        }
        let mut sbt = Buffer::with_usage(
            &self.gpu,
            "shader binding table",
            size + ba,
            MemoryLocation::CpuToGpu,
            vk::BufferUsageFlags::SHADER_BINDING_TABLE_KHR,
        )?;
        // The table starts at the first base-aligned address of the buffer.
        let base = align(sbt.address(), ba);
        let skip = (base - sbt.address()) as usize;
        let mut bytes = vec![0u8; skip];
        bytes.extend_from_slice(&table);
        sbt.write(&bytes)?;
        let region = |at: u64, stride: u64, size: u64| {
            vk::StridedDeviceAddressRegionKHR::default()
                .device_address(base + at)
                .stride(stride)
                .size(size)
        };
        let raygen_size = align(stride, ba);
        Ok(Pipeline {
            raw,
            _sbt: sbt,
            regions: [
                region(raygen_at, raygen_size, raygen_size),
                region(miss_at, stride, stride),
                region(hit_at, stride, 2 * stride),
            ],
        })
    }

    /// The one geometry of a bottom level of kind `group` over `count` primitives from
    /// device address `data` (triangles: 16-byte vertices; spheres: 24-byte boxes).
    fn geometry(
        group: u32,
        count: u32,
        data: vk::DeviceAddress,
        alpha: bool,
    ) -> vk::AccelerationStructureGeometryKHR<'static> {
        let address = vk::DeviceOrHostAddressConstKHR { device_address: data };
        if group == TRIANGLES {
            let data = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
                .vertex_format(vk::Format::R32G32B32_SFLOAT)
                .vertex_data(address)
                .vertex_stride(16)
                .max_vertex(3 * count - 1)
                .index_type(vk::IndexType::NONE_KHR);
            vk::AccelerationStructureGeometryKHR::default()
                .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
                .geometry(vk::AccelerationStructureGeometryDataKHR { triangles: data })
                .flags(if alpha {
                    vk::GeometryFlagsKHR::empty()
                } else {
                    vk::GeometryFlagsKHR::OPAQUE
                })
        } else {
            let data = vk::AccelerationStructureGeometryAabbsDataKHR::default()
                .data(address)
                .stride(24);
            vk::AccelerationStructureGeometryKHR::default()
                .geometry_type(vk::GeometryTypeKHR::AABBS)
                .geometry(vk::AccelerationStructureGeometryDataKHR { aabbs: data })
                .flags(vk::GeometryFlagsKHR::OPAQUE)
        }
    }

    fn blas_flags(build: DriverBuild) -> vk::BuildAccelerationStructureFlagsKHR {
        use vk::BuildAccelerationStructureFlagsKHR as F;
        match build {
            DriverBuild::FastBuild => F::PREFER_FAST_BUILD,
            DriverBuild::FastTrace => F::PREFER_FAST_TRACE,
            DriverBuild::Update => F::PREFER_FAST_BUILD | F::ALLOW_UPDATE,
        }
    }

    /// The sizes of a structure of type `ty` over `geometry` (one geometry) of `count`
    /// primitives or instances.
    fn sizes(
        &self,
        ty: vk::AccelerationStructureTypeKHR,
        flags: vk::BuildAccelerationStructureFlagsKHR,
        geometry: &[vk::AccelerationStructureGeometryKHR],
        count: u32,
    ) -> vk::AccelerationStructureBuildSizesInfoKHR<'static> {
        let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(ty)
            .flags(flags)
            .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
            .geometries(geometry);
        let mut size = vk::AccelerationStructureBuildSizesInfoKHR::default();
        // SAFETY: valid build info on a device with acceleration structures.
        unsafe {
            self.accel.get_acceleration_structure_build_sizes(
                vk::AccelerationStructureBuildTypeKHR::DEVICE,
                &info,
                &[count],
                &mut size,
            )
        };
        size
    }

    /// Makes an acceleration structure of `size` bytes.
    fn make_accel(&self, name: &str, ty: vk::AccelerationStructureTypeKHR, size: u64) -> Result<Accel> {
        let buffer = Buffer::with_usage(
            &self.gpu,
            name,
            size,
            MemoryLocation::GpuOnly,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR,
        )?;
        let info = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(buffer.raw)
            .size(size)
            .ty(ty);
        // SAFETY: the buffer was made for acceleration-structure storage on this device.
        let raw = unsafe { self.accel.create_acceleration_structure(&info, None) }
            .with_context(|| format!("creating the {name}"))?;
        // SAFETY: as above.
        let address = unsafe {
            self.accel.get_acceleration_structure_device_address(
                &vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(raw),
            )
        };
        Ok(Accel { raw, buffer, address })
    }

    /// Makes the structures for scene `d` (`sets`: sets 0 and 1 of the scene loaded): the
    /// meshes that never change built and compacted now ([`Self::build_static`]), the rest by
    /// every [`Self::record_build`].
    pub fn load(&mut self, d: &DriverScene, build: DriverBuild, sets: [vk::DescriptorSet; 2]) -> Result<()> {
        self.drop_scene();
        let boxes = Buffer::new(
            &self.gpu,
            "sphere boxes",
            24 * d.n_spheres as u64,
            MemoryLocation::GpuOnly,
        )?;
        // A bottom level per mesh and kind (one level holds geometries of one type), each
        // with its part of the scratch buffer; the top level's part after them.
        let (tri_bytes, box_bytes) = (size_of::<shared::types::Triangle>() as u64, 24);
        let mut bottoms = Vec::new();
        let mut mesh_bottoms = Vec::new();
        let mut scratch_end = 0;
        for m in &d.meshes {
            let mut mine = Vec::new();
            let kinds = [
                (TRIANGLES, m.n_tris, d.tris.address() + m.tri0 as u64 * tri_bytes),
                (SPHERES, m.n_spheres, boxes.address() + m.sphere0 as u64 * box_bytes),
            ];
            for (group, count, data) in kinds.into_iter().filter(|k| k.1 > 0) {
                let geometry = [Self::geometry(group, count, data, d.alpha)];
                let size = self.sizes(
                    vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
                    Self::blas_flags(build),
                    &geometry,
                    count,
                );
                mine.push(bottoms.len());
                bottoms.push(Bottom {
                    accel: self.make_accel(
                        "driver's bottom level",
                        vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
                        size.acceleration_structure_size,
                    )?,
                    group,
                    count,
                    data,
                    dynamic: m.dynamic,
                    scratch_at: scratch_end,
                });
                scratch_end += align(
                    size.build_scratch_size.max(size.update_scratch_size),
                    self.scratch_align,
                );
            }
            mesh_bottoms.push(mine);
        }
        let n_top: u32 = d
            .instances
            .iter()
            .map(|i| mesh_bottoms.get(i.mesh).map_or(0, |b| b.len() as u32))
            .sum();
        if n_top == 0 {
            bail!("--accel driver: the scene has no primitives");
        }
        let top = [Self::instance_geometry(0)];
        let top_size = self.sizes(
            vk::AccelerationStructureTypeKHR::TOP_LEVEL,
            vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD,
            &top,
            n_top,
        );
        let tlas = self.make_accel(
            "driver's top level",
            vk::AccelerationStructureTypeKHR::TOP_LEVEL,
            top_size.acceleration_structure_size,
        )?;
        let top_scratch_at = scratch_end;
        let scratch_bytes = self.scratch_align + top_scratch_at + top_size.build_scratch_size;
        let scratch = Buffer::new(
            &self.gpu,
            "driver's build scratch",
            scratch_bytes,
            MemoryLocation::GpuOnly,
        )?;
        let instance = Buffer::new(
            &self.gpu,
            "driver's instances",
            64 * n_top as u64,
            MemoryLocation::CpuToGpu,
        )?;
        let dev = &self.gpu.device;
        let sizes = [
            vk::DescriptorPoolSize::default()
                .ty(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
                .descriptor_count(1),
            vk::DescriptorPoolSize::default()
                .ty(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(1),
        ];
        // SAFETY: valid create and allocate infos; the pool is owned by the scene below.
        let pool = unsafe {
            dev.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&sizes),
                None,
            )
        }
        .context("creating the driver tracer's descriptor pool")?;
        let layouts = [self.set_layout];
        // SAFETY: as above.
        let set = match unsafe {
            dev.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(&layouts),
            )
        } {
            Ok(s) => s[0],
            Err(e) => {
                // SAFETY: nothing uses the pool.
                unsafe { dev.destroy_descriptor_pool(pool, None) };
                return Err(anyhow!("allocating the driver tracer's descriptor set: {e}"));
            }
        };
        let structures = [tlas.raw];
        let mut as_write =
            vk::WriteDescriptorSetAccelerationStructureKHR::default().acceleration_structures(&structures);
        let box_info = [vk::DescriptorBufferInfo::default()
            .buffer(boxes.raw)
            .range(vk::WHOLE_SIZE)];
        let writes = [
            vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(0)
                .descriptor_count(1)
                .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
                .push_next(&mut as_write),
            vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(1)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .buffer_info(&box_info),
        ];
        // SAFETY: the writes name live objects and a set of this device.
        unsafe { dev.update_descriptor_sets(&writes, &[]) };
        self.scene = Some(SceneAccel {
            bottoms,
            mesh_bottoms,
            instances: d.instances.clone(),
            tlas,
            n_top,
            scratch,
            instance,
            _boxes: boxes,
            pool,
            set,
            n_spheres: d.n_spheres,
            alpha: d.alpha,
            build,
            built: false,
            top_scratch_at,
        });
        self.build_static(sets)?;
        self.write_instances()
    }

    /// Builds the bottom levels of the meshes that never change (an instanced scene's, all
    /// but the world-space group) once, with `ALLOW_COMPACTION`, and compacts them: the
    /// driver's size query read back, each copied into a structure of that size (the
    /// forest's and the herd's levels shrink; `bench peer` reports the bytes).
    fn build_static(&mut self, sets: [vk::DescriptorSet; 2]) -> Result<()> {
        let s = self.scene.as_ref().context("no scene loaded for the driver tracer")?;
        let statics: Vec<usize> = (0..s.bottoms.len()).filter(|&i| !s.bottoms[i].dynamic).collect();
        if statics.is_empty() {
            return Ok(());
        }
        let d = &self.gpu.device;
        let mut cmds = Commands::new(&self.gpu)?;
        cmds.begin()?;
        self.record_sphere_boxes(&cmds, sets);
        let flags = Self::blas_flags(s.build) | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
        let n = statics.len() as u32;
        // SAFETY (all below): valid create infos and commands on a live device; the pool is
        // destroyed before returning, the old structures once nothing uses them.
        let pool = unsafe {
            d.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR)
                    .query_count(n),
                None,
            )
        }
        .context("creating the compaction query pool")?;
        let handles: Vec<_> = statics.iter().map(|&i| s.bottoms[i].accel.raw).collect();
        let built = (|| -> Result<Vec<u64>> {
            self.record_bottoms(cmds.cb, s, &statics, flags, false);
            unsafe {
                full_barrier(&self.gpu, cmds.cb);
                d.cmd_reset_query_pool(cmds.cb, pool, 0, n);
                self.accel.cmd_write_acceleration_structures_properties(
                    cmds.cb,
                    &handles,
                    vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                    pool,
                    0,
                );
            }
            cmds.submit_wait()
                .context("building the driver's static bottom levels")?;
            let mut sizes = vec![0u64; n as usize];
            unsafe {
                d.get_query_pool_results(
                    pool,
                    0,
                    &mut sizes,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
            }
            .context("reading the compacted sizes")?;
            Ok(sizes)
        })();
        unsafe { d.destroy_query_pool(pool, None) };
        let sizes = built?;
        let mut compacted = Vec::with_capacity(statics.len());
        for &size in &sizes {
            compacted.push(self.make_accel(
                "driver's compacted bottom level",
                vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
                size,
            )?);
        }
        cmds.begin()?;
        for (&i, c) in statics.iter().zip(&compacted) {
            let info = vk::CopyAccelerationStructureInfoKHR::default()
                .src(s.bottoms[i].accel.raw)
                .dst(c.raw)
                .mode(vk::CopyAccelerationStructureModeKHR::COMPACT);
            unsafe { self.accel.cmd_copy_acceleration_structure(cmds.cb, &info) };
        }
        full_barrier(&self.gpu, cmds.cb);
        cmds.submit_wait().context("compacting the driver's bottom levels")?;
        let s = self.scene.as_mut().context("no scene loaded for the driver tracer")?;
        for (&i, c) in statics.iter().zip(compacted) {
            let old = std::mem::replace(&mut s.bottoms[i].accel, c);
            unsafe { self.accel.destroy_acceleration_structure(old.raw, None) };
        }
        Ok(())
    }

    /// Records `sphere_boxes` over every sphere of set 0 (`sets`: sets 0 and 1) and a
    /// barrier after it.
    fn record_sphere_boxes(&self, cmds: &Commands, sets: [vk::DescriptorSet; 2]) {
        let Some(s) = self.scene.as_ref() else {
            return;
        };
        let d = &self.gpu.device;
        let cb = cmds.cb;
        if s.n_spheres > 0 {
            let (x, y) = grid(s.n_spheres.div_ceil(WORKGROUP));
            // SAFETY: recording state; pipeline, layout and sets belong to this device.
            unsafe {
                d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, self.boxes_pipeline);
                d.cmd_bind_descriptor_sets(
                    cb,
                    vk::PipelineBindPoint::COMPUTE,
                    self.layout,
                    0,
                    &[sets[0], sets[1], s.set],
                    &[],
                );
                d.cmd_dispatch(cb, x, y, 1);
            }
        }
        full_barrier(&self.gpu, cb);
    }

    /// New transforms of the instances (the same instances as loaded, in order): the next
    /// [`Self::record_build`] builds the top level over them.
    pub fn set_instances(&mut self, instances: &[DriverInstance]) -> Result<()> {
        let s = self.scene.as_mut().context("no scene loaded for the driver tracer")?;
        ensure!(
            instances.len() == s.instances.len() && instances.iter().zip(&s.instances).all(|(a, b)| a.mesh == b.mesh),
            "the driver tracer's instances changed: load the scene again"
        );
        s.instances = instances.to_vec();
        self.write_instances()
    }

    /// Writes the top level's instances (`VkAccelerationStructureInstanceKHR`, 64 bytes): the
    /// transform, the custom index and mask 0xff, the hit group of the bottom level's kind,
    /// opaque flags left to the geometries, the bottom level's address.
    fn write_instances(&mut self) -> Result<()> {
        let s = self.scene.as_mut().context("no scene loaded for the driver tracer")?;
        let mut words = Vec::with_capacity(16 * s.n_top as usize);
        for inst in &s.instances {
            for &b in s.mesh_bottoms.get(inst.mesh).map_or(&[][..], |b| b.as_slice()) {
                let bottom = &s.bottoms[b];
                for row in inst.rows {
                    words.extend(row.map(f32::to_bits));
                }
                words.push(inst.custom & 0xff_ffff | 0xff << 24);
                words.push(bottom.group);
                words.push(bottom.accel.address as u32);
                words.push((bottom.accel.address >> 32) as u32);
            }
        }
        s.instance.write(&words)
    }

    /// The top level's one geometry: instances at `address`.
    fn instance_geometry(address: vk::DeviceAddress) -> vk::AccelerationStructureGeometryKHR<'static> {
        vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::INSTANCES)
            .geometry(vk::AccelerationStructureGeometryDataKHR {
                instances: vk::AccelerationStructureGeometryInstancesDataKHR::default().data(
                    vk::DeviceOrHostAddressConstKHR {
                        device_address: address,
                    },
                ),
            })
    }

    /// Device bytes of the structures themselves (bottom and top levels).
    pub fn structure_bytes(&self) -> u64 {
        self.scene.as_ref().map_or(0, |s| {
            s.bottoms.iter().map(|b| b.accel.buffer.size).sum::<u64>() + s.tlas.buffer.size
        })
    }

    /// GPU milliseconds of `runs` builds of both levels over the `n_tris` triangles in `tris`
    /// (no spheres), as `build` says (`bench peer`'s build rows); the structures stay loaded
    /// for the next call with the same input.
    pub fn time_builds(&mut self, tris: &Buffer, n_tris: u32, build: DriverBuild, runs: usize) -> Result<Vec<f64>> {
        let loaded = self
            .scene
            .as_ref()
            .is_some_and(|s| s.build == build && s.n_spheres == 0 && s.bottoms.iter().map(|b| b.count).eq([n_tris]));
        if !loaded {
            self.load(
                &DriverScene::flattened(tris, n_tris, 0, false),
                build,
                [vk::DescriptorSet::null(); 2],
            )?;
        }
        let mut cmds = Commands::new(&self.gpu)?;
        let mut out = Vec::with_capacity(runs);
        for _ in 0..runs {
            cmds.begin()?;
            cmds.timestamp("start");
            // No spheres: the sphere-box kernel, the only user of the sets, does not run.
            self.record_build(&mut cmds, [vk::DescriptorSet::null(); 2])?;
            cmds.submit_wait().context("building the driver's structures")?;
            let t = cmds.timings()?;
            out.push(t.iter().filter(|(l, _)| *l == "build").map(|(_, ns)| ns * 1e-6).sum());
        }
        Ok(out)
    }

    /// Records the builds of bottom levels `which` of `s` (disjoint scratch parts), with
    /// `flags`; `update`: in place from their last build.
    fn record_bottoms(
        &self,
        cb: vk::CommandBuffer,
        s: &SceneAccel,
        which: &[usize],
        flags: vk::BuildAccelerationStructureFlagsKHR,
        update: bool,
    ) {
        if which.is_empty() {
            return;
        }
        let scratch = align(s.scratch.address(), self.scratch_align);
        let geometries: Vec<_> = which
            .iter()
            .map(|&i| {
                let b = &s.bottoms[i];
                [Self::geometry(b.group, b.count, b.data, s.alpha)]
            })
            .collect();
        let infos: Vec<_> = which
            .iter()
            .zip(&geometries)
            .map(|(&i, g)| {
                let b = &s.bottoms[i];
                let (mode, src) = if update {
                    (vk::BuildAccelerationStructureModeKHR::UPDATE, b.accel.raw)
                } else {
                    (
                        vk::BuildAccelerationStructureModeKHR::BUILD,
                        vk::AccelerationStructureKHR::null(),
                    )
                };
                vk::AccelerationStructureBuildGeometryInfoKHR::default()
                    .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
                    .flags(flags)
                    .mode(mode)
                    .src_acceleration_structure(src)
                    .dst_acceleration_structure(b.accel.raw)
                    .geometries(g)
                    .scratch_data(vk::DeviceOrHostAddressKHR {
                        device_address: scratch + b.scratch_at,
                    })
            })
            .collect();
        let ranges: Vec<[vk::AccelerationStructureBuildRangeInfoKHR; 1]> = which
            .iter()
            .map(|&i| [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(s.bottoms[i].count)])
            .collect();
        let range_refs: Vec<&[vk::AccelerationStructureBuildRangeInfoKHR]> = ranges.iter().map(|r| &r[..]).collect();
        // SAFETY: recording state; every address names a live buffer of this device, and the
        // builds' scratch regions are disjoint.
        unsafe { self.accel.cmd_build_acceleration_structures(cb, &infos, &range_refs) };
    }

    /// Records the frame's builds into `cmds` after the transform stage (`sets`: sets 0
    /// and 1): the spheres' boxes; the bottom levels that change every frame (rebuilt, or
    /// updated after the first build with [`DriverBuild::Update`]); the top level.
    pub fn record_build(&mut self, cmds: &mut Commands, sets: [vk::DescriptorSet; 2]) -> Result<()> {
        let s = self.scene.as_ref().context("no scene loaded for the driver tracer")?;
        // The static levels were built (and compacted, their spheres boxed) when the scene
        // was loaded: only the levels that change are built again.
        let todo: Vec<usize> = (0..s.bottoms.len()).filter(|&i| s.bottoms[i].dynamic).collect();
        if todo.iter().any(|&i| s.bottoms[i].group == SPHERES) {
            self.record_sphere_boxes(cmds, sets);
        } else {
            // The transform stage's writes, before the builds read them.
            full_barrier(&self.gpu, cmds.cb);
        }
        let update = s.build == DriverBuild::Update && s.built;
        self.record_bottoms(cmds.cb, s, &todo, Self::blas_flags(s.build), update);
        let s = self.scene.as_mut().context("no scene loaded for the driver tracer")?;
        let cb = cmds.cb;
        let scratch = align(s.scratch.address(), self.scratch_align);
        s.built = true;
        full_barrier(&self.gpu, cb);
        let top = [Self::instance_geometry(s.instance.address())];
        let top_scratch = scratch + s.top_scratch_at;
        let top_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
            .flags(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD)
            .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
            .dst_acceleration_structure(s.tlas.raw)
            .geometries(&top)
            .scratch_data(vk::DeviceOrHostAddressKHR {
                device_address: top_scratch,
            });
        let top_range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(s.n_top)];
        // SAFETY: as above.
        unsafe {
            self.accel
                .cmd_build_acceleration_structures(cb, &[top_info], &[&top_range])
        };
        full_barrier(&self.gpu, cb);
        cmds.timestamp("build");
        Ok(())
    }

    /// Whether the structures were built (a frame recorded since the scene was loaded).
    pub fn built(&self) -> bool {
        self.scene.as_ref().is_some_and(|s| s.built)
    }

    /// Records a launch of ray generation `raygen` ([`PATH_TRACE`]: `push.samples` samples
    /// per pixel over `width` x `height` pixels; [`CAST_RAYS`]: `push.count` queries over
    /// `width`) with the pipeline specialised to `features` (`sets`: sets 0 and 1).
    #[allow(clippy::too_many_arguments)]
    pub fn record_launch(
        &mut self,
        cmds: &mut Commands,
        raygen: &'static str,
        features: u32,
        sets: [vk::DescriptorSet; 2],
        push: &RenderPush,
        width: u32,
        height: u32,
    ) -> Result<()> {
        let set = self
            .scene
            .as_ref()
            .context("no scene loaded for the driver tracer")?
            .set;
        let layout = self.layout;
        let (raw, regions) = {
            let p = self.pipeline(raygen, features)?;
            (p.raw, p.regions)
        };
        let d = &self.gpu.device;
        let cb = cmds.cb;
        let callable = vk::StridedDeviceAddressRegionKHR::default();
        // SAFETY: recording state; pipeline, layout, sets and table belong to this device.
        unsafe {
            d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::RAY_TRACING_KHR, raw);
            d.cmd_bind_descriptor_sets(
                cb,
                vk::PipelineBindPoint::RAY_TRACING_KHR,
                layout,
                0,
                &[sets[0], sets[1], set],
                &[],
            );
            d.cmd_push_constants(
                cb,
                layout,
                vk::ShaderStageFlags::RAYGEN_KHR,
                0,
                bytemuck::bytes_of(push),
            );
            self.rt
                .cmd_trace_rays(cb, &regions[0], &regions[1], &regions[2], &callable, width, height, 1);
        }
        full_barrier(&self.gpu, cb);
        Ok(())
    }

    fn drop_scene(&mut self) {
        if let Some(s) = self.scene.take() {
            // SAFETY: owners wait for GPU work before loading again or dropping.
            unsafe {
                self.gpu.device.destroy_descriptor_pool(s.pool, None);
                for b in &s.bottoms {
                    self.accel.destroy_acceleration_structure(b.accel.raw, None);
                }
                self.accel.destroy_acceleration_structure(s.tlas.raw, None);
            }
        }
    }
}

/// Every earlier write (shaders, transfers, acceleration-structure builds) visible to every
/// later command: the driver tracer's stages between the compute kernels.
fn full_barrier(gpu: &Gpu, cb: vk::CommandBuffer) {
    let m = [vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
        .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)];
    let all = vk::PipelineStageFlags::ALL_COMMANDS;
    // SAFETY: recording state.
    unsafe {
        gpu.device
            .cmd_pipeline_barrier(cb, all, all, vk::DependencyFlags::empty(), &m, &[], &[])
    };
}

impl Drop for DriverTracer {
    fn drop(&mut self) {
        self.drop_scene();
        let d = &self.gpu.device;
        // SAFETY: owners wait for GPU work before dropping.
        unsafe {
            for p in self.pipelines.values() {
                d.destroy_pipeline(p.raw, None);
            }
            d.destroy_pipeline(self.boxes_pipeline, None);
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
            d.destroy_shader_module(self.module, None);
        }
    }
}
