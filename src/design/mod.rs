//! Experiment design shared by all methods: observability indices O1..O5 and D-optimal
//! selection of configurations by DETMAX, Poisson-disc sampling of joint boxes, commanded
//! trajectories for accuracy tests. No I/O.

pub mod balls;
pub mod detmax;
pub mod observability;
pub mod poisson;
pub mod trajectory;

pub use detmax::{DetmaxOptions, Pool, Selection, detmax};
pub use observability::{Indices, indices};
pub use poisson::{PoissonError, poisson_disc, poisson_disc_n};
