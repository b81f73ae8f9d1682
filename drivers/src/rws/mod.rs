//! ABB IRC5 over Robot Web Services 1.0: a small HTTP/1.1 codec, Digest auth, RAPID
//! literals, the driver (joints, RAPID variables, guarded moves through the calibd RAPID
//! module in `drivers/rapid/`), IRB 120 kinematics and the mock controller.

pub mod digest;
pub mod driver;
pub mod http;
pub mod irb120;
pub mod mock;
pub mod rapid;

pub use driver::{
    ControllerState, DEFAULT_CALIB_MODULE, RwsConfig, RwsHandle, RwsIdentity, RwsState,
};
