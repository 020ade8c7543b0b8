//! Compute pipelines for every entry point of the embedded SPIR-V, one shared pipeline layout
//! (set 0: the build's `BINDINGS` storage buffers; set 1: the renderer's `RENDER_BINDINGS`;
//! one push-constant range for `BuildParams`, `RenderPush` or `DenoisePush`), and descriptor sets.
use super::{shader_module, Buffer, Commands, Gpu};
use anyhow::{bail, Context, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;
use shared::types::{BuildParams, RenderPush, FEATURES_ALL, RENDER_BINDINGS, VARIANT_SPLIT_PRODUCTS};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Storage-buffer bindings of set 0 (see `shared::types`).
pub const BINDINGS: usize = 14;

// One push-constant range for every kernel: the largest push.
const _: () = assert!(size_of::<BuildParams>() <= size_of::<RenderPush>());
const _: () = assert!(size_of::<shared::denoise::DenoisePush>() <= size_of::<RenderPush>());

/// Entry points of `shader-crate`.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    BoundsReduce,
    Morton30Counted,
    Morton63Counted,
    SortScatterU32,
    SortScatterU64,
    SortScatterManyU32,
    SortScatterManyU64,
    SortRunsU32,
    SortRunsU64,
    InstanceRunsU32,
    InstanceRunsU64,
    SortMergeU32,
    SortMergeU64,
    KarrasBuildU32,
    KarrasBuildU64,
    PlocU32,
    PlocU64,
    Fit,
    FitWide,
    EmptyBoxes,
    WideWrite,
    PairsWrite,
    RefitTreelets,
    RefitTreeletsRelaxed,
    RefitRestructured,
    Transform,
    TransformBounds,
    InstanceBoxes,
    InstanceBounds,
    PathTrace,
    PathTracePersistent,
    PathStepped,
    PathSteppedPersistent,
    PathQueue,
    PathQueuePersistent,
    ShadowResolve,
    ShadowResolvePersistent,
    AccumGroups,
    DisplayImage,
    CastRays,
    FmaProbe,
    DenoiseTemporal,
    DenoiseVariance,
    DenoiseAtrous,
}

impl Kernel {
    /// The path tracer and the ray casts: kernels specialised to the frame's features.
    pub fn is_tracer(self) -> bool {
        matches!(
            self,
            Kernel::PathTrace
                | Kernel::PathTracePersistent
                | Kernel::PathStepped
                | Kernel::PathSteppedPersistent
                | Kernel::PathQueue
                | Kernel::PathQueuePersistent
                | Kernel::ShadowResolve
                | Kernel::ShadowResolvePersistent
                | Kernel::CastRays
        )
    }

    pub const ALL: [Kernel; 44] = [
        Kernel::BoundsReduce,
        Kernel::Morton30Counted,
        Kernel::Morton63Counted,
        Kernel::SortScatterU32,
        Kernel::SortScatterU64,
        Kernel::SortScatterManyU32,
        Kernel::SortScatterManyU64,
        Kernel::SortRunsU32,
        Kernel::SortRunsU64,
        Kernel::InstanceRunsU32,
        Kernel::InstanceRunsU64,
        Kernel::SortMergeU32,
        Kernel::SortMergeU64,
        Kernel::KarrasBuildU32,
        Kernel::KarrasBuildU64,
        Kernel::PlocU32,
        Kernel::PlocU64,
        Kernel::Fit,
        Kernel::FitWide,
        Kernel::EmptyBoxes,
        Kernel::WideWrite,
        Kernel::PairsWrite,
        Kernel::RefitTreelets,
        Kernel::RefitTreeletsRelaxed,
        Kernel::RefitRestructured,
        Kernel::Transform,
        Kernel::TransformBounds,
        Kernel::InstanceBoxes,
        Kernel::InstanceBounds,
        Kernel::PathTrace,
        Kernel::PathTracePersistent,
        Kernel::PathStepped,
        Kernel::PathSteppedPersistent,
        Kernel::PathQueue,
        Kernel::PathQueuePersistent,
        Kernel::ShadowResolve,
        Kernel::ShadowResolvePersistent,
        Kernel::AccumGroups,
        Kernel::DisplayImage,
        Kernel::CastRays,
        Kernel::FmaProbe,
        Kernel::DenoiseTemporal,
        Kernel::DenoiseVariance,
        Kernel::DenoiseAtrous,
    ];

