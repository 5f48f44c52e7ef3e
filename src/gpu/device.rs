//! Choosing and describing the physical device: what it supports (features the kernels
//! need, float atomics, subgroup size, limits), which queue family runs compute, and the
//! [`DeviceInfo`] every report carries.

use std::ffi::CStr;

use ash::vk;

use crate::error::{Error, Result, VkContext};

/// What the engine learned about its device.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceInfo {
    pub name: String,
    pub device_type: String,
    pub driver_name: String,
    pub driver_info: String,
    pub api_version: String,
    pub subgroup_size: u32,
    pub max_storage_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    pub max_compute_shared_memory_size: u32,
    pub max_compute_work_group_count: [u32; 3],
    pub max_compute_work_group_invocations: u32,
    pub max_push_constants_size: u32,
    pub timestamp_period_ns: f32,
    pub device_local_heap_bytes: u64,
    /// The device offers VK_EXT_memory_budget ([`Context::memory_budget`](super::Context::memory_budget)).
    pub memory_budget_ext: bool,
    pub features_enabled: Vec<String>,
    pub float_atomic_add: bool,
    pub full_subgroups: bool,
    /// VK_EXT_conditional_rendering is enabled: a recorded iteration can skip its
    /// dispatches on a flag the GPU wrote earlier in the same command buffer (the
    /// trainer's one-submission step).
    pub conditional_rendering: bool,
    pub is_cpu: bool,
}

impl DeviceInfo {
    /// Whether the driver may stop an invocation's loops after a fixed number of
    /// iterations (llvmpipe before Mesa 25 stops them after 65 535 in total and falls
    /// through silently; measured: a 393 000-entry tile composited in one dispatch is
    /// wrong on Mesa 22.3 and right on 25.0). Kernels then split long work into
    /// dispatches. Assumed for every CPU device but llvmpipe of Mesa 25 or later.
    pub fn loop_limit(&self) -> bool {
        if !self.is_cpu {
            return false;
        }
        !(self.driver_name.contains("llvmpipe") && mesa_major(&self.driver_info) >= Some(25))
    }
}

/// Device-dependent tuning, all in one place (what differs between a CPU rasterizer such
/// as llvmpipe and a GPU).
impl DeviceInfo {
    /// Look-back polls before the fallback: CPU devices run one workgroup per thread, so
    /// a short spin costs little and the fallback is cheap; GPUs publish within
    /// microseconds.
    pub fn lookback_spin_limit(&self) -> u32 {
        if self.is_cpu {
            256
        } else {
            4096
        }
    }

    /// Look-back status words each digit of the coalesced sort pass reads at once
    /// ([`crate::sort::RadixSort::set_lookback_window`]): on a GPU a walk over
    /// predecessors costs one memory latency per window instead of one per tile; a CPU
    /// device reads them from its caches, one at a time. 8 (the shader's most) on GPUs:
    /// on the H200 (2026-11-29, 2^24 pairs, `c256`) 3.51 ms against 3.65 with 4 and
    /// 4.27 with 1, each digit walking ~10 predecessors.
    pub fn lookback_window(&self) -> u32 {
        if self.is_cpu {
            1
        } else {
            8
        }
    }

    /// Entries per composite dispatch of the forward: under the loop limit
    /// ([`Self::loop_limit`]: 65 535 trips per invocation) far below it, ≤ ~7 trips per
    /// entry even if nothing unrolls; unbounded (2²²) elsewhere.
    pub fn forward_chunk_entries(&self) -> u32 {
        if self.loop_limit() {
            8192
        } else {
            1 << 22
        }
    }

    /// Entries per segment of a tile's list in the forward composite (0: segments off;
    /// see `Renderer::set_segment_entries`). On a GPU, segments let many workgroups
    /// share a long list, so a small image's few tiles still fill the device; 2048 is
    /// a first choice, not yet measured against others on a GPU. Off on CPU devices,
    /// whose few threads the tiles already keep busy (the extra pass would only cost).
    /// `SVRASTER_SEGMENTS=N` overrides the default on any device, so that a CPU device
    /// can run the suite with a GPU's segmented walks (tests that assume a device's
    /// defaults show up on lavapipe).
    pub fn segment_entries(&self) -> u32 {
        if let Some(n) = std::env::var("SVRASTER_SEGMENTS")
            .ok()
            .and_then(|v| v.trim().parse::<u32>().ok())
        {
            return n;
        }
        if self.is_cpu {
            0
        } else {
            2048
        }
    }

    /// Whether a frame's segment length follows its tile count (at most
    /// [`DeviceInfo::segment_entries`]; `raster::auto_segment_entries`): on GPUs, unless
    /// `SVRASTER_SEGMENTS` fixes it.
    pub fn segments_adapt(&self) -> bool {
        !self.is_cpu && std::env::var_os("SVRASTER_SEGMENTS").is_none()
    }

    /// Entries per backward dispatch: the per-entry work has more loops than the
    /// forward's (samples × corners, and a CAS loop per add without float atomics).
    pub fn backward_chunk_entries(&self, float_atomics: bool) -> u32 {
        match (self.loop_limit(), float_atomics) {
            (false, _) => 1 << 22,
            (true, true) => 2048,
            (true, false) => 1024,
        }
    }
}

