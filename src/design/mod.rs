//! Experiment design shared by all methods: observability indices O1..O5, D-optimal
//! selection of configurations by DETMAX, feasibility of postures, optimal calibration
//! postures (COCP, NOCP) and the order and trajectory to play them. No I/O.

pub mod detmax;
pub mod feasibility;
pub mod humanoid;
pub mod observability;
pub mod postures;
pub mod trajectory;

pub use detmax::{DetmaxOptions, Pool, Selection, detmax};
pub use feasibility::{Constraints, PointBox, Sphere, Violation};
pub use observability::{Indices, indices};
pub use postures::{
    NocpOptions, OptimOptions, PostureModel, PostureSet, cocp, nocp, partial_optim,
    random_feasible, worst_index,
};