    /// The entry point's name in the SPIR-V module: its function's path in `shader-crate`.
    pub fn symbol(self) -> String {
        format!("compute::{}", self.entry())
    }

    /// The entry point's function name.
    pub fn entry(self) -> &'static str {
        match self {
            Kernel::BoundsReduce => "bounds_reduce",
            Kernel::Morton30Counted => "morton30_counted",
            Kernel::Morton63Counted => "morton63_counted",
            Kernel::SortScatterU32 => "sort_scatter_u32",
            Kernel::SortScatterU64 => "sort_scatter_u64",
            Kernel::SortScatterManyU32 => "sort_scatter_many_u32",
            Kernel::SortScatterManyU64 => "sort_scatter_many_u64",
            Kernel::SortRunsU32 => "sort_runs_u32",
            Kernel::SortRunsU64 => "sort_runs_u64",
            Kernel::InstanceRunsU32 => "instance_runs_u32",
            Kernel::InstanceRunsU64 => "instance_runs_u64",
            Kernel::SortMergeU32 => "sort_merge_u32",
            Kernel::SortMergeU64 => "sort_merge_u64",
            Kernel::KarrasBuildU32 => "karras_build_u32",
            Kernel::KarrasBuildU64 => "karras_build_u64",
            Kernel::PlocU32 => "ploc_u32",
            Kernel::PlocU64 => "ploc_u64",
            Kernel::Fit => "fit",
            Kernel::FitWide => "fit_wide",
            Kernel::EmptyBoxes => "empty_boxes",
            Kernel::WideWrite => "wide_write",
            Kernel::PairsWrite => "pairs_write",
            Kernel::RefitTreelets => "refit_treelets",
            Kernel::RefitTreeletsRelaxed => "refit_treelets_relaxed",
            Kernel::RefitRestructured => "refit_restructured",
            Kernel::Transform => "transform",
            Kernel::TransformBounds => "transform_bounds",
            Kernel::InstanceBoxes => "instance_boxes",
            Kernel::InstanceBounds => "instance_bounds",
            Kernel::PathTrace => "path_trace",
            Kernel::PathTracePersistent => "path_trace_persistent",
            Kernel::PathStepped => "path_stepped",
            Kernel::PathSteppedPersistent => "path_stepped_persistent",
            Kernel::PathQueue => "path_queue",
            Kernel::PathQueuePersistent => "path_queue_persistent",
            Kernel::ShadowResolve => "shadow_resolve",
            Kernel::ShadowResolvePersistent => "shadow_resolve_persistent",
            Kernel::AccumGroups => "accum_groups",
            Kernel::DisplayImage => "display_image",
            Kernel::CastRays => "cast_rays",
            Kernel::FmaProbe => "fma_probe",
            Kernel::DenoiseTemporal => "denoise_temporal",
            Kernel::DenoiseVariance => "denoise_variance",
            Kernel::DenoiseAtrous => "denoise_atrous",
        }
    }
}

/// A pipeline's entry point and the value of its specialisation constant 0, if set.
type PipelineKey = (Kernel, Option<u32>);

/// A pipeline once made (or why it could not be).
type PipelineCell = OnceLock<Result<vk::Pipeline, String>>;

