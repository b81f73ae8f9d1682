//! Experiment design shared by all methods: observability indices O1..O5 and D-optimal
//! selection of configurations by DETMAX. No I/O.

pub mod balls;
pub mod detmax;
pub mod observability;

pub use detmax::{DetmaxOptions, Pool, Selection, detmax};
pub use observability::{Indices, indices};
