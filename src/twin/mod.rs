//! Digital twins: a "true" robot (nominal perturbed by known errors) and simulated sensors
//! with noise, used by tests, examples, benchmarks and the simulated lab. Seeded, no I/O.

pub mod humanoid;
pub mod serial;

pub use humanoid::HumanoidTwin;
pub use serial::SerialTwin;