/// All compute pipelines and their shared layout.
pub struct Kernels {
    gpu: Arc<Gpu>,
    /// Layouts of set 0 (build) and set 1 (render).
    pub set_layouts: [vk::DescriptorSetLayout; 2],
    pub layout: vk::PipelineLayout,
    /// Every pipeline, made when first asked for (a flattened render uses 8 of the 34 compute entry points),
    /// each from its entry point's own module, with the value of
    /// specialisation constant 0 where it is set. Each is made outside the map's lock, once:
    /// a second ask waits for the first (see [`Kernels::make_soon`]).
    pipelines: Mutex<HashMap<PipelineKey, Arc<PipelineCell>>>,
    /// Host seconds each pipeline took to make, in the order they were made.
    made_log: Mutex<Vec<(Kernel, f64)>>,
    /// Whether the device's GLSL `Fma` rounds once (see [`Kernels::specialised`]).
    pub fused_fma: bool,
}

impl Kernels {
    pub fn new(gpu: &Arc<Gpu>) -> Result<Kernels> {
        let d = &gpu.device;
        let mut k = Kernels {
            gpu: gpu.clone(),
            set_layouts: [vk::DescriptorSetLayout::null(); 2],
            layout: vk::PipelineLayout::null(),
            pipelines: Mutex::new(HashMap::new()),
            made_log: Mutex::new(Vec::new()),
            fused_fma: true,
        };
        // SAFETY (all calls below): valid create infos on a live device; objects are owned by
        // `k` as soon as they exist, so an early return frees them.
        // The driver tracer's shaders read the same sets (`crate::gpu::driver`).
        let stages = if gpu.ray_tracing.is_ok() {
            vk::ShaderStageFlags::COMPUTE | super::driver::STAGES
        } else {
            vk::ShaderStageFlags::COMPUTE
        };
        for (set, count) in [BINDINGS as u32, RENDER_BINDINGS].into_iter().enumerate() {
            let bindings: Vec<_> = (0..count)
                .map(|b| {
                    vk::DescriptorSetLayoutBinding::default()
                        .binding(b)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .descriptor_count(1)
                        .stage_flags(stages)
                })
                .collect();
            k.set_layouts[set] = unsafe {
                d.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings), None)
            }
            .with_context(|| format!("creating the layout of descriptor set {set}"))?;
        }
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .size(size_of::<RenderPush>() as u32)];
        let layouts = k.set_layouts;
        k.layout = unsafe {
            d.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(&layouts)
                    .push_constant_ranges(&ranges),
                None,
            )
        }
        .context("creating the pipeline layout")?;
        k.fused_fma = k.probe_fma().context("probing the device's fma")?;
        Ok(k)
    }

    /// Whether the device's GLSL `Fma` rounds once, as the kernels' exact products assume:
    /// Vulkan lets it round twice (llvmpipe's does). `fma_probe` computes
    /// `(1 + 2^-12) (1 + 2^-12) - (1 + 2^-11)`: `2^-24` fused, `0` rounded twice.
    fn probe_fma(&self) -> Result<bool> {
        let x = 1.0 + f32::powi(2.0, -12);
        let mut io = Buffer::new(&self.gpu, "fma probe", 16, MemoryLocation::GpuToCpu)?;
        io.write(&[x, x, -(1.0 + f32::powi(2.0, -11)), f32::NAN])?;
        let set = BindingSets::new(&self.gpu, self, 0, &[&[&io; BINDINGS]])?;
        let mut cmds = Commands::new(&self.gpu)?;
        cmds.begin()?;
        cmds.dispatch_sets(self, &set.sets, Kernel::FmaProbe, &[0; 16], 1, 1)?;
        cmds.barrier();
        cmds.submit_wait()?;
        let r: Vec<f32> = io.read(4)?;
        Ok(r[3] == f32::powi(2.0, -24))
    }

    /// A pipeline of `kernel`, with specialisation constant 0 set to `constant` if given.
    fn create_pipeline(&self, kernel: Kernel, constant: Option<u32>) -> Result<vk::Pipeline> {
        let symbol = kernel.symbol();
        let bytes = shader_module(&symbol).with_context(|| format!("no SPIR-V module for entry point {symbol}"))?;
        let words = ash::util::read_spv(&mut std::io::Cursor::new(bytes))
            .with_context(|| format!("reading the SPIR-V module of {symbol}"))?;
        let d = &self.gpu.device;
        // SAFETY: valid create info on a live device; the module is destroyed below, once the
        // pipeline that reads it is made (Vulkan allows it then).
        let module = unsafe { d.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }
            .with_context(|| format!("creating the shader module of {symbol}"))?;
        let made = self.create_pipeline_from(module, &symbol, kernel, constant);
        // SAFETY: no pipeline is being made from it any more.
        unsafe { d.destroy_shader_module(module, None) };
        made
    }

    /// [`Kernels::create_pipeline`] from `module`, which holds `symbol`.
    fn create_pipeline_from(
        &self,
        module: vk::ShaderModule,
        symbol: &str,
        kernel: Kernel,
        constant: Option<u32>,
    ) -> Result<vk::Pipeline> {
        let name = std::ffi::CString::new(symbol)?;
        let entries = [vk::SpecializationMapEntry::default().constant_id(0).offset(0).size(4)];
        let data = constant.unwrap_or(0).to_ne_bytes();
        let spec = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
        let mut stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(&name);
        if constant.is_some() {
            stage = stage.specialization_info(&spec);
        }
        let flags = if self.gpu.kernel_stats {
            vk::PipelineCreateFlags::CAPTURE_STATISTICS_KHR
        } else {
            vk::PipelineCreateFlags::empty()
        };
        let mut unchecked = self.gpu.unchecked_buffers();
        let mut one = vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(self.layout)
            .flags(flags);
        if let Some(u) = unchecked.as_mut() {
            one = one.push_next(u);
        }
        let info = [one];
        // SAFETY: valid create info on a live device; the caller owns the pipeline.
        let p = unsafe {
            self.gpu
                .device
                .create_compute_pipelines(vk::PipelineCache::null(), &info, None)
        }
        .map_err(|(_, e)| e)
        .with_context(|| format!("creating the compute pipeline of entry point {}", kernel.entry()))?;
        Ok(p[0])
    }

    /// `kernel` specialised to `constant` (its specialisation constant 0: the path tracer's
    /// `FEATURE_*` and `VARIANT_*` bits; the fit's ordering), made on first use and kept. On a
    /// device whose `fma` rounds twice [`VARIANT_SPLIT_PRODUCTS`] is added to a tracer's.
    pub fn specialised(&self, kernel: Kernel, constant: u32) -> Result<vk::Pipeline> {
        let constant = if kernel.is_tracer() {
            self.tracer_constant(constant)
        } else {
            constant
        };
        self.made(kernel, Some(constant))
    }

    /// A tracer's specialisation constant on this device: `features`, with
    /// [`VARIANT_SPLIT_PRODUCTS`] where the device's `fma` rounds twice.
    pub fn tracer_constant(&self, features: u32) -> u32 {
        if self.fused_fma {
            features
        } else {
            features | VARIANT_SPLIT_PRODUCTS
        }
    }

    /// The pipeline of `kernel` with `constant`, made if it is the first ask.
    fn made(&self, kernel: Kernel, constant: Option<u32>) -> Result<vk::Pipeline> {
        let cell = self
            .pipelines
            .lock()
            .map_err(|_| anyhow::anyhow!("pipeline cache lock poisoned"))?
            .entry((kernel, constant))
            .or_default()
            .clone();
        let made = cell.get_or_init(|| {
            let t = Instant::now();
            let p = self.create_pipeline(kernel, constant).map_err(|e| format!("{e:#}"));
            if let Ok(mut log) = self.made_log.lock() {
                log.push((kernel, t.elapsed().as_secs_f64()));
            }
            p
        });
        made.clone().map_err(anyhow::Error::msg)
    }

    /// Starts making the pipeline of the tracer `kernel` specialised to `features` (as
    /// [`Kernels::specialised`] would) on a thread of its own, unless it is made or being
    /// made: the driver takes tens of milliseconds for the path tracer's, which the caller can
    /// spend recording work that needs other pipelines. An ask for it meanwhile waits for it.
    pub fn make_soon(self: &Arc<Self>, kernel: Kernel, features: u32) {
        let key = (kernel, Some(self.tracer_constant(features)));
        let started = self.pipelines.lock().is_ok_and(|p| p.contains_key(&key));
        if !started {
            let k = self.clone();
            std::thread::spawn(move || {
                let _ = k.specialised(kernel, features);
            });
        }
    }

    /// Host seconds each pipeline made so far took, in the order they were made.
    pub fn made_log(&self) -> Vec<(Kernel, f64)> {
        self.made_log.lock().map(|l| l.clone()).unwrap_or_default()
    }

    /// The driver's statistics of every pipeline, as "name: value" strings (empty unless the
    /// GPU was opened with `kernel_stats` and the driver offers them).
    pub fn statistics(&self) -> Result<Vec<(&'static str, Vec<String>)>> {
        if !self.gpu.kernel_stats {
            return Ok(Vec::new());
        }
        let mut out = Vec::new();
        for kernel in Kernel::ALL {
            let pipeline = if kernel.is_tracer() {
                self.specialised(kernel, FEATURES_ALL)?
            } else {
                self.pipeline(kernel)?
            };
            out.push((kernel.entry(), self.pipeline_statistics(pipeline)?));
        }
        Ok(out)
    }

    /// The driver's statistics of `kernel` specialised to `constant` (see [`Self::specialised`]);
    /// empty as for [`Self::statistics`].
    pub fn specialised_statistics(&self, kernel: Kernel, constant: u32) -> Result<Vec<String>> {
        if !self.gpu.kernel_stats {
            return Ok(Vec::new());
        }
        self.pipeline_statistics(self.specialised(kernel, constant)?)
    }

    fn pipeline_statistics(&self, pipeline: vk::Pipeline) -> Result<Vec<String>> {
        let ext = ash::khr::pipeline_executable_properties::Device::new(&self.gpu.instance, &self.gpu.device);
        let info = vk::PipelineExecutableInfoKHR::default()
            .pipeline(pipeline)
            .executable_index(0);
        // SAFETY: the pipeline was created with CAPTURE_STATISTICS on a device with the
        // extension enabled.
        let stats = unsafe { ext.get_pipeline_executable_statistics(&info) }.context("reading pipeline statistics")?;
        Ok(stats
            .iter()
            .map(|st| {
                let name = st
                    .name_as_c_str()
                    .map(|c| c.to_string_lossy().into_owned())
                    .unwrap_or_default();
                // SAFETY: the union member read is the one `format` names.
                let value = unsafe {
                    match st.format {
                        vk::PipelineExecutableStatisticFormatKHR::BOOL32 => format!("{}", st.value.b32),
                        vk::PipelineExecutableStatisticFormatKHR::INT64 => format!("{}", st.value.i64),
                        vk::PipelineExecutableStatisticFormatKHR::UINT64 => format!("{}", st.value.u64),
                        _ => format!("{}", st.value.f64),
                    }
                };
                format!("{name}: {value}")
            })
            .collect())
    }

    /// The unspecialised pipeline of `k`, made on first use. Not of a tracer: those run only
    /// specialised ([`Self::specialised`]), and their unspecialised pipelines, the largest by
    /// far, would cost lavapipe a minute to compile.
    pub fn pipeline(&self, k: Kernel) -> Result<vk::Pipeline> {
        if k.is_tracer() {
            bail!("{} runs only specialised", k.entry());
        }
        self.made(k, None)
    }
}