/// Major Mesa version in a driver-info string such as "Mesa 25.0.7-2~bpo12+1 (LLVM 15.0.6)".
pub(super) fn mesa_major(driver_info: &str) -> Option<u32> {
    driver_info
        .split_whitespace()
        .skip_while(|w| *w != "Mesa")
        .nth(1)
        .and_then(|v| v.split('.').next())
        .and_then(|m| m.parse::<u32>().ok())
}

pub(super) fn type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

pub(super) fn type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
        vk::PhysicalDeviceType::CPU => "CPU",
        _ => "other",
    }
}

pub(super) fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

pub(super) fn cstr_field(raw: &[std::ffi::c_char]) -> String {
    // SAFETY: Vulkan fixed-size strings are NUL-terminated within their array.
    unsafe { CStr::from_ptr(raw.as_ptr()) }
        .to_string_lossy()
        .into_owned()
}

/// Features a device must support, and which optional ones it has.
pub(super) struct Support {
    pub(super) missing: Vec<&'static str>,
    pub(super) float_atomic_add: bool,
    pub(super) full_subgroups: bool,
    pub(super) conditional_rendering: bool,
}

pub(super) fn query_support(instance: &ash::Instance, pdev: vk::PhysicalDevice) -> Support {
    let props = unsafe { instance.get_physical_device_properties(pdev) };
    let api = props.api_version;
    let mut missing = Vec::new();
    if api < vk::API_VERSION_1_2 {
        missing.push("Vulkan 1.2");
        return Support {
            missing,
            float_atomic_add: false,
            full_subgroups: false,
            conditional_rendering: false,
        };
    }
    let exts = unsafe { instance.enumerate_device_extension_properties(pdev) }.unwrap_or_default();
    let has_ext = |name: &CStr| exts.iter().any(|e| e.extension_name_as_c_str() == Ok(name));
    let has_atomic_float = has_ext(ash::ext::shader_atomic_float::NAME);
    let has_conditional = has_ext(ash::ext::conditional_rendering::NAME);

    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut fa = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
    let mut fc = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12);
    if has_conditional {
        f2 = f2.push_next(&mut fc);
    }
    if api >= vk::API_VERSION_1_3 {
        f2 = f2.push_next(&mut f13);
    }
    if has_atomic_float {
        f2 = f2.push_next(&mut fa);
    }
    unsafe { instance.get_physical_device_features2(pdev, &mut f2) };
    let f10 = f2.features;
    if f10.shader_int64 == 0 {
        missing.push("shaderInt64");
    }
    if f12.buffer_device_address == 0 {
        missing.push("bufferDeviceAddress");
    }
    if f12.shader_buffer_int64_atomics == 0 {
        missing.push("shaderBufferInt64Atomics");
    }
    let mut sg = vk::PhysicalDeviceSubgroupProperties::default();
    let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut sg);
    unsafe { instance.get_physical_device_properties2(pdev, &mut p2) };
    let need_ops = vk::SubgroupFeatureFlags::BASIC
        | vk::SubgroupFeatureFlags::BALLOT
        | vk::SubgroupFeatureFlags::ARITHMETIC
        | vk::SubgroupFeatureFlags::VOTE
        | vk::SubgroupFeatureFlags::SHUFFLE;
    if !sg.supported_stages.contains(vk::ShaderStageFlags::COMPUTE)
        || !sg.supported_operations.contains(need_ops)
    {
        missing.push("subgroup basic/vote/ballot/arithmetic/shuffle in compute");
    }
    if !(8..=128).contains(&sg.subgroup_size) {
        missing.push("subgroup size in 8..=128");
    }
    if props.limits.timestamp_compute_and_graphics == 0 {
        missing.push("timestampComputeAndGraphics");
    }
    let full_subgroups = api >= vk::API_VERSION_1_3
        && f13.subgroup_size_control != 0
        && f13.compute_full_subgroups != 0;
    let float_atomic_add = has_atomic_float
        && fa.shader_buffer_float32_atomics != 0
        && fa.shader_buffer_float32_atomic_add != 0;
    Support {
        missing,
        float_atomic_add,
        full_subgroups,
        conditional_rendering: has_conditional && fc.conditional_rendering != 0,
    }
}

