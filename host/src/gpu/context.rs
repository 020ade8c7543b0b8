//! Instance, device selection and logical device, with the features rust-gpu's SPIR-V needs
//! (Vulkan memory model with device scope, 64-bit integers), the Khronos validation layer when
//! asked for and installed, and gpu-allocator for memory.
use anyhow::{anyhow, bail, Context, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to open the GPU.
#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    /// Enable the Khronos validation layer if it is installed.
    pub validation: bool,
    /// Pick the device whose name contains this text, or whose index is this number
    /// (falls back to `RAYTRACE_DEVICE`); otherwise the first discrete GPU.
    pub device: Option<String>,
    /// Ask the driver for per-pipeline statistics (registers, spills...) where it offers
    /// VK_KHR_pipeline_executable_properties.
    pub kernel_stats: bool,
    /// Instance extensions a window surface needs (from `ash_window`); when not empty the
    /// device is also opened with VK_KHR_swapchain.
    pub window_extensions: Vec<&'static CStr>,
    /// Open the device with the driver's acceleration structures and ray-tracing pipelines
    /// (`--accel driver`) where it offers them; [`Gpu::ray_tracing`] says whether it did.
    pub ray_tracing: bool,
}

/// The device extensions the driver tracer needs (`crate::gpu::driver`).
pub const RAY_TRACING_EXTENSIONS: [&CStr; 3] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::ray_tracing_pipeline::NAME,
    ash::khr::deferred_host_operations::NAME,
];

/// A Vulkan device the kernels can run on.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// Index in the loader's list (what `--device` takes).
    pub index: usize,
    pub physical: vk::PhysicalDevice,
    pub queue_family: u32,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period: f64,
    pub name: String,
    pub driver: String,
    pub kind: vk::PhysicalDeviceType,
    pub driver_id: vk::DriverId,
    /// The most bytes one storage-buffer binding may span (`maxStorageBufferRange`).
    pub max_binding: u64,
    /// What a storage-buffer binding's offset must be a multiple of
    /// (`minStorageBufferOffsetAlignment`).
    pub offset_alignment: u64,
    /// Streaming multiprocessors, where the driver says (VK_NV_shader_sm_builtins).
    pub processors: Option<u32>,
}

impl DeviceInfo {
    /// The default choice's order: discrete, integrated, virtual, then the rest (CPU).
    fn rank(&self) -> u32 {
        match self.kind {
            vk::PhysicalDeviceType::DISCRETE_GPU => 0,
            vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
            vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
            _ => 3,
        }
    }

    /// Whether the device runs the kernels on the CPU (lavapipe, SwiftShader).
    pub fn is_cpu(&self) -> bool {
        self.kind == vk::PhysicalDeviceType::CPU
    }

    /// "discrete GPU", "CPU", ...
    pub fn kind_name(&self) -> &'static str {
        match self.kind {
            vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
            vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
            vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
            vk::PhysicalDeviceType::CPU => "CPU implementation",
            _ => "other",
        }
    }
}

/// Messages the validation layer reported as errors.
#[derive(Default)]
pub struct ValidationLog {
    errors: Mutex<Vec<String>>,
}

/// A Vulkan instance (with the validation layer's messenger where asked for), shared by the
/// devices opened from it ([`Gpu::on`]) and destroyed with the last of them.
pub struct Instance {
    entry: ash::Entry,
    instance: ash::Instance,
    validation: bool,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    log: Arc<ValidationLog>,
}

