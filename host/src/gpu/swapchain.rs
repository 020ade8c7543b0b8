//! A window surface and its swapchain: the viewer copies the display pass's packed 8-bit
//! pixels straight into the acquired image (no CPU round trip) and presents it. Rebuilt on
//! resize; a zero-size (minimised) window has no swapchain until it has a size again.
use super::{Buffer, Commands, Gpu};
use anyhow::{bail, Context, Result};
use ash::vk;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};
use std::sync::Arc;

pub struct Swapchain {
    gpu: Arc<Gpu>,
    surface_fn: ash::khr::surface::Instance,
    surface: vk::SurfaceKHR,
    swap_fn: ash::khr::swapchain::Device,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    /// Size of the images; 0 x 0 while the window is minimised.
    pub extent: vk::Extent2D,
    pub format: vk::Format,
    /// The format stores blue first: the display pass must pack B, G, R, A.
    pub bgra: bool,
    /// FIFO presentation (tear-free, paced by the display) instead of MAILBOX/IMMEDIATE.
    pub vsync: bool,
    /// Images can be copied back (screenshots of what was presented).
    pub readable: bool,
    /// The swapchain no longer matches the window (resized, suboptimal): rebuild it.
    pub stale: bool,
    acquired: vk::Semaphore,
    /// One per image: the copy into image `i` is done, it may be presented.
    presentable: Vec<vk::Semaphore>,
}

impl Swapchain {
    /// A surface for the window and a swapchain of `size` (the window's inner size).
    pub fn new(
        gpu: &Arc<Gpu>,
        display: RawDisplayHandle,
        window: RawWindowHandle,
        size: (u32, u32),
        vsync: bool,
    ) -> Result<Swapchain> {
        if !gpu.swapchain {
            bail!("the Vulkan device was opened without window support");
        }
        // SAFETY: the handles come from a live window that outlives the swapchain (the viewer
        // drops the swapchain before the window).
        let surface = unsafe { ash_window::create_surface(&gpu.entry, &gpu.instance, display, window, None) }
            .context("creating a Vulkan surface for the window")?;
        let surface_fn = ash::khr::surface::Instance::new(&gpu.entry, &gpu.instance);
        let swap_fn = ash::khr::swapchain::Device::new(&gpu.instance, &gpu.device);
        let mut s = Swapchain {
            gpu: gpu.clone(),
            surface_fn,
            surface,
            swap_fn,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            extent: vk::Extent2D::default(),
            format: vk::Format::UNDEFINED,
            bgra: false,
            vsync,
            readable: false,
            stale: false,
            acquired: vk::Semaphore::null(),
            presentable: Vec::new(),
        };
        // SAFETY: physical device, queue family and surface are live.
        let supported = unsafe {
            s.surface_fn
                .get_physical_device_surface_support(gpu.physical, gpu.queue_family, surface)
        }
        .context("asking whether the device can present to the window")?;
        if !supported {
            bail!("{} cannot present to this window from its compute queue", gpu.name);
        }
        // SAFETY: plain create call on a live device.
        s.acquired = unsafe { gpu.device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }
            .context("creating a semaphore")?;
        s.build(size)?;
        Ok(s)
    }

    /// Makes the swapchain again for a window of `size` (waits for the GPU to be idle).
    pub fn resize(&mut self, size: (u32, u32)) -> Result<()> {
        // SAFETY: waiting on a live device.
        unsafe { self.gpu.device.device_wait_idle() }.context("waiting for the GPU before a resize")?;
        self.build(size)
    }

