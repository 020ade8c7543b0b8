//! A `VkBuffer` with its gpu-allocator memory, freed on drop.
use super::Gpu;
use anyhow::{anyhow, Context, Result};
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

pub struct Buffer {
    gpu: Arc<Gpu>,
    pub raw: vk::Buffer,
    pub size: u64,
    /// What it holds (in errors).
    pub name: String,
    alloc: Option<Allocation>,
}

impl Buffer {
    /// A buffer of `size` bytes (at least 4) usable as storage and as copy source/target (on
    /// a device opened for the driver tracer also by device address, and as input of
    /// acceleration-structure builds).
    pub fn new(gpu: &Arc<Gpu>, name: &str, size: u64, location: MemoryLocation) -> Result<Buffer> {
        Self::with_usage(gpu, name, size, location, vk::BufferUsageFlags::empty())
    }

    /// [`Buffer::new`] usable also as `extra` says (acceleration-structure storage, a shader
    /// binding table).
    pub fn with_usage(
        gpu: &Arc<Gpu>,
        name: &str,
        size: u64,
        location: MemoryLocation,
        extra: vk::BufferUsageFlags,
    ) -> Result<Buffer> {
        let size = size.max(4);
        let mut usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST
            | extra;
        if gpu.ray_tracing.is_ok() {
            usage |= vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS
                | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
        }
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let d = &gpu.device;
        // SAFETY: valid create info on a live device.
        let raw = unsafe { d.create_buffer(&info, None) }
            .with_context(|| format!("creating buffer {name} ({size} bytes)"))?;
        // SAFETY: `raw` was just created on this device.
        let requirements = unsafe { d.get_buffer_memory_requirements(raw) };
        let desc = AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        };
        let alloc = gpu
            .allocator
            .lock()
            .map_err(|_| anyhow!("allocator lock poisoned"))?
            .as_mut()
            .ok_or_else(|| anyhow!("allocator already destroyed"))?
            .allocate(&desc);
        let alloc = match alloc {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: the buffer is unused.
                unsafe { d.destroy_buffer(raw, None) };
                return Err(anyhow!("allocating {size} bytes of GPU memory for {name}: {e}"));
            }
        };
        // SAFETY: memory and offset come from an allocation made for these requirements.
        let bound = unsafe { d.bind_buffer_memory(raw, alloc.memory(), alloc.offset()) };
        let buffer = Buffer {
            gpu: gpu.clone(),
            raw,
            size,
            name: name.to_string(),
            alloc: Some(alloc),
        };
        bound.with_context(|| format!("binding memory of buffer {name}"))?;
        Ok(buffer)
    }

    /// The buffer's device address (a device opened for the driver tracer).
    pub fn address(&self) -> vk::DeviceAddress {
        // SAFETY: the buffer was made with SHADER_DEVICE_ADDRESS on such a device.
        unsafe {
            self.gpu
                .device
                .get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(self.raw))
        }
    }

    /// Copies `data` into a host-visible buffer.
    pub fn write<T: Pod>(&mut self, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let dst = self
            .alloc
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .ok_or_else(|| anyhow!("buffer is not host visible"))?;
        anyhow::ensure!(
            bytes.len() <= dst.len(),
            "writing {} bytes into a {}-byte buffer",
            bytes.len(),
            dst.len()
        );
        dst[..bytes.len()].copy_from_slice(bytes);
        Ok(())
    }

    /// Reads `count` elements from a host-visible buffer.
    pub fn read<T: Pod>(&self, count: usize) -> Result<Vec<T>> {
        let mut out = vec![T::zeroed(); count];
        self.read_into(&mut out)?;
        Ok(out)
    }

    /// Fills `out` from the start of a host-visible buffer.
    pub fn read_into<T: Pod>(&self, out: &mut [T]) -> Result<()> {
        let src = self
            .alloc
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .ok_or_else(|| anyhow!("buffer is not host visible"))?;
        let dst: &mut [u8] = bytemuck::cast_slice_mut(out);
        anyhow::ensure!(
            dst.len() <= src.len(),
            "reading {} bytes from a {}-byte buffer",
            dst.len(),
            src.len()
        );
        dst.copy_from_slice(&src[..dst.len()]);
        Ok(())
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // SAFETY: the owner guarantees the GPU no longer uses the buffer (work is waited for
        // before buffers are dropped).
        unsafe { self.gpu.device.destroy_buffer(self.raw, None) };
        if let (Some(a), Ok(mut guard)) = (self.alloc.take(), self.gpu.allocator.lock()) {
            if let Some(alloc) = guard.as_mut() {
                let _ = alloc.free(a);
            }
        }
    }
}
