//! Measurement campaigns: the [`engine`] owns the loop every campaign repeats (journal skip
//! on resume, retry with back-off, pause with reason, cancel before every move, progress
//! and ETA); each campaign supplies its plan and a "measure one" [`engine::Step`], then
//! calls the numerical kinds through typed functions on the blocking pool.

pub mod centre;
pub mod commission;
pub mod engine;
pub mod instruments;
pub mod jog;
pub mod mocap;
pub mod operator;
pub mod pcr;
pub mod preflight;
pub mod results;
mod results_report;
pub mod spec;
pub mod trical;
pub mod verify;

#[cfg(test)]
mod journal_tests;
