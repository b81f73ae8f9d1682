//! Helpers shared by integration tests.
#![allow(dead_code, unreachable_pub)]

pub mod daemon;
pub mod report;

use std::path::PathBuf;

use calibd::jobs::{Completed, DirResolver, Job, JobError, prepare};
use calibd::util::NoMonitor;
use serde_json::Value;

/// The device names of a campaign result's `instruments`, in order.
pub fn instrument_names(result: &Value) -> Vec<&str> {
    result["instruments"]
        .as_array()
        .expect("instruments")
        .iter()
        .filter_map(|i| i["device"].as_str())
        .collect()
}

/// The repository's examples folder.
pub fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples")
}

/// The repository's test data folder.
pub fn data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// A job document read from an example file.
pub fn example(name: &str) -> Value {
    let text = std::fs::read_to_string(examples().join(name)).expect("example exists");
    serde_json::from_str(&text).expect("example is JSON")
}

/// Prepare a document with paths relative to `examples/`.
pub fn prepare_in_examples(doc: &Value) -> Result<Job, JobError> {
    prepare(doc, &DirResolver { dir: examples() })
}

/// Prepare and run a document with paths relative to `examples/`.
pub fn run_in_examples(doc: &Value) -> Result<Completed, JobError> {
    prepare_in_examples(doc)?.run(&NoMonitor)
}
