//! `Context`: the Vulkan instance/device the engine runs on, either created here (owned)
//! or borrowed from a host engine that already has one.

use std::ffi::CString;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};

use super::device::{cstr_field, query_support, type_name, version_string, DeviceInfo};
use super::validation::ValidationLog;
use crate::error::{Error, Result};

/// How to create an owned context.
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Device to use: an index into `vkEnumeratePhysicalDevices` or a case-insensitive
    /// substring of the device name. `None` reads `SVRASTER_DEVICE`, then picks
    /// discrete > integrated > virtual > CPU.
    pub device: Option<String>,
    /// Enable `VK_LAYER_KHRONOS_validation` (with synchronization validation). Also
    /// enabled by `SVRASTER_VALIDATION=1`. Every warning or error it reports is counted
    /// (see [`Context::validation_messages`]).
    pub validation: bool,
}

/// Handles of a host engine's Vulkan objects, lent to the engine. The host keeps
/// ownership: dropping the `Context` destroys nothing of these.
///
/// The host must have created the device with API ≥ 1.2 and the features listed by
/// [`Context::required_device_features`]; `Context::borrowed` checks what it can.
pub struct BorrowedHandles {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub physical_device: vk::PhysicalDevice,
    pub device: ash::Device,
    pub queue_family_index: u32,
    pub queue_index: u32,
    /// Whether the host enabled `VK_EXT_debug_utils` on the instance (debug names).
    pub debug_utils: bool,
    /// Optional features the host enabled on the device (see `required_device_features`).
    pub float_atomic_add: bool,
    pub full_subgroups: bool,
    /// The host enabled VK_EXT_conditional_rendering (feature `conditionalRendering`);
    /// without it the trainer takes two submissions per iteration.
    pub conditional_rendering: bool,
}

pub(crate) struct Inner {
    _entry: ash::Entry,
    pub instance: ash::Instance,
    pub physical_device: vk::PhysicalDevice,
    pub device: ash::Device,
    pub queue: vk::Queue,
    pub queue_family: u32,
    pub allocator: Mutex<Option<Allocator>>,
    pub debug_device: Option<ash::ext::debug_utils::Device>,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    validation: Option<*const ValidationLog>,
    owned: bool,
    pub info: DeviceInfo,
    pub pipeline_cache: vk::PipelineCache,
    /// Every kernel's pipeline and layout, made once per context on first use and kept
    /// until the context drops (`Kernel::new` takes them from here; keyed by the
    /// kernel's name and SPIR-V). A renderer, backward or sort made again on the same
    /// context costs no pipeline creation (on lavapipe each one is a shader compile).
    pub(crate) pipelines: Mutex<super::kernel::PipelineRegistry>,
    /// Guards `queue` (Vulkan requires external synchronisation) and the command pool.
    pub submit: Mutex<vk::CommandPool>,
    pub conditional: Option<ash::ext::conditional_rendering::Device>,
    pub(crate) queue_state: super::pending::QueueState,
}

// SAFETY: the raw ValidationLog pointer is only read through `&` and the log is Sync.
unsafe impl Send for Inner {}
unsafe impl Sync for Inner {}

/// A device-local heap's size, budget and usage ([`Context::memory_budget`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBudget {
    pub heap_bytes: u64,
    pub budget_bytes: u64,
    pub usage_bytes: u64,
}

impl MemoryBudget {
    /// What this process may still allocate on the heap.
    pub fn available_bytes(&self) -> u64 {
        self.budget_bytes.saturating_sub(self.usage_bytes)
    }
}

/// The Vulkan device the engine runs on. Cheap to clone (shared handle).
#[derive(Clone)]
pub struct Context {
    pub(crate) inner: Arc<Inner>,
}

impl Context {
    /// Borrows a host engine's instance, device and queue. Nothing of the host's is
    /// destroyed when the context drops; the host must keep them alive longer and must
    /// not use the same queue from another thread while the engine submits to it.
    pub fn borrowed(handles: BorrowedHandles) -> Result<Self> {
        let s = query_support(&handles.instance, handles.physical_device);
        if !s.missing.is_empty() {
            let pr = unsafe {
                handles
                    .instance
                    .get_physical_device_properties(handles.physical_device)
            };
            return Err(Error::MissingFeatures {
                device: cstr_field(&pr.device_name),
                missing: s.missing.join(", "),
            });
        }
        if handles.float_atomic_add && !s.float_atomic_add {
            return Err(Error::Invalid(
                "float_atomic_add claimed but the device lacks it".into(),
            ));
        }
        Self::build(handles, false, None, None)
    }