/// An open Vulkan device with one compute queue.
pub struct Gpu {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    /// What `entry` and `instance` belong to (kept alive while the device is).
    shared: Arc<Instance>,
    pub physical: vk::PhysicalDevice,
    pub device: ash::Device,
    pub queue: vk::Queue,
    pub queue_family: u32,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period: f64,
    pub name: String,
    pub driver: String,
    pub validation_enabled: bool,
    pub driver_id: vk::DriverId,
    /// Discrete, integrated, virtual or CPU (lavapipe, SwiftShader).
    pub kind: vk::PhysicalDeviceType,
    /// The most bytes one storage-buffer binding may span (`maxStorageBufferRange`).
    pub max_binding: u64,
    /// What a storage-buffer binding's offset must be a multiple of
    /// (`minStorageBufferOffsetAlignment`).
    pub offset_alignment: u64,
    /// Pipelines capture driver statistics (see `Kernels::statistics`).
    pub kernel_stats: bool,
    /// The device was opened with VK_EXT_pipeline_robustness, so that pipelines can ask for
    /// storage and uniform buffer accesses without bounds checks (see
    /// [`Gpu::unchecked_buffers`]).
    pub pipeline_robustness: bool,
    /// The device was opened with VK_KHR_swapchain (see `GpuOptions::window_extensions`).
    pub swapchain: bool,
    /// The device was opened with acceleration structures, ray-tracing pipelines and buffer
    /// device addresses (`GpuOptions::ray_tracing`); else why not: `Err` names what the
    /// device lacks, or that nobody asked.
    pub ray_tracing: std::result::Result<(), String>,
    pub allocator: Mutex<Option<Allocator>>,
}

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        // SAFETY: the layer passes valid callback data; `user` is the `ValidationLog` that the
        // `Gpu` keeps alive for as long as the messenger exists.
        let (msg, log) = unsafe {
            let p = (*data).p_message;
            let msg = if p.is_null() {
                String::from("(no message)")
            } else {
                CStr::from_ptr(p).to_string_lossy().into_owned()
            };
            (msg, &*(user as *const ValidationLog))
        };
        eprintln!("vulkan validation error: {msg}");
        if let Ok(mut e) = log.errors.lock() {
            e.push(msg);
        }
    }
    vk::FALSE
}

