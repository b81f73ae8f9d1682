//! Device adapters: each driver actor's handle behind a procedure trait
//! ([`crate::procedures::devices`]), with driver errors mapped to device errors that name
//! the device.

pub mod pcr;
pub mod qtm;
pub mod serial;

pub use pcr::{Microscope, SmaractStages};
pub use qtm::QtmStream;
pub use serial::{RwsRobot, UwaveIndicators, device_error};
