//! The library's one error type.

use ash::vk;

/// Everything the library can fail with. Messages say what happened and, where a user
/// can act on it, what to do next.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("cannot load the Vulkan loader (libvulkan.so.1): {0}. Install it (Debian: `apt-get install libvulkan1 mesa-vulkan-drivers`)")]
    Loader(String),
    #[error("Vulkan call {call} failed: {result}")]
    Vulkan {
        call: &'static str,
        result: vk::Result,
    },
    #[error("no usable Vulkan device: {0}")]
    NoDevice(String),
    #[error("device `{device}` lacks required features: {missing}")]
    MissingFeatures { device: String, missing: String },
    #[error("the Khronos validation layer was requested but is not installed (Debian: `apt-get install vulkan-validationlayers`)")]
    NoValidationLayer,
    #[error("out of device memory allocating `{name}` ({bytes} bytes): {detail}")]
    OutOfMemory {
        name: String,
        bytes: u64,
        detail: String,
    },
    #[error("buffer `{name}` needs {bytes} bytes, more than the device allows in one allocation ({limit} bytes)")]
    TooLarge {
        name: String,
        bytes: u64,
        limit: u64,
    },
    #[error("capacity exceeded: {0}")]
    Capacity(String),
    #[error("invalid input: {0}")]
    Invalid(String),
    #[error("GPU reported an internal error: {0}")]
    Gpu(String),
    /// The windowed viewer (feature `viewer`): no window system, no device that can
    /// present, a failed swapchain or screenshot.
    #[error("viewer: {0}")]
    Viewer(String),
    #[error("{0} validation message(s) were reported (see stderr)")]
    Validation(u64),
    /// (The I/O error is part of the message, not a `source`, so `{:#}` chains do not
    /// print it twice.)
    #[error("I/O error on {path}: {error}")]
    Io { path: String, error: std::io::Error },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Attaches the name of the Vulkan call to a `vk::Result`.
pub(crate) trait VkContext<T> {
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| Error::Vulkan { call, result })
    }
}