impl Instance {
    /// Loads the Vulkan loader and makes an instance: with the Khronos validation layer if
    /// `validation` and the layer is installed, with the instance extensions a window needs.
    /// Fails with one clear message when no Vulkan loader exists.
    pub fn new(validation: bool, window_extensions: &[&'static CStr]) -> Result<Arc<Instance>> {
        // SAFETY: loading the system Vulkan loader; its entry points are trusted.
        let entry = unsafe { ash::Entry::load() }
            .context("no Vulkan loader found (install libvulkan1 and a driver, e.g. mesa-vulkan-drivers)")?;
        // SAFETY: plain enumeration call.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }.context("enumerating Vulkan layers")?;
        let has_layer = layers
            .iter()
            .any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER));
        let validation = validation && has_layer;
        let app = vk::ApplicationInfo::default()
            .application_name(c"raytrace")
            .api_version(vk::API_VERSION_1_2);
        let layer_ptrs = if validation {
            vec![VALIDATION_LAYER.as_ptr()]
        } else {
            vec![]
        };
        let mut ext_ptrs: Vec<_> = window_extensions.iter().map(|e| e.as_ptr()).collect();
        if validation {
            ext_ptrs.push(ash::ext::debug_utils::NAME.as_ptr());
        }
        let info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layer_ptrs)
            .enabled_extension_names(&ext_ptrs);
        // SAFETY: the create info points at live data.
        let instance = unsafe { entry.create_instance(&info, None) }.context("creating the Vulkan instance")?;
        let log = Arc::new(ValidationLog::default());
        let debug = if validation {
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::ERROR | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(on_message))
                .user_data(Arc::as_ptr(&log) as *mut c_void);
            // SAFETY: the callback's user data outlives the messenger (both owned by `Gpu`).
            let m = unsafe { du.create_debug_utils_messenger(&info, None) }.context("creating the debug messenger")?;
            Some((du, m))
        } else {
            None
        };
        Ok(Arc::new(Instance {
            entry,
            instance,
            validation,
            debug,
            log,
        }))
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        // SAFETY: every device made from the instance holds an `Arc` of it, so none is left.
        unsafe {
            if let Some((du, m)) = self.debug.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

impl Gpu {
    /// Opens the best (or the chosen) Vulkan device. Fails with one clear message when no
    /// Vulkan loader or device exists.
    pub fn new(opts: &GpuOptions) -> Result<Arc<Gpu>> {
        Self::on(&Instance::new(opts.validation, &opts.window_extensions)?, opts)
    }

    /// Opens the best (or the chosen) device of `shared` (several devices of one host share
    /// an instance: made once, and the driver loaded once).
    pub fn on(shared: &Arc<Instance>, opts: &GpuOptions) -> Result<Arc<Gpu>> {
        let instance = shared.instance.clone();
        let (chosen, device, kernel_stats, pipeline_robustness, ray_tracing) = Self::open_device(&instance, opts)?;
        let DeviceInfo {
            physical,
            queue_family,
            timestamp_period,
            name,
            driver,
            driver_id,
            kind,
            max_binding,
            offset_alignment,
            ..
        } = chosen;
        // SAFETY: the device was created with this queue family.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: ray_tracing.is_ok(),
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: nothing was made on the device yet.
                unsafe { device.destroy_device(None) };
                bail!("creating the GPU memory allocator: {e}");
            }
        };
        Ok(Arc::new(Gpu {
            entry: shared.entry.clone(),
            instance,
            shared: shared.clone(),
            physical,
            device,
            queue,
            queue_family,
            timestamp_period,
            name,
            driver,
            validation_enabled: shared.validation,
            driver_id,
            kind,
            max_binding,
            offset_alignment,
            kernel_stats,
            pipeline_robustness,
            swapchain: !opts.window_extensions.is_empty(),
            ray_tracing,
            allocator: Mutex::new(Some(allocator)),
        }))
    }

    /// Every Vulkan device the kernels can run on (Vulkan 1.2, a compute queue with
    /// timestamps), in the loader's order.
    pub fn list() -> Result<Vec<DeviceInfo>> {
        // SAFETY: loading the system Vulkan loader; its entry points are trusted.
        let entry = unsafe { ash::Entry::load() }.context("no Vulkan loader found")?;
        let app = vk::ApplicationInfo::default()
            .application_name(c"raytrace")
            .api_version(vk::API_VERSION_1_2);
        // SAFETY: the create info points at live data.
        let instance =
            unsafe { entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None) }
                .context("creating the Vulkan instance")?;
        let devices = Self::candidates(&instance);
        // SAFETY: nothing else uses the instance.
        unsafe { instance.destroy_instance(None) };
        devices
    }

    fn candidates(instance: &ash::Instance) -> Result<Vec<DeviceInfo>> {
        // SAFETY: plain enumeration call on a live instance.
        let all = unsafe { instance.enumerate_physical_devices() }.context("enumerating Vulkan devices")?;
        let mut candidates = Vec::new();
        for (index, &pd) in all.iter().enumerate() {
            // SAFETY: `pd` comes from this instance.
            let exts = unsafe { instance.enumerate_device_extension_properties(pd) }.unwrap_or_default();
            let sm_ext = ash::nv::shader_sm_builtins::NAME;
            let has_sms = exts
                .iter()
                .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == sm_ext));
            let mut drv = vk::PhysicalDeviceDriverProperties::default();
            let mut sms = vk::PhysicalDeviceShaderSMBuiltinsPropertiesNV::default();
            let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut drv);
            if has_sms {
                props2 = props2.push_next(&mut sms);
            }
            // SAFETY: `pd` comes from this instance; the chain holds only structures of
            // extensions it offers.
            unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
            let props = props2.properties;
            let processors = (has_sms && sms.shader_sm_count > 0).then_some(sms.shader_sm_count);
            let name = props
                .device_name_as_c_str()
                .map(|c| c.to_string_lossy().into_owned())
                .unwrap_or_default();
            let driver = format!(
                "{} {}",
                drv.driver_name_as_c_str()
                    .map(|c| c.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                drv.driver_info_as_c_str()
                    .map(|c| c.to_string_lossy().into_owned())
                    .unwrap_or_default()
            );
            // SAFETY: as above.
            let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
            let Some(qf) = families
                .iter()
                .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0)
            else {
                continue;
            };
            if props.api_version < vk::API_VERSION_1_2 {
                continue;
            }
            candidates.push(DeviceInfo {
                index,
                physical: pd,
                queue_family: qf as u32,
                timestamp_period: props.limits.timestamp_period as f64,
                name,
                driver: driver.trim().to_string(),
                kind: props.device_type,
                driver_id: drv.driver_id,
                max_binding: props.limits.max_storage_buffer_range as u64,
                offset_alignment: props.limits.min_storage_buffer_offset_alignment.max(1),
                processors,
            });
        }
        Ok(candidates)
    }

    #[allow(clippy::type_complexity)]
    fn open_device(
        instance: &ash::Instance,
        opts: &GpuOptions,
    ) -> Result<(DeviceInfo, ash::Device, bool, bool, std::result::Result<(), String>)> {
        // SAFETY: plain enumeration call on a live instance.
        let all = unsafe { instance.enumerate_physical_devices() }.context("enumerating Vulkan devices")?;
        if all.is_empty() {
            bail!("no Vulkan device found (on a machine without a GPU, install Mesa's lavapipe: mesa-vulkan-drivers)");
        }
        let candidates = Self::candidates(instance)?;
        let wanted = opts.device.clone().or_else(|| std::env::var("RAYTRACE_DEVICE").ok());
        let chosen = match &wanted {
            // A number is an index, never part of a name ("1" is in "NVIDIA H100": on a host
            // of two H100s, device 1 was device 0).
            Some(w) => match w.trim().parse::<usize>() {
                Ok(i) => candidates.iter().find(|c| c.index == i),
                Err(_) => candidates
                    .iter()
                    .find(|c| c.name.to_lowercase().contains(&w.to_lowercase())),
            }
            .ok_or_else(|| {
                let names: Vec<_> = candidates.iter().map(|c| format!("{}: {}", c.index, c.name)).collect();
                anyhow!("no Vulkan device matches {w:?}; available: {}", names.join(", "))
            })?,
            None => candidates
                .iter()
                .min_by_key(|c| c.rank())
                .ok_or_else(|| anyhow!("no Vulkan 1.2 device with a compute queue and timestamps found"))?,
        };
        let (pd, name) = (chosen.physical, chosen.name.clone());

        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut f_rt = vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default();
        let mut f_robust = vk::PhysicalDevicePipelineRobustnessFeaturesEXT::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .push_next(&mut f12)
            .push_next(&mut f_as)
            .push_next(&mut f_rt)
            .push_next(&mut f_robust);
        // SAFETY: `pd` comes from this instance.
        unsafe { instance.get_physical_device_features2(pd, &mut f2) };
        let base = f2.features;
        if f12.vulkan_memory_model == 0
            || f12.vulkan_memory_model_device_scope == 0
            || f12.shader_buffer_int64_atomics == 0
            || base.shader_int64 == 0
        {
            bail!("Vulkan device {name} lacks a feature the kernels need (vulkanMemoryModel, vulkanMemoryModelDeviceScope, shaderBufferInt64Atomics, shaderInt64)");
        }
        let mut want12 = vk::PhysicalDeviceVulkan12Features::default()
            .vulkan_memory_model(true)
            .vulkan_memory_model_device_scope(true)
            .shader_buffer_int64_atomics(true);
        let want = vk::PhysicalDeviceFeatures::default().shader_int64(true);
        // SAFETY: `pd` comes from this instance.
        let exts =
            unsafe { instance.enumerate_device_extension_properties(pd) }.context("listing device extensions")?;
        let stats_ext = ash::khr::pipeline_executable_properties::NAME;
        let stats = opts.kernel_stats
            && exts
                .iter()
                .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == stats_ext));
        let mut ext_ptrs = if stats { vec![stats_ext.as_ptr()] } else { vec![] };
        let robust_ext = ash::ext::pipeline_robustness::NAME;
        let robustness = f_robust.pipeline_robustness != 0
            && exts
                .iter()
                .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == robust_ext));
        if robustness {
            ext_ptrs.push(robust_ext.as_ptr());
        }
        let mut want_robust = vk::PhysicalDevicePipelineRobustnessFeaturesEXT::default().pipeline_robustness(true);
        if !opts.window_extensions.is_empty() {
            let sc = ash::khr::swapchain::NAME;
            if !exts.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == sc)) {
                bail!("Vulkan device {name} cannot present to windows (no VK_KHR_swapchain)");
            }
            ext_ptrs.push(sc.as_ptr());
        }
        // The driver tracer's extensions and features, where asked for and offered.
        let has = |n: &CStr| exts.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|x| x == n));
        let missing: Vec<String> = RAY_TRACING_EXTENSIONS
            .iter()
            .filter(|n| !has(n))
            .map(|n| n.to_string_lossy().into_owned())
            .chain((f_as.acceleration_structure == 0).then(|| "the accelerationStructure feature".to_string()))
            .chain((f_rt.ray_tracing_pipeline == 0).then(|| "the rayTracingPipeline feature".to_string()))
            .chain((f12.buffer_device_address == 0).then(|| "the bufferDeviceAddress feature".to_string()))
            .collect();
        let ray_tracing = if !opts.ray_tracing {
            Err("the device was opened without them (GpuOptions::ray_tracing)".to_string())
        } else if missing.is_empty() {
            ext_ptrs.extend(RAY_TRACING_EXTENSIONS.iter().map(|n| n.as_ptr()));
            want12 = want12.buffer_device_address(true);
            Ok(())
        } else {
            Err(format!("{name} lacks {}", missing.join(", ")))
        };
        let mut want_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default().acceleration_structure(true);
        let mut want_rt = vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default().ray_tracing_pipeline(true);
        let mut want_stats =
            vk::PhysicalDevicePipelineExecutablePropertiesFeaturesKHR::default().pipeline_executable_info(true);
        let prio = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(chosen.queue_family)
            .queue_priorities(&prio)];
        let mut info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&want)
            .enabled_extension_names(&ext_ptrs)
            .push_next(&mut want12);
        if stats {
            info = info.push_next(&mut want_stats);
        }
        if robustness {
            info = info.push_next(&mut want_robust);
        }
        if ray_tracing.is_ok() {
            info = info.push_next(&mut want_as).push_next(&mut want_rt);
        }
        // SAFETY: the create info points at live data; the features were checked above.
        let device = unsafe { instance.create_device(pd, &info, None) }
            .with_context(|| format!("creating the Vulkan device on {name}"))?;
        Ok((chosen.clone(), device, stats, robustness, ray_tracing))
    }

    /// The instance the device was opened from, for opening others beside it
    /// ([`Gpu::on`]).
    pub fn shared_instance(&self) -> &Arc<Instance> {
        &self.shared
    }

    /// Validation errors reported so far (empty when validation is off).
    pub fn validation_errors(&self) -> Vec<String> {
        self.shared.log.errors.lock().map(|e| e.clone()).unwrap_or_default()
    }

    /// What a pipeline chains to its create info so that its storage and uniform buffer
    /// accesses go unchecked (VK_EXT_pipeline_robustness), where the device was opened with
    /// it. NVIDIA's driver bounds-checks every buffer access by default even where
    /// robustBufferAccess is off: an address, a compare and a predicated load per 4-byte word
    /// (the pair walk's 64-byte read: sixteen of each). Without the checks the H200 traced
    /// every frame 6-12% faster (bench/NOTES.md, session 53). The kernels index within their
    /// buffers by construction (`shared::sync::at`; the CPU executor runs the same code with
    /// its indices checked).
    pub fn unchecked_buffers(&self) -> Option<vk::PipelineRobustnessCreateInfoEXT<'static>> {
        self.pipeline_robustness.then(|| {
            vk::PipelineRobustnessCreateInfoEXT::default()
                .storage_buffers(vk::PipelineRobustnessBufferBehaviorEXT::DISABLED)
                .uniform_buffers(vk::PipelineRobustnessBufferBehaviorEXT::DISABLED)
        })
    }

    /// Whether the device runs the kernels on the CPU (lavapipe, SwiftShader): the CPU
    /// executor is faster there.
    pub fn is_cpu(&self) -> bool {
        self.kind == vk::PhysicalDeviceType::CPU
    }

    /// True on Mesa's lavapipe (llvmpipe), which runs the kernels on the CPU.
    pub fn is_lavapipe(&self) -> bool {
        self.driver_id == vk::DriverId::MESA_LLVMPIPE
    }

    /// The refit entry point for this device, with or without treelet restructuring, and
    /// the value of its specialisation constant where it has one: lavapipe needs the relaxed
    /// variants (see `shared::refit`).
    pub fn refit_kernel(&self, treelets: bool) -> (super::Kernel, Option<u32>) {
        use super::Kernel::*;
        match (treelets, self.is_lavapipe()) {
            (false, lavapipe) => (Fit, Some(if lavapipe { 0 } else { shared::refit::FIT_ORDERED })),
            (true, false) => (RefitTreelets, None),
            (true, true) => (RefitTreeletsRelaxed, None),
        }
    }

    /// The refit of a restructured tree (`refit_restructured`) for this device, restructuring
    /// again where `treelets` asks, and the value of its specialisation constant.
    pub fn restructured_kernel(&self, treelets: bool) -> (super::Kernel, u32) {
        use shared::refit::{ORDERED_COUNTERS, RESTRUCTURE};
        let ordered = if self.is_lavapipe() { 0 } else { ORDERED_COUNTERS };
        (
            super::Kernel::RefitRestructured,
            ordered | if treelets { RESTRUCTURE } else { 0 },
        )
    }

    /// "name (driver)" for reports.
    pub fn describe(&self) -> String {
        format!("{} ({})", self.name, self.driver)
    }
}

impl Drop for Gpu {
    fn drop(&mut self) {
        // SAFETY: every object created from this device is owned by something holding an
        // `Arc<Gpu>`, so all of them are gone by now.
        unsafe {
            let _ = self.device.device_wait_idle();
            if let Ok(mut a) = self.allocator.lock() {
                a.take();
            }
            self.device.destroy_device(None);
        }
    }
}
