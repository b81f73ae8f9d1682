//! calibd's integration tests, one binary (linked once, not once per file): each module is
//! one area, against the library, a daemon on a real socket (`server`), or the real
//! `calibd` binary in another process (`common::daemon`). Run one area with
//! `cargo test --test it security::`.

mod common;
mod server;

mod api;
mod api_contract;
mod campaign;
mod cell_models;
mod cli;
mod commission;
mod dispersion_values;
mod drift;
mod fleet;
mod hil;
mod humanoid_identifiability;
mod humanoid_jobs;
mod humanoid_twin;
mod identify_reference;
mod joint_kinds_twin;
mod justin_elastic;
mod kill9;
mod lab_check_cell;
mod layers;
mod memory;
mod mocap_campaign;
mod mock_joints;
mod mock_microscope;
mod mukca;
mod openapi_jobs;
mod pcr_camera;
mod pcr_campaign;
mod pcr_jobs;
mod pcr_model;
mod pcr_mount_markers;
mod pcr_prior;
mod pcr_twin;
mod plan_check;
mod rapid_program;
mod replay_steps;
mod report;
mod report_studies;
mod security;
mod serial_distance;
mod serial_jobs;
mod serial_on_axis;
mod serial_prior;
mod serial_stream;
mod serial_twin;
mod shipped_commission;
mod shipped_lab;
mod talos_coverage;
mod talos_prior;
