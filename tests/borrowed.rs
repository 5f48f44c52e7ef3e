//! Embedding: a host engine creates its own ash instance/device (with validation and its
//! own debug messenger), lends them to the engine, and records the sort into a command
//! buffer it owns and submits itself.

mod common;

use std::ffi::{c_void, CStr};
use std::sync::atomic::{AtomicU64, Ordering};

use ash::vk;
use svraster::gpu::{BorrowedHandles, Context};
use svraster::sort::{Count, RadixSort, SortScratch};

static HOST_VALIDATION_MESSAGES: AtomicU64 = AtomicU64::new(0);

unsafe extern "system" fn host_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _ty: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user: *mut c_void,
) -> vk::Bool32 {
    if severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    ) {
        HOST_VALIDATION_MESSAGES.fetch_add(1, Ordering::SeqCst);
        let msg = CStr::from_ptr((*data).p_message).to_string_lossy();
        eprintln!("[host validation] {msg}");
    }
    vk::FALSE
}

#[test]
fn sort_on_a_borrowed_device_in_a_host_command_buffer() {
    unsafe {
        let entry = ash::Entry::load().expect("libvulkan");
        let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
        let exts = [ash::ext::debug_utils::NAME.as_ptr()];
        let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
        let instance = entry
            .create_instance(
                &vk::InstanceCreateInfo::default()
                    .application_info(&app)
                    .enabled_layer_names(&layers)
                    .enabled_extension_names(&exts),
                None,
            )
            .expect("host instance (needs vulkan-validationlayers)");
        let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
        let messenger = du
            .create_debug_utils_messenger(
                &vk::DebugUtilsMessengerCreateInfoEXT::default()
                    .message_severity(
                        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                    )
                    .message_type(
                        vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                            | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL,
                    )
                    .pfn_user_callback(Some(host_callback)),
                None,
            )
            .unwrap();

        // The host picks a device and a compute queue family and enables what the engine
        // documents as required (Context::required_device_features).
        let pdev = instance.enumerate_physical_devices().unwrap()[0];
        let qf = instance
            .get_physical_device_queue_family_properties(pdev)
            .iter()
            .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
            .unwrap() as u32;
        let prio = [1.0f32];
        let qci = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(qf)
            .queue_priorities(&prio)];
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .buffer_device_address(true)
            .shader_buffer_int64_atomics(true);
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .features(vk::PhysicalDeviceFeatures::default().shader_int64(true))
            .push_next(&mut f12);
        let device = instance
            .create_device(
                pdev,
                &vk::DeviceCreateInfo::default()
                    .queue_create_infos(&qci)
                    .push_next(&mut f2),
                None,
            )
            .expect("host device");
        let queue = device.get_device_queue(qf, 0);

        {
            let ctx = Context::borrowed(BorrowedHandles {
                entry: entry.clone(),
                instance: instance.clone(),
                physical_device: pdev,
                device: device.clone(),
                queue_family_index: qf,
                queue_index: 0,
                debug_utils: true,
                float_atomic_add: false,
                full_subgroups: false,
            })
            .expect("borrow the host device");
            assert!(!ctx.is_owned());

            let n = 200_000u32;
            let sort = RadixSort::new(&ctx, n).unwrap();
            let bufs = SortScratch::new(&ctx, n).unwrap();
            let mut rng = common::Rng(99);
            let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
            let vals: Vec<u32> = (0..n).collect();
            ctx.upload(&bufs.keys, 0, &keys).unwrap();
            ctx.upload(&bufs.values, 0, &vals).unwrap();

            // The host's own pool, command buffer, fence and submission.
            let pool = device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default().queue_family_index(qf),
                    None,
                )
                .unwrap();
            let cmd = device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(pool)
                        .command_buffer_count(1),
                )
                .unwrap()[0];
            device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
                .unwrap();
            let which = sort
                .record(cmd, &bufs.as_buffers(), Count::Host(n), 0..48, None)
                .unwrap();
            device.end_command_buffer(cmd).unwrap();
            let fence = device
                .create_fence(&vk::FenceCreateInfo::default(), None)
                .unwrap();
            let cmds = [cmd];
            device
                .queue_submit(
                    queue,
                    &[vk::SubmitInfo::default().command_buffers(&cmds)],
                    fence,
                )
                .unwrap();
            device.wait_for_fences(&[fence], true, u64::MAX).unwrap();

            let (k, v) = bufs.result(which);
            let (rk, rv) = common::reference_sort(&keys, &vals, 0, 48);
            assert_eq!(ctx.download::<u64>(k, 0, n as usize).unwrap(), rk);
            assert_eq!(ctx.download::<u32>(v, 0, n as usize).unwrap(), rv);
            assert_eq!(sort.take_errors().unwrap(), 0);

            device.destroy_fence(fence, None);
            device.destroy_command_pool(pool, None);
            // The engine's objects drop here; the host's device must survive that.
        }
        device
            .device_wait_idle()
            .expect("host device still alive after the engine dropped");
        device.destroy_device(None);
        du.destroy_debug_utils_messenger(messenger, None);
        instance.destroy_instance(None);
    }
    assert_eq!(
        HOST_VALIDATION_MESSAGES.load(Ordering::SeqCst),
        0,
        "validation messages on the host's messenger"
    );
}
