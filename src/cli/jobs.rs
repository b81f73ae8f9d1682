//! The commands that talk to a daemon about jobs: `calibd submit`, `watch`, `jobs`,
//! `cancel`, `result`, `resume`, `rerun`, `report`.

use std::path::PathBuf;

use anyhow::Result;
use calibd::client::{Client, ClientError, commands};

use super::runtime;

/// Where the daemon is and how to authenticate.
#[derive(Debug, clap::Args)]
pub(crate) struct Remote {
    /// The daemon's URL.
    #[arg(long, env = "CALIBD_URL", default_value = "http://127.0.0.1:8750")]
    server: String,
    /// Bearer token (default: DATA/operator.token). A token on the command line is
    /// visible to every user of the machine in `ps`: prefer CALIBD_TOKEN or the file.
    #[arg(long, env = "CALIBD_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// The daemon's data folder, to find operator.token.
    #[arg(long, env = "CALIBD_DATA", default_value = "calibd-data")]
    data: PathBuf,
}

impl Remote {
    fn client(&self) -> Client {
        if token_on_command_line(std::env::args()) {
            eprintln!(
                "warning: a token given with --token is visible to every user of this machine \
                 (in `ps`, /proc/PID/cmdline) and lands in the shell history: set CALIBD_TOKEN, \
                 or let calibd read {} (the daemon's operator token)",
                self.data.join("operator.token").display()
            );
        }
        let token = Client::find_token(self.token.clone(), &self.data);
        let found = token.is_some();
        let c = Client::new(&self.server, token);
        if found {
            c
        } else {
            c.with_token_search(Client::token_places(&self.data))
        }
    }
}

/// Whether the arguments carry `--token` (rather than CALIBD_TOKEN or the token file).
fn token_on_command_line(args: impl Iterator<Item = String>) -> bool {
    args.take_while(|a| a != "--")
        .any(|a| a == "--token" || a.starts_with("--token="))
}

/// Run `f` with a client of `r` on a fresh runtime.
fn remote<F, Fut>(r: &Remote, f: F) -> Result<()>
where
    F: FnOnce(Client) -> Fut,
    Fut: std::future::Future<Output = Result<(), ClientError>>,
{
    let c = r.client();
    runtime()?.block_on(f(c))?;
    Ok(())
}

/// Options of `calibd submit`.
#[derive(Debug, clap::Args)]
pub(crate) struct SubmitArgs {
    /// The job file.
    job: PathBuf,
    /// Follow the job with a progress bar and print the result summary.
    #[arg(long)]
    watch: bool,
    /// Priority (higher runs first).
    #[arg(long, default_value_t = 0)]
    priority: i64,
    /// Plan only: print the plan's envelope check and estimated duration; nothing is
    /// submitted or moved (exits non-zero if the plan leaves the cell's envelope).
    #[arg(long, conflicts_with = "watch")]
    dry_run: bool,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd watch`.
#[derive(Debug, clap::Args)]
pub(crate) struct WatchArgs {
    /// Job id.
    id: i64,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd jobs`.
#[derive(Debug, clap::Args)]
pub(crate) struct JobsArgs {
    /// Only jobs in this state.
    #[arg(long, value_parser = ["queued", "running", "paused", "succeeded", "failed", "cancelled", "interrupted"])]
    state: Option<String>,
    /// Only jobs of this kind.
    #[arg(long)]
    kind: Option<String>,
    /// How many.
    #[arg(long, default_value_t = 20)]
    limit: usize,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd cancel`.
#[derive(Debug, clap::Args)]
pub(crate) struct CancelArgs {
    /// Job id.
    id: i64,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd result`.
#[derive(Debug, clap::Args)]
pub(crate) struct ResultArgs {
    /// Job id.
    id: i64,
    /// Folder for result.json, the artefacts and the main table.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the printable HTML report (self-contained: open it in a browser, print
    /// it, sign it off) to this file.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd resume`.
#[derive(Debug, clap::Args)]
pub(crate) struct ResumeArgs {
    /// Job id.
    id: i64,
    /// Follow it until it ends and print the summary.
    #[arg(long)]
    watch: bool,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd rerun`.
#[derive(Debug, clap::Args)]
pub(crate) struct RerunArgs {
    /// Job id.
    id: i64,
    /// Follow the new job until it ends and print the summary.
    #[arg(long)]
    watch: bool,
    #[command(flatten)]
    remote: Remote,
}

/// Options of `calibd report`.
#[derive(Debug, clap::Args)]
pub(crate) struct ReportArgs {
    /// Job id.
    id: i64,
    /// The HTML file to write.
    #[arg(short = 'o', long, value_name = "FILE", default_value = "report.html")]
    out: PathBuf,
    #[command(flatten)]
    remote: Remote,
}

/// `calibd submit`: upload the files the job names, submit it, optionally follow it.
pub(crate) fn submit(a: SubmitArgs) -> Result<()> {
    let SubmitArgs {
        job,
        watch,
        priority,
        dry_run,
        remote: r,
    } = a;
    if dry_run {
        return remote(&r, |c| async move {
            commands::dry_run(&c, &job).await.map(|_| ())
        });
    }
    remote(&r, |c| async move {
        commands::submit(&c, &job, priority, watch)
            .await
            .map(|_| ())
    })
}

/// `calibd watch`: follow a job until it ends.
pub(crate) fn watch(a: WatchArgs) -> Result<()> {
    let id = a.id;
    remote(&a.remote, |c| async move {
        commands::watch(&c, id).await.map(|_| ())
    })
}

/// `calibd jobs`: the newest jobs, filtered.
pub(crate) fn jobs(a: JobsArgs) -> Result<()> {
    let JobsArgs {
        state,
        kind,
        limit,
        remote: r,
    } = a;
    remote(&r, |c| async move {
        commands::jobs(&c, state.as_deref(), kind.as_deref(), limit).await
    })
}

/// `calibd cancel`: cancel a job.
pub(crate) fn cancel(a: CancelArgs) -> Result<()> {
    let id = a.id;
    remote(&a.remote, |c| async move { commands::cancel(&c, id).await })
}

/// `calibd result`: print a result, or write it (and the report) to files.
pub(crate) fn result(a: ResultArgs) -> Result<()> {
    let ResultArgs {
        id,
        out,
        report,
        remote: r,
    } = a;
    remote(&r, |c| async move {
        if let Some(file) = &report {
            commands::report(&c, id, file).await?;
            if out.is_none() {
                return Ok(());
            }
        }
        commands::result(&c, id, out.as_deref()).await
    })
}

/// `calibd resume`: resume a campaign from its journal, optionally following it.
pub(crate) fn resume(a: ResumeArgs) -> Result<()> {
    let ResumeArgs {
        id,
        watch,
        remote: r,
    } = a;
    remote(&r, |c| async move {
        commands::resume(&c, id).await?;
        if watch {
            commands::watch(&c, id).await?;
        }
        Ok(())
    })
}

/// `calibd rerun`: a job's document as a new job, optionally followed.
pub(crate) fn rerun(a: RerunArgs) -> Result<()> {
    let RerunArgs {
        id,
        watch,
        remote: r,
    } = a;
    remote(&r, |c| async move {
        let new = commands::rerun(&c, id).await?;
        if watch {
            commands::watch(&c, new).await?;
        }
        Ok(())
    })
}

/// `calibd report`: write a job's printable HTML report.
pub(crate) fn report(a: ReportArgs) -> Result<()> {
    let ReportArgs { id, out, remote: r } = a;
    remote(&r, |c| async move { commands::report(&c, id, &out).await })
}
