//! Experiment design shared by all methods: observability indices O1..O5, D-optimal
//! selection of configurations by DETMAX, feasibility of postures, optimal calibration
//! postures (COCP, NOCP) and the order and trajectory to play them. No I/O.

pub mod detmax;
pub mod feasibility;
pub mod humanoid;
pub mod observability;
pub mod ocp;
pub mod postures;
pub mod trajectory;

pub use detmax::{DetmaxOptions, Pool, Selection, detmax};
pub use feasibility::{Constraints, PointBox, Sphere, Violation};
pub use observability::{Indices, indices};
pub use ocp::{NocpOptions, OptimOptions, cocp, nocp, partial_optim, random_feasible};
pub use postures::{PostureModel, PostureSet, worst_index};
