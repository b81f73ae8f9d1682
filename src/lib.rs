//! calibd: a calibration service for precision robots.
//!
//! Module map (pure maths apart from device procedures, apart from jobs and storage):
//! - [`util`]: seeded random numbers, descriptive statistics.
//! - [`geometry`]: rigid transforms and elementary motions (no I/O).
//! - [`model`]: robot models (serial chains from DH files or URDF, the 3-PF parallel
//!   continuum robot), FK, IK, Jacobians, torques.
//! - [`identify`]: least squares shared by every method: Levenberg-Marquardt, rank detection
//!   by pivoted QR, gauge freedoms, robust losses, covariance and reports.
//! - [`measure`]: measurement models (ball coincidence, Cartesian points, the 3-PF
//!   microscope, mocap markers), the 3-PF three-step identification, ISO 9283 accuracy,
//!   mocap pre-processing.
//! - [`signal`]: Butterworth design and zero-phase filtering.
//! - [`design`]: observability indices, configuration selection (DETMAX), Poisson-disc
//!   sampling, trajectories, optimal calibration postures (COCP, NOCP), feasibility.
//! - [`procedures`]: device-driven steps (centring loop, campaigns) over small device
//!   traits.
//! - [`twin`]: digital twins (true parameters and noise) for tests and simulation.
//! - [`jobs`]: job specifications, inputs, dispatch to the job kinds, results.
//! - [`store`]: SQLite storage of jobs, datasets, progress, results, logs, schedules.
//! - [`service`]: the job queue, the worker pool, progress events, cancellation.
//! - [`schedule`]: cron schedules that submit jobs.
//! - [`report`]: SVG plots from results.
//! - [`api`]: the HTTP API, the web page, authentication, SSE.
//! - [`config`]: daemon settings (TOML file + environment).
//! - [`server`]: `calibd serve` wiring.
//! - [`client`]: the HTTP client behind `calibd submit`, `watch`, `jobs`, `cancel`, `result`.
//! - [`bench`]: benchmarks printed by `calibd bench`.
#![warn(missing_docs)]

pub mod api;
pub mod bench;
pub mod campaigns;
pub mod client;
pub mod config;
pub mod design;
pub mod geometry;
pub mod identify;
pub mod jobs;
pub mod lab;
pub mod measure;
pub mod model;
pub use jobs::offline;
pub mod procedures;
pub mod report;
pub mod run;
pub mod schedule;
pub mod server;
pub mod service;
pub mod signal;
pub mod sim;
pub mod store;
pub mod twin;
pub mod util;
