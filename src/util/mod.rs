//! Small shared helpers with no domain knowledge: a seeded random generator and
//! descriptive statistics.

pub mod rng;
pub mod stats;

pub use rng::Rng;
pub use stats::Summary;
