//! Experiment design shared by all methods: observability indices O1..O5, D-optimal
//! selection of configurations by DETMAX, Poisson-disc sampling of joint boxes, commanded
//! trajectories for accuracy tests, feasibility of postures, optimal calibration postures
//! (COCP, NOCP) and the order and segments to play them. No I/O.

pub mod balls;
pub mod detmax;
pub mod feasibility;
pub mod humanoid;
pub mod observability;
pub mod ocp;
pub mod playback;
pub mod poisson;
pub mod postures;
pub mod trajectory;

pub use detmax::{DetmaxOptions, DetmaxStep, Pool, Selection, detmax};
pub use feasibility::{Constraints, PointBox, Sphere, Violation};
pub use observability::{Indices, indices};
pub use ocp::{NocpOptions, OptimOptions, cocp, nocp, partial_optim, random_feasible};
pub use poisson::{PoissonError, poisson_disc, poisson_disc_n};
pub use postures::{PostureModel, PostureSet, worst_index};