    /// Instance extensions, device extensions and features a host must enable on the
    /// device it lends (see [`Context::borrowed`]). Returned as names for documentation
    /// and error messages; the feature structs are those of `Context::new`.
    pub fn required_device_features() -> &'static [&'static str] {
        &[
            "Vulkan 1.2",
            "shaderInt64",
            "bufferDeviceAddress",
            "shaderBufferInt64Atomics",
            "subgroup basic/vote/ballot/arithmetic/shuffle in compute",
            "optional: VK_EXT_shader_atomic_float shaderBufferFloat32AtomicAdd",
            "optional: Vulkan 1.3 subgroupSizeControl + computeFullSubgroups",
        ]
    }

    pub(super) fn build(
        h: BorrowedHandles,
        owned: bool,
        messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
        validation: Option<*const ValidationLog>,
    ) -> Result<Self> {
        let instance = h.instance;
        let pdev = h.physical_device;
        let device = h.device;
        let cleanup = |device: &ash::Device| {
            if owned {
                unsafe { device.destroy_device(None) };
            }
        };
        let mut sg = vk::PhysicalDeviceSubgroupProperties::default();
        let mut drv = vk::PhysicalDeviceDriverProperties::default();
        let mut m3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut p2 = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut sg)
            .push_next(&mut drv)
            .push_next(&mut m3);
        unsafe { instance.get_physical_device_properties2(pdev, &mut p2) };
        let props = p2.properties;
        let mem = unsafe { instance.get_physical_device_memory_properties(pdev) };
        let device_local_heap_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
            .iter()
            .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
            .map(|h| h.size)
            .max()
            .unwrap_or(0);
        // VK_EXT_memory_budget is a physical-device query: supported is enough.
        let memory_budget_ext = unsafe { instance.enumerate_device_extension_properties(pdev) }
            .map(|exts| {
                exts.iter()
                    .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::memory_budget::NAME))
            })
            .unwrap_or(false);
        let mut features_enabled: Vec<String> = [
            "shaderInt64",
            "bufferDeviceAddress",
            "shaderBufferInt64Atomics",
            "subgroup basic/vote/ballot/arithmetic/shuffle",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        if h.full_subgroups {
            features_enabled.push("subgroupSizeControl+computeFullSubgroups".into());
        }
        if h.float_atomic_add {
            features_enabled.push("shaderBufferFloat32AtomicAdd".into());
        }
        if h.conditional_rendering {
            features_enabled.push("conditionalRendering".into());
        }
        let info = DeviceInfo {
            name: cstr_field(&props.device_name),
            device_type: type_name(props.device_type).into(),
            driver_name: cstr_field(&drv.driver_name),
            driver_info: cstr_field(&drv.driver_info),
            api_version: version_string(props.api_version),
            subgroup_size: sg.subgroup_size,
            max_storage_buffer_range: props.limits.max_storage_buffer_range as u64,
            max_memory_allocation_size: m3.max_memory_allocation_size,
            max_compute_shared_memory_size: props.limits.max_compute_shared_memory_size,
            max_compute_work_group_count: props.limits.max_compute_work_group_count,
            max_compute_work_group_invocations: props.limits.max_compute_work_group_invocations,
            max_push_constants_size: props.limits.max_push_constants_size,
            timestamp_period_ns: props.limits.timestamp_period,
            device_local_heap_bytes,
            memory_budget_ext,
            features_enabled,
            float_atomic_add: h.float_atomic_add,
            full_subgroups: h.full_subgroups,
            conditional_rendering: h.conditional_rendering,
            is_cpu: props.device_type == vk::PhysicalDeviceType::CPU,
        };
        let allocator = match Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: pdev,
            debug_settings: Default::default(),
            buffer_device_address: true,
            allocation_sizes: Default::default(),
        }) {
            Ok(a) => a,
            Err(e) => {
                cleanup(&device);
                return Err(Error::NoDevice(format!("gpu-allocator: {e}")));
            }
        };
        let queue = unsafe { device.get_device_queue(h.queue_family_index, h.queue_index) };
        let pool = match unsafe {
            device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .queue_family_index(h.queue_family_index)
                    .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                None,
            )
        } {
            Ok(p) => p,
            Err(e) => {
                drop(allocator);
                cleanup(&device);
                return Err(Error::Vulkan {
                    call: "vkCreateCommandPool",
                    result: e,
                });
            }
        };
        let pipeline_cache =
            unsafe { device.create_pipeline_cache(&vk::PipelineCacheCreateInfo::default(), None) }
                .unwrap_or(vk::PipelineCache::null());
        let conditional = h
            .conditional_rendering
            .then(|| ash::ext::conditional_rendering::Device::new(&instance, &device));
        let debug_device = if h.debug_utils {
            Some(ash::ext::debug_utils::Device::new(&instance, &device))
        } else {
            None
        };
        Ok(Context {
            inner: Arc::new(Inner {
                _entry: h.entry,
                instance,
                physical_device: pdev,
                device,
                queue,
                queue_family: h.queue_family_index,
                allocator: Mutex::new(Some(allocator)),
                debug_device,
                messenger,
                validation,
                owned,
                info,
                pipeline_cache,
                pipelines: Mutex::default(),
                submit: Mutex::new(pool),
                conditional,
                queue_state: Default::default(),
            }),
        })
    }

    pub fn info(&self) -> &DeviceInfo {
        &self.inner.info
    }

    /// Kernels whose pipelines this context has made so far (each once: renderers,
    /// backwards and sorts made again on the context take them from its registry).
    pub fn pipelines_made(&self) -> usize {
        self.inner.pipelines.lock().map_or(0, |p| p.len())
    }

    /// The largest device-local heap as VK_EXT_memory_budget reports it now: its size,
    /// the budget the driver gives this process on it and the process's current usage
    /// (all processes' allocations count against the budget). `None` where the device
    /// does not offer the extension.
    pub fn memory_budget(&self) -> Option<MemoryBudget> {
        if !self.inner.info.memory_budget_ext {
            return None;
        }
        let mut b = vk::PhysicalDeviceMemoryBudgetPropertiesEXT::default();
        let mut p = vk::PhysicalDeviceMemoryProperties2::default().push_next(&mut b);
        unsafe {
            self.inner
                .instance
                .get_physical_device_memory_properties2(self.inner.physical_device, &mut p)
        };
        let heaps = p.memory_properties.memory_heaps;
        let n = p.memory_properties.memory_heap_count as usize;
        (0..n)
            .filter(|&i| heaps[i].flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
            .max_by_key(|&i| heaps[i].size)
            .map(|i| MemoryBudget {
                heap_bytes: heaps[i].size,
                budget_bytes: b.heap_budget[i],
                usage_bytes: b.heap_usage[i],
            })
    }
    pub fn device(&self) -> &ash::Device {
        &self.inner.device
    }
    pub fn queue_family(&self) -> u32 {
        self.inner.queue_family
    }
    /// Whether this context created the device (as opposed to borrowing a host's).
    pub fn is_owned(&self) -> bool {
        self.inner.owned
    }

    /// Number of validation warnings/errors reported so far (0 when validation is off).
    pub fn validation_messages(&self) -> u64 {
        self.inner
            .validation
            .map(|p| unsafe { &*p }.count.load(Ordering::SeqCst))
            .unwrap_or(0)
    }
    /// The text of the validation messages reported so far.
    pub fn validation_log(&self) -> Vec<String> {
        self.inner
            .validation
            .and_then(|p| unsafe { &*p }.messages.lock().ok().map(|m| m.clone()))
            .unwrap_or_default()
    }
    pub fn validation_enabled(&self) -> bool {
        self.inner.validation.is_some()
    }

    /// Gives a Vulkan object a debug name (visible in validation messages and tools).
    pub fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.inner.debug_device {
            if let Ok(c) = CString::new(name) {
                let info = vk::DebugUtilsObjectNameInfoEXT::default()
                    .object_handle(handle)
                    .object_name(&c);
                let _ = unsafe { du.set_debug_utils_object_name(&info) };
            }
        }
    }

    /// Device memory the engine's allocator holds (bytes, all memory types), including
    /// the unused parts of its blocks.
    pub fn memory_allocated(&self) -> u64 {
        match self.inner.allocator.lock() {
            Ok(a) => a
                .as_ref()
                .map_or(0, |a| a.generate_report().total_capacity_bytes),
            Err(_) => 0,
        }
    }

    /// Fails if validation reported anything (tests call this at the end).
    pub fn check_validation(&self) -> Result<()> {
        match self.validation_messages() {
            0 => Ok(()),
            n => Err(Error::Validation(n)),
        }
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        unsafe {
            let _ = self.device.device_wait_idle();
            self.queue_state.destroy_in_flight(&self.device);
            self.queue_state
                .free_parked(&self.device, &self.allocator, true);
            if let Ok(pool) = self.submit.lock() {
                self.device.destroy_command_pool(*pool, None);
            }
            if let Ok(mut p) = self.pipelines.lock() {
                p.destroy(&self.device);
            }
            if self.pipeline_cache != vk::PipelineCache::null() {
                self.device
                    .destroy_pipeline_cache(self.pipeline_cache, None);
            }
            if let Ok(mut a) = self.allocator.lock() {
                a.take();
            }
            if self.owned {
                self.device.destroy_device(None);
                if let Some((du, m)) = self.messenger.take() {
                    du.destroy_debug_utils_messenger(m, None);
                }
                self.instance.destroy_instance(None);
                if let Some(log) = self.validation.take() {
                    drop(Box::from_raw(log as *mut ValidationLog));
                }
            }
        }
    }
}