    fn build(&mut self, size: (u32, u32)) -> Result<()> {
        let (pd, sf) = (self.gpu.physical, &self.surface_fn);
        // SAFETY (queries below): physical device and surface are live.
        let caps = unsafe { sf.get_physical_device_surface_capabilities(pd, self.surface) }
            .context("reading the surface's capabilities")?;
        let formats =
            unsafe { sf.get_physical_device_surface_formats(pd, self.surface) }.context("listing surface formats")?;
        let modes = unsafe { sf.get_physical_device_surface_present_modes(pd, self.surface) }
            .context("listing present modes")?;
        // The display pass already encodes sRGB, so the image must store its bytes unchanged.
        let format = [vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM]
            .into_iter()
            .find_map(|want| formats.iter().find(|f| f.format == want))
            .copied()
            .with_context(|| format!("the window offers no 8-bit UNORM RGBA/BGRA format (it offers {formats:?})"))?;
        if !caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_DST) {
            bail!("the window's images cannot be copied into (no TRANSFER_DST usage)");
        }
        self.readable = caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_SRC);
        let mode = if self.vsync {
            vk::PresentModeKHR::FIFO
        } else {
            [vk::PresentModeKHR::MAILBOX, vk::PresentModeKHR::IMMEDIATE]
                .into_iter()
                .find(|m| modes.contains(m))
                .unwrap_or(vk::PresentModeKHR::FIFO)
        };
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: size.0.clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: size.1.clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        self.destroy_swapchain();
        self.extent = vk::Extent2D::default();
        self.stale = false;
        if extent.width == 0 || extent.height == 0 || size.0 == 0 || size.1 == 0 {
            return Ok(()); // minimised: nothing to present to
        }
        let mut count = caps.min_image_count + 1;
        if caps.max_image_count > 0 {
            count = count.min(caps.max_image_count);
        }
        let mut usage = vk::ImageUsageFlags::TRANSFER_DST;
        if self.readable {
            usage |= vk::ImageUsageFlags::TRANSFER_SRC;
        }
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(format.format)
            .image_color_space(format.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(usage)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            .present_mode(mode)
            .clipped(true);
        // SAFETY: valid create info; the old swapchain was destroyed above.
        self.swapchain = unsafe { self.swap_fn.create_swapchain(&info, None) }.context("creating the swapchain")?;
        // SAFETY: the swapchain was just created.
        self.images =
            unsafe { self.swap_fn.get_swapchain_images(self.swapchain) }.context("listing swapchain images")?;
        while self.presentable.len() < self.images.len() {
            // SAFETY: plain create call on a live device.
            let s = unsafe {
                self.gpu
                    .device
                    .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
            }
            .context("creating a semaphore")?;
            self.presentable.push(s);
        }
        self.extent = extent;
        self.format = format.format;
        self.bgra = format.format == vk::Format::B8G8R8A8_UNORM;
        Ok(())
    }

    /// The next image to draw into, and the semaphore the drawing must wait for; `None`
    /// while minimised or when the swapchain must be rebuilt first (`stale`).
    pub fn acquire(&mut self) -> Result<Option<(u32, vk::Semaphore)>> {
        if self.swapchain == vk::SwapchainKHR::null() || self.stale {
            return Ok(None);
        }
        // SAFETY: live swapchain; `acquired` is unsignalled (its last wait has completed,
        // the viewer waits for every frame before the next).
        let r = unsafe {
            self.swap_fn
                .acquire_next_image(self.swapchain, u64::MAX, self.acquired, vk::Fence::null())
        };
        match r {
            Ok((i, suboptimal)) => {
                self.stale |= suboptimal;
                Ok(Some((i, self.acquired)))
            }
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.stale = true;
                Ok(None)
            }
            Err(e) => Err(e).context("acquiring a swapchain image"),
        }
    }

    /// The semaphore the copy into image `index` signals and its presentation waits for.
    pub fn presentable(&self, index: u32) -> vk::Semaphore {
        self.presentable[index as usize]
    }

    /// Records the copy of `pixels` (packed 8-bit, `extent` sized) into image `index` and,
    /// when given, the copy of that image back into `readback`.
    pub fn record_copy(&self, cmds: &Commands, pixels: &Buffer, index: u32, readback: Option<&Buffer>) {
        let d = &self.gpu.device;
        let image = self.images[index as usize];
        let range = vk::ImageSubresourceRange::default()
            .aspect_mask(vk::ImageAspectFlags::COLOR)
            .level_count(1)
            .layer_count(1);
        let layers = vk::ImageSubresourceLayers::default()
            .aspect_mask(vk::ImageAspectFlags::COLOR)
            .layer_count(1);
        let region = [vk::BufferImageCopy::default()
            .image_subresource(layers)
            .image_extent(vk::Extent3D {
                width: self.extent.width,
                height: self.extent.height,
                depth: 1,
            })];
        let transition = |from, to, src_access, dst_access, src_stage, dst_stage| {
            let b = [vk::ImageMemoryBarrier::default()
                .old_layout(from)
                .new_layout(to)
                .src_access_mask(src_access)
                .dst_access_mask(dst_access)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .image(image)
                .subresource_range(range)];
            // SAFETY: recording state; the image belongs to this swapchain.
            unsafe {
                d.cmd_pipeline_barrier(
                    cmds.cb,
                    src_stage,
                    dst_stage,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &b,
                )
            };
        };
        use vk::{AccessFlags as A, ImageLayout as L, PipelineStageFlags as S};
        transition(
            L::UNDEFINED,
            L::TRANSFER_DST_OPTIMAL,
            A::empty(),
            A::TRANSFER_WRITE,
            S::TRANSFER,
            S::TRANSFER,
        );
        // SAFETY: recording state; the buffer holds `extent` packed pixels (the renderer's
        // image is sized to the swapchain).
        unsafe { d.cmd_copy_buffer_to_image(cmds.cb, pixels.raw, image, L::TRANSFER_DST_OPTIMAL, &region) };
        let mut last = L::TRANSFER_DST_OPTIMAL;
        if let Some(rb) = readback.filter(|_| self.readable) {
            transition(
                last,
                L::TRANSFER_SRC_OPTIMAL,
                A::TRANSFER_WRITE,
                A::TRANSFER_READ,
                S::TRANSFER,
                S::TRANSFER,
            );
            // SAFETY: recording state; `rb` holds `extent` packed pixels.
            unsafe { d.cmd_copy_image_to_buffer(cmds.cb, image, L::TRANSFER_SRC_OPTIMAL, rb.raw, &region) };
            last = L::TRANSFER_SRC_OPTIMAL;
        }
        transition(
            last,
            L::PRESENT_SRC_KHR,
            A::TRANSFER_WRITE | A::TRANSFER_READ,
            A::empty(),
            S::TRANSFER,
            S::BOTTOM_OF_PIPE,
        );
    }

    /// Presents image `index` once its copy is done.
    pub fn present(&mut self, index: u32) -> Result<()> {
        let waits = [self.presentable[index as usize]];
        let chains = [self.swapchain];
        let indices = [index];
        let info = vk::PresentInfoKHR::default()
            .wait_semaphores(&waits)
            .swapchains(&chains)
            .image_indices(&indices);
        // SAFETY: the image was acquired and its copy submitted with `waits` to signal.
        match unsafe { self.swap_fn.queue_present(self.gpu.queue, &info) } {
            Ok(suboptimal) => {
                self.stale |= suboptimal;
                Ok(())
            }
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.stale = true;
                Ok(())
            }
            Err(e) => Err(e).context("presenting a frame"),
        }
    }

    fn destroy_swapchain(&mut self) {
        if self.swapchain != vk::SwapchainKHR::null() {
            // SAFETY: the device is idle (callers wait) and nothing uses the images any more.
            unsafe { self.swap_fn.destroy_swapchain(self.swapchain, None) };
            self.swapchain = vk::SwapchainKHR::null();
            self.images.clear();
        }
    }
}

impl Drop for Swapchain {
    fn drop(&mut self) {
        // SAFETY: after the device is idle nothing uses the swapchain, semaphores or surface.
        unsafe {
            let _ = self.gpu.device.device_wait_idle();
            self.destroy_swapchain();
            for &s in self.presentable.iter().chain([&self.acquired]) {
                if s != vk::Semaphore::null() {
                    self.gpu.device.destroy_semaphore(s, None);
                }
            }
            self.surface_fn.destroy_surface(self.surface, None);
        }
    }
}