impl Drop for Kernels {
    fn drop(&mut self) {
        let d = &self.gpu.device;
        // SAFETY: owners wait for GPU work before dropping the kernels.
        unsafe {
            if let Ok(cache) = self.pipelines.lock() {
                for p in cache.values().filter_map(|c| c.get()?.as_ref().ok()) {
                    d.destroy_pipeline(*p, None);
                }
            }
            d.destroy_pipeline_layout(self.layout, None);
            for &l in &self.set_layouts {
                d.destroy_descriptor_set_layout(l, None);
            }
        }
    }
}

/// A descriptor pool holding descriptor sets of one of the shared set layouts, each naming
/// one buffer per binding.
pub struct BindingSets {
    gpu: Arc<Gpu>,
    pool: vk::DescriptorPool,
    pub sets: Vec<vk::DescriptorSet>,
}

impl BindingSets {
    /// Sets of layout `layout` (0: build, 1: render), binding `i` of each naming `buffers[i]`.
    pub fn new(gpu: &Arc<Gpu>, kernels: &Kernels, layout: usize, sets: &[&[&Buffer]]) -> Result<BindingSets> {
        // A binding past the device's limit is not an error Vulkan reports: kernels would read
        // wrong data, or nothing.
        if let Some(b) = sets.iter().flat_map(|s| s.iter()).find(|b| b.size > gpu.max_binding) {
            bail!(
                "the {} buffer needs {:.1} MB in one binding, and {} binds at most {:.1} MB (maxStorageBufferRange): the scene or image is too large for this device",
                b.name,
                b.size as f64 / 1e6,
                gpu.name,
                gpu.max_binding as f64 / 1e6
            );
        }
        let d = &gpu.device;
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(sets.iter().map(|s| s.len() as u32).sum::<u32>().max(1))];
        // SAFETY: valid create info; the pool is owned by the returned value.
        let pool = unsafe {
            d.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(sets.len() as u32)
                    .pool_sizes(&sizes),
                None,
            )
        }
        .context("creating a descriptor pool")?;
        let mut out = BindingSets {
            gpu: gpu.clone(),
            pool,
            sets: Vec::new(),
        };
        let layouts = vec![kernels.set_layouts[layout]; sets.len()];
        // SAFETY: the pool has room for these sets.
        out.sets = unsafe {
            d.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(&layouts),
            )
        }
        .context("allocating descriptor sets")?;
        for (set, buffers) in out.sets.iter().zip(sets) {
            let infos: Vec<_> = buffers
                .iter()
                .map(|b| [vk::DescriptorBufferInfo::default().buffer(b.raw).range(vk::WHOLE_SIZE)])
                .collect();
            let writes: Vec<_> = infos
                .iter()
                .enumerate()
                .map(|(i, info)| {
                    vk::WriteDescriptorSet::default()
                        .dst_set(*set)
                        .dst_binding(i as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(info)
                })
                .collect();
            // SAFETY: every write names a live buffer and a set of this pool.
            unsafe { d.update_descriptor_sets(&writes, &[]) };
        }
        Ok(out)
    }
}

impl BindingSets {
    /// Binding `binding` of set `set` names `buf` from byte `offset` on (a multiple of the
    /// device's `offset_alignment`), instead of what it named. No command recorded with the
    /// set may be pending.
    pub fn rebind(&self, set: usize, binding: u32, buf: vk::Buffer, offset: u64) {
        let info = [vk::DescriptorBufferInfo::default()
            .buffer(buf)
            .offset(offset)
            .range(vk::WHOLE_SIZE)];
        let write = vk::WriteDescriptorSet::default()
            .dst_set(self.sets[set])
            .dst_binding(binding)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&info);
        // SAFETY: a live buffer and a set of this pool, not in use (the caller's word).
        unsafe { self.gpu.device.update_descriptor_sets(&[write], &[]) };
    }
}

impl Drop for BindingSets {
    fn drop(&mut self) {
        // SAFETY: owners wait for GPU work before dropping; destroying the pool frees its sets.
        unsafe { self.gpu.device.destroy_descriptor_pool(self.pool, None) };
    }
}
