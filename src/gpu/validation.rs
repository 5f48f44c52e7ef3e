//! The validation layer's messages: the debug-utils callback counts every warning and
//! error it reports into a [`ValidationLog`] (tests fail on any), and prints them.

use std::ffi::{c_void, CStr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use ash::vk;

pub(super) const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// What the validation layer reported through the messenger of an owned context.
#[derive(Default)]
pub(crate) struct ValidationLog {
    pub(super) count: AtomicU64,
    pub(super) messages: Mutex<Vec<String>>,
}

/// The messenger's create info, its user data `log` (warnings and errors of every type).
pub(super) fn messenger_info(
    log: *mut ValidationLog,
) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(log as *mut c_void)
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    ty: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    let msg = if data.is_null() || (*data).p_message.is_null() {
        String::from("(no message)")
    } else {
        CStr::from_ptr((*data).p_message)
            .to_string_lossy()
            .into_owned()
    };
    let serious = severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    );
    if serious && ty.contains(vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION) && !user.is_null() {
        let log = &*(user as *const ValidationLog);
        log.count.fetch_add(1, Ordering::SeqCst);
        if let Ok(mut m) = log.messages.lock() {
            m.push(msg.clone());
        }
        eprintln!("[vulkan validation] {msg}");
    } else if serious {
        eprintln!("[vulkan] {msg}");
    }
    vk::FALSE
}

pub(super) fn env_flag(name: &str) -> bool {
    std::env::var(name).is_ok_and(|v| !v.is_empty() && v != "0")
}
