//! Small shared helpers with no domain knowledge: a seeded random generator, descriptive
//! statistics, and the progress/cancellation hook of long computations.

pub mod monitor;
pub mod rng;
pub mod stats;

pub use monitor::{Monitor, NoMonitor, SubMonitor};
pub use rng::Rng;
pub use stats::Summary;
