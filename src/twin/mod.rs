//! Digital twins: a "true" robot (nominal perturbed by known errors) and simulated sensors
//! with noise, used by tests, examples, benchmarks and the simulated lab. Seeded, no I/O.

pub mod cell;
pub mod elastic;
pub mod humanoid;
pub mod pcr;
pub mod serial;

pub use humanoid::HumanoidTwin;
pub use pcr::PcrTwin;
pub use serial::SerialTwin;
