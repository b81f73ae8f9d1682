//! `calibd store ...`: moving a lab's history between stores.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub(crate) enum StoreCommand {
    /// Copy every job, result, dataset, schedule and journal into an empty database.
    Copy {
        /// Source: `sqlite:FOLDER` (the daemon's data folder).
        #[arg(long)]
        from: String,
        /// Target: a `postgres://USER@HOST:PORT/DB` URL (no password in it).
        #[arg(long)]
        to: String,
        /// File holding the target's password (else CALIBD_STORE_PASSWORD).
        #[arg(long)]
        password_file: Option<PathBuf>,
    },
}

/// Run a `calibd store` subcommand.
pub(crate) fn store(command: StoreCommand) -> Result<()> {
    match command {
        StoreCommand::Copy {
            from,
            to,
            password_file,
        } => copy(&from, &to, password_file.as_deref()),
    }
}

/// `calibd store copy`: every table of a SQLite data folder into an empty database.
fn copy(from: &str, to: &str, password_file: Option<&Path>) -> Result<()> {
    use calibd::store::{Location, Store};
    let password = match password_file {
        Some(p) => Some(
            std::fs::read_to_string(p)
                .with_context(|| format!("reading {}", p.display()))?
                .lines()
                .next()
                .unwrap_or("")
                .to_string(),
        ),
        None => std::env::var("CALIBD_STORE_PASSWORD").ok(),
    };
    let src = Location::parse(from, None)?;
    match &src {
        Location::Sqlite(dir) if dir.join("calibd.sqlite3").exists() => {}
        Location::Sqlite(dir) => bail!("no calibd.sqlite3 in {}", dir.display()),
        Location::Postgres(_) => bail!("--from must be sqlite:FOLDER"),
    }
    let dst = Location::parse(to, password)?;
    let src = Store::open_location(&src)?;
    let dst = Store::open_location(&dst)?;
    for (table, n) in src.copy_to(&dst)? {
        println!("{table}: {n} rows");
    }
    Ok(())
}
