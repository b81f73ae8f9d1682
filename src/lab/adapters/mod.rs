//! Device adapters: each driver actor's handle behind a procedure trait
//! ([`crate::procedures::devices`]), with driver errors mapped to device errors that name
//! the device.

/// A device adapter that is a driver handle and the device's name (used in errors).
macro_rules! named_adapter {
    ($(#[$doc:meta])* $name:ident, $handle:ty) => {
        $(#[$doc])*
        #[derive(Debug, Clone)]
        pub struct $name {
            handle: $handle,
            name: String,
        }

        impl $name {
            /// Wrap a driver handle; `name` is the device name in errors.
            pub fn new(handle: $handle, name: impl Into<String>) -> Self {
                Self {
                    handle,
                    name: name.into(),
                }
            }
        }
    };
}

pub mod camera;
pub mod joints;
pub mod pcr;
pub mod qtm;
pub mod serial;

pub use camera::CameraMicroscope;
pub use joints::JointInterface;
pub use pcr::{Microscope, PerJoint, SmaractStages, StageEnvelope};
pub use qtm::QtmStream;
pub use serial::{RwsModules, RwsRobot, UwaveIndicators, device_error};
