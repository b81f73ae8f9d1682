//! The calibd command line: a thin layer of clap over the library. This file parses the
//! arguments and dispatches; each group of subcommands is in [`cli`].

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

use cli::{bench, daemon, jobs, lab, mock, run, store, twin};

/// calibd: calibration service for precision robots.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a job file in-process, without a daemon, and print or write its result.
    ///
    /// An identification (serial.identify, tree.identify, humanoid.identify, pcr.identify)
    /// ends with a verdict, printed on stderr with its reasons, and the exit code says it:
    /// 0 accepted, 3 review (usable after a person read the reasons), 4 rejected (nothing
    /// usable was made: no calibrated_model* is written, rejected_model* instead). Jobs that
    /// are not identifications exit 0. Errors (invalid job, failed run) exit 1.
    Run(run::RunArgs),
    /// Run the benchmarks of an area and print the figures.
    Bench(bench::BenchArgs),
    /// List the job kinds.
    Kinds,
    /// Print an example job (IRB 120 twin data, inline) to stdout; without NAME, list them.
    Example(run::ExampleArgs),
    /// Run the daemon: job queue, workers, REST API, web page, schedules.
    Serve(daemon::ServeArgs),
    /// The store: `calibd store copy --from sqlite:FOLDER --to postgres://…` moves a lab's
    /// history into an empty PostgreSQL database (password: CALIBD_STORE_PASSWORD or
    /// --password-file).
    Store {
        #[command(subcommand)]
        command: store::StoreCommand,
    },
    /// The lab: `calibd lab check` connects to every configured device and prints who
    /// answered, and what to fix where one did not.
    Lab {
        #[command(subcommand)]
        command: lab::LabCommand,
    },
    /// Submit a job file to a daemon (files it names are uploaded as datasets).
    Submit(jobs::SubmitArgs),
    /// Follow a job until it ends.
    Watch(jobs::WatchArgs),
    /// List jobs, newest first.
    Jobs(jobs::JobsArgs),
    /// Cancel a job.
    Cancel(jobs::CancelArgs),
    /// Print a job's result, or write it with its artefacts into a folder.
    Result(jobs::ResultArgs),
    /// Resume a paused or interrupted campaign from its journal (operator role).
    Resume(jobs::ResumeArgs),
    /// Run a job's document again as a new job (same inputs, new id).
    Rerun(jobs::RerunArgs),
    /// Write a job's printable HTML report (self-contained: open, print, sign off).
    Report(jobs::ReportArgs),
    /// Check that a daemon answers `GET /v1/health` with 200 (no token needed).
    ///
    /// Prints one line, exits 0 when healthy and 1 otherwise. The container image's
    /// HEALTHCHECK.
    Health(daemon::HealthArgs),
    /// Make a new API token and print it with the config line that grants it.
    Token(daemon::TokenArgs),
    /// Run a mock device server (QTM, ABB RWS, U-WAVE, SmarAct MCS/MCS2, CAN, microscope, joint
    /// interface) until Ctrl-C. `calibd mock lab --config LAB.toml [--cell NAME]` serves the
    /// devices of a lab file's cells from the digital twins instead (`calibd mock lab --help`).
    Mock(calibd_drivers::mock::MockArgs),
    /// Write a digital twin's data set (CSV tables and the model file) into a folder, for
    /// examples and experiments.
    Twin(twin::TwinArgs),
}

fn main() -> Result<()> {
    // `calibd mock lab` takes a lab file rather than one device: its own arguments.
    let argv: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(args) = mock::lab_args(&argv) {
        return mock::lab(args);
    }
    match Cli::parse().command {
        Command::Run(a) => run::run(a),
        Command::Bench(a) => bench::bench(a),
        Command::Kinds => run::kinds(),
        Command::Example(a) => run::example(a),
        Command::Serve(a) => daemon::serve(a),
        Command::Store { command } => store::store(command),
        Command::Lab { command } => lab::lab(command),
        Command::Submit(a) => jobs::submit(a),
        Command::Watch(a) => jobs::watch(a),
        Command::Jobs(a) => jobs::jobs(a),
        Command::Cancel(a) => jobs::cancel(a),
        Command::Result(a) => jobs::result(a),
        Command::Resume(a) => jobs::resume(a),
        Command::Rerun(a) => jobs::rerun(a),
        Command::Report(a) => jobs::report(a),
        Command::Health(a) => daemon::health(a),
        Command::Token(a) => daemon::token(a),
        Command::Mock(a) => mock::device(a),
        Command::Twin(a) => twin::twin(a),
    }
}