pub(super) fn compute_queue_family(
    instance: &ash::Instance,
    pdev: vk::PhysicalDevice,
) -> Option<u32> {
    let fams = unsafe { instance.get_physical_device_queue_family_properties(pdev) };
    // Prefer a compute queue that also does graphics (the universal queue): it has
    // timestamps everywhere; any compute queue with timestamps otherwise.
    let ok = |f: &vk::QueueFamilyProperties| {
        f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0
    };
    fams.iter()
        .position(|f| ok(f) && f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
        .or_else(|| fams.iter().position(ok))
        .map(|i| i as u32)
}

/// The physical device to run on: `wanted` (an index or a case-insensitive name
/// substring; else `SVRASTER_DEVICE`), or the best of discrete > integrated > virtual >
/// CPU among those with the required features and a compute queue.
pub(super) fn pick_physical_device(
    instance: &ash::Instance,
    wanted: Option<String>,
) -> Result<vk::PhysicalDevice> {
    let pdevs =
        unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
    if pdevs.is_empty() {
        return Err(Error::NoDevice(
                "the Vulkan loader found no device. Install a driver; for a CPU device: `apt-get install mesa-vulkan-drivers` (lavapipe)".into(),
            ));
    }
    let selector = wanted.or_else(|| {
        std::env::var("SVRASTER_DEVICE")
            .ok()
            .filter(|s| !s.is_empty())
    });
    let described: Vec<(vk::PhysicalDevice, String, vk::PhysicalDeviceType)> = pdevs
        .iter()
        .map(|&p| {
            let pr = unsafe { instance.get_physical_device_properties(p) };
            (p, cstr_field(&pr.device_name), pr.device_type)
        })
        .collect();
    let list = described
        .iter()
        .enumerate()
        .map(|(i, (_, n, t))| format!("[{i}] {n} ({})", type_name(*t)))
        .collect::<Vec<_>>()
        .join(", ");
    let pdev = if let Some(sel) = selector {
        let found = match sel.parse::<usize>() {
            Ok(i) => described.get(i).map(|d| d.0),
            Err(_) => described
                .iter()
                .find(|d| d.1.to_lowercase().contains(&sel.to_lowercase()))
                .map(|d| d.0),
        };
        let p = found.ok_or_else(|| {
            Error::NoDevice(format!("no device matches `{sel}`; available: {list}"))
        })?;
        let s = query_support(instance, p);
        if !s.missing.is_empty() {
            let name = described
                .iter()
                .find(|d| d.0 == p)
                .map(|d| d.1.clone())
                .unwrap_or_default();
            return Err(Error::MissingFeatures {
                device: name,
                missing: s.missing.join(", "),
            });
        }
        p
    } else {
        let mut cands: Vec<_> = described
            .iter()
            .filter(|d| {
                query_support(instance, d.0).missing.is_empty()
                    && compute_queue_family(instance, d.0).is_some()
            })
            .collect();
        cands.sort_by_key(|d| type_rank(d.2));
        match cands.first() {
            Some(d) => d.0,
            None => {
                let why = described
                    .iter()
                    .map(|d| {
                        format!(
                            "{}: missing {}",
                            d.1,
                            query_support(instance, d.0).missing.join(", ")
                        )
                    })
                    .collect::<Vec<_>>()
                    .join("; ");
                return Err(Error::NoDevice(format!(
                    "no device has the required features ({why})"
                )));
            }
        }
    };
    Ok(pdev)
}

/// Creates the logical device with one compute queue of family `qf` and the features
/// (and optional extensions) the kernels use.
pub(super) fn create_device(
    instance: &ash::Instance,
    pdev: vk::PhysicalDevice,
    support: &Support,
    qf: u32,
) -> Result<ash::Device> {
    let prio = [1.0f32];
    let qci = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(qf)
        .queue_priorities(&prio)];
    let mut dev_exts: Vec<*const std::ffi::c_char> = Vec::new();
    if support.float_atomic_add {
        dev_exts.push(ash::ext::shader_atomic_float::NAME.as_ptr());
    }
    if support.conditional_rendering {
        dev_exts.push(ash::ext::conditional_rendering::NAME.as_ptr());
    }
    let f10 = vk::PhysicalDeviceFeatures::default().shader_int64(true);
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
        .buffer_device_address(true)
        .shader_buffer_int64_atomics(true);
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
        .subgroup_size_control(true)
        .compute_full_subgroups(true);
    let mut fa = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
        .shader_buffer_float32_atomics(true)
        .shader_buffer_float32_atomic_add(true);
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .features(f10)
        .push_next(&mut f12);
    if support.full_subgroups {
        f2 = f2.push_next(&mut f13);
    }
    if support.float_atomic_add {
        f2 = f2.push_next(&mut fa);
    }
    let mut fc =
        vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default().conditional_rendering(true);
    if support.conditional_rendering {
        f2 = f2.push_next(&mut fc);
    }
    let dci = vk::DeviceCreateInfo::default()
        .queue_create_infos(&qci)
        .enabled_extension_names(&dev_exts)
        .push_next(&mut f2);
    let device = unsafe { instance.create_device(pdev, &dci, None) }.vk("vkCreateDevice")?;
    Ok(device)
}

#[cfg(test)]
mod tests {
    #[test]
    fn mesa_major_from_driver_info() {
        assert_eq!(
            super::mesa_major("Mesa 25.0.7-2~bpo12+1 (LLVM 15.0.6)"),
            Some(25)
        );
        assert_eq!(super::mesa_major("Mesa 22.3.6 (LLVM 15.0.6)"), Some(22));
        assert_eq!(super::mesa_major("SwiftShader 5.0"), None);
        assert_eq!(super::mesa_major("Mesa"), None);
    }
}
