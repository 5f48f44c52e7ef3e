//! Creating an owned context: the Vulkan instance (API version, the validation layer and
//! its features, debug utils), then the device ([`super::device`] picks and creates it)
//! and the validation messenger, assembled by `Context::build`.

use ash::vk;

use super::context::{Context, ContextOptions};
use super::device::{compute_queue_family, query_support, version_string};
use super::validation::{env_flag, ValidationLog, VALIDATION_LAYER};
use super::BorrowedHandles;
use crate::error::{Error, Result, VkContext};

impl Context {
    /// Creates an owned instance and device.
    pub fn new(opts: &ContextOptions) -> Result<Self> {
        let entry = unsafe { ash::Entry::load() }.map_err(|e| Error::Loader(e.to_string()))?;
        let validation = opts.validation || env_flag("SVRASTER_VALIDATION");
        let loader_api = unsafe { entry.try_enumerate_instance_version() }
            .vk("vkEnumerateInstanceVersion")?
            .unwrap_or(vk::API_VERSION_1_0);
        if loader_api < vk::API_VERSION_1_2 {
            return Err(Error::NoDevice(format!(
                "the Vulkan loader supports only API {}; 1.2 or newer is required",
                version_string(loader_api)
            )));
        }
        let api = loader_api.min(vk::API_VERSION_1_3);

        let mut layers: Vec<*const std::ffi::c_char> = Vec::new();
        let mut exts: Vec<*const std::ffi::c_char> = Vec::new();
        let inst_exts = unsafe { entry.enumerate_instance_extension_properties(None) }
            .vk("vkEnumerateInstanceExtensionProperties")?;
        let has_debug_utils = inst_exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));
        let mut use_validation_features = false;
        if validation {
            let avail = unsafe { entry.enumerate_instance_layer_properties() }
                .vk("vkEnumerateInstanceLayerProperties")?;
            if !avail
                .iter()
                .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER))
            {
                return Err(Error::NoValidationLayer);
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            let lexts =
                unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER)) }
                    .unwrap_or_default();
            if lexts
                .iter()
                .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::validation_features::NAME))
            {
                exts.push(ash::ext::validation_features::NAME.as_ptr());
                use_validation_features = true;
            }
        }
        let debug_utils = has_debug_utils || validation;
        if debug_utils {
            exts.push(ash::ext::debug_utils::NAME.as_ptr());
        }

        let log = Box::into_raw(Box::new(ValidationLog::default()));
        let app = vk::ApplicationInfo::default()
            .application_name(c"svraster")
            .engine_name(c"svraster-vk")
            .api_version(api);
        let mut messenger_ci = super::validation::messenger_info(log);
        let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut vfeat = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
        let mut ici = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&exts);
        if validation {
            ici = ici.push_next(&mut messenger_ci);
            if use_validation_features {
                ici = ici.push_next(&mut vfeat);
            }
        }
        let instance = match unsafe { entry.create_instance(&ici, None) } {
            Ok(i) => i,
            Err(e) => {
                drop(unsafe { Box::from_raw(log) });
                return Err(Error::Vulkan {
                    call: "vkCreateInstance",
                    result: e,
                });
            }
        };
        // From here on, failures must destroy the instance.
        let result = Self::finish_owned(
            &entry,
            &instance,
            opts,
            validation,
            debug_utils,
            log,
            &messenger_ci,
        );
        match result {
            Ok(ctx) => Ok(ctx),
            Err(e) => {
                unsafe { instance.destroy_instance(None) };
                drop(unsafe { Box::from_raw(log) });
                Err(e)
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn finish_owned(
        entry: &ash::Entry,
        instance: &ash::Instance,
        opts: &ContextOptions,
        validation: bool,
        debug_utils: bool,
        log: *mut ValidationLog,
        messenger_ci: &vk::DebugUtilsMessengerCreateInfoEXT<'_>,
    ) -> Result<Self> {
        let pdev = super::device::pick_physical_device(instance, opts.device.clone())?;
        let support = query_support(instance, pdev);
        let qf = compute_queue_family(instance, pdev).ok_or_else(|| {
            Error::NoDevice("the device has no compute queue with timestamps".into())
        })?;

        let device = super::device::create_device(instance, pdev, &support, qf)?;

        let messenger = if validation {
            let du = ash::ext::debug_utils::Instance::new(entry, instance);
            match unsafe { du.create_debug_utils_messenger(messenger_ci, None) } {
                Ok(m) => Some((du, m)),
                Err(e) => {
                    unsafe { device.destroy_device(None) };
                    return Err(Error::Vulkan {
                        call: "vkCreateDebugUtilsMessengerEXT",
                        result: e,
                    });
                }
            }
        } else {
            None
        };
        let handles = BorrowedHandles {
            entry: entry.clone(),
            instance: instance.clone(),
            physical_device: pdev,
            device,
            queue_family_index: qf,
            queue_index: 0,
            debug_utils,
            float_atomic_add: support.float_atomic_add,
            full_subgroups: support.full_subgroups,
            conditional_rendering: support.conditional_rendering,
        };
        Self::build(
            handles,
            true,
            messenger,
            if validation {
                Some(log as *const _)
            } else {
                None
            },
        )
    }
}
