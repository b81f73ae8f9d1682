//! calibd: a calibration service for precision robots.
//!
//! Module map (pure maths apart from device procedures, apart from jobs and storage):
//! - [`util`]: seeded random numbers, descriptive statistics.
//! - [`geometry`]: rigid transforms and elementary motions (no I/O).
//! - [`model`]: robot models (serial chains from DH files or URDF), FK, Jacobians, torques.
//! - [`identify`]: least squares shared by every method: Levenberg-Marquardt, rank detection
//!   by pivoted QR, covariance and reports.
//! - [`measure`]: measurement models (ball coincidence, Cartesian points, mocap markers)
//!   and mocap pre-processing.
//! - [`signal`]: Butterworth design and zero-phase filtering.
//! - [`design`]: observability indices, configuration selection (DETMAX), optimal
//!   calibration postures (COCP, NOCP), feasibility and trajectories.
//! - [`twin`]: digital twins (true parameters and noise) for tests and simulation.
//! - [`jobs`]: job specifications, inputs, dispatch to the job kinds, results.
//! - [`bench`]: benchmarks printed by `calibd bench`.
#![warn(missing_docs)]

pub mod bench;
pub mod design;
pub mod geometry;
pub mod identify;
pub mod jobs;
pub mod measure;
pub mod model;
pub mod signal;
pub mod twin;
pub mod util;
