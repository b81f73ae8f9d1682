//! `calibd bench AREA`: run an area's benchmarks and print (and optionally save) the figures.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use super::runtime;

/// Options of `calibd bench`.
#[derive(Debug, clap::Args)]
pub(crate) struct BenchArgs {
    /// Area: `serial`, `pcr`, `humanoid`, `identify` (identification from 90 to 100,000
    /// measurements), `all` (those four), `serial.fk` (only the `serial.fk` table
    /// figures of `serial`), `serial.dispersion` (only its dispersion study figure),
    /// `humanoid.detmax` (only its DETMAX 12 of 1,000 figure),
    /// `identify:N` (one size), `kernels` (nalgebra against faer
    /// and the crossovers), `drivers` or `api` (the daemon under many concurrent
    /// clients), or `compare OLD.json NEW.json` (two saved runs side by side; exits 1 when
    /// a figure got slower beyond the noise of the runs).
    area: String,
    /// For `compare`: the old and the new saved run.
    files: Vec<PathBuf>,
    /// Also write every figure (median, min, max, peak memory) of `serial`, `pcr`,
    /// `humanoid`, `identify` or `all` to this JSON file, to compare a run with an earlier one.
    #[arg(long)]
    json: Option<PathBuf>,
    /// For `fleet`: the PostgreSQL URL the daemons share (default: a throw-away cluster,
    /// when PostgreSQL's binaries are installed).
    #[arg(long)]
    store: Option<String>,
    /// For `fleet`: the fleet sizes, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2, 4])]
    daemons: Vec<usize>,
}

/// The figures of a numerical area; `None` for an unknown one.
fn numerical(a: &str) -> Option<Vec<calibd::bench::Figure>> {
    match a {
        "serial" => Some(calibd::bench::serial::run()),
        "serial.fk" => Some(calibd::bench::serial::fk_tables()),
        "serial.compensate" => Some(calibd::bench::serial::compensate_figures()),
        "serial.dispersion" => Some(calibd::bench::serial::dispersion_figures()),
        "humanoid" => Some(calibd::bench::humanoid::run()),
        "humanoid.detmax" => Some(calibd::bench::humanoid::detmax_only()),
        "pcr" => Some(calibd::bench::pcr::run()),
        "identify" => Some(calibd::bench::identify::run()),
        "kernels" => Some(calibd::bench::kernels::run()),
        other => other
            .strip_prefix("identify:")
            .and_then(|n| n.parse::<usize>().ok())
            .map(|n| calibd::bench::identify::sweep(&[n])),
    }
}

/// `calibd bench`: print each area's figures; write them as JSON with `--json`.
pub(crate) fn bench(a: BenchArgs) -> Result<()> {
    let BenchArgs {
        area,
        files,
        json,
        store,
        daemons,
    } = a;
    let areas: Vec<&str> = match area.as_str() {
        "compare" => return compare(&files),
        other if !files.is_empty() => {
            bail!(
                "`calibd bench {other}` takes no file arguments (only `calibd bench compare OLD.json NEW.json` does)"
            )
        }
        "all" => vec!["serial", "pcr", "humanoid", "identify"],
        "api" => {
            let report = runtime()?.block_on(calibd::bench::api::run(Default::default()))?;
            println!("{report}");
            return Ok(());
        }
        "fleet" => {
            let mut o = calibd::bench::fleet::FleetBenchOptions::new(
                std::env::current_exe().context("cannot find calibd's own executable")?,
            );
            o.store = store;
            o.daemons = daemons;
            if o.daemons.is_empty() || o.daemons.contains(&0) {
                bail!("--daemons takes fleet sizes of at least 1, e.g. 1,2,4");
            }
            let figures = calibd::bench::fleet::run(&o)?;
            print!("{}", calibd::bench::fleet::render(&o, &figures));
            return Ok(());
        }
        "drivers" => {
            return Ok(calibd_drivers::bench::run_and_print(&mut std::io::stdout())?);
        }
        other if numerical_area(other) => vec![other],
        other => {
            bail!(
                "unknown benchmark area `{other}` (known: serial, serial.fk, serial.compensate, serial.dispersion, pcr, humanoid, humanoid.detmax, identify, identify:N, kernels, all, drivers, api, fleet)"
            )
        }
    };
    let mut report = Vec::new();
    for a in areas {
        let figures = numerical(a).unwrap_or_default();
        println!("== {a}");
        calibd::bench::print(&mut std::io::stdout(), &figures)?;
        report.push(calibd::bench::Area {
            area: a.to_string(),
            figures,
        });
    }
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&calibd::bench::Report::new(report))?;
        std::fs::write(&path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("figures written to {}", path.display());
    }
    Ok(())
}

/// `calibd bench compare OLD NEW`: print the comparison; an error when a figure is slower.
fn compare(files: &[PathBuf]) -> Result<()> {
    use calibd::bench::compare::{Change, SavedReport, compare, render};
    let [old, new] = files else {
        bail!(
            "`calibd bench compare` takes two files written by `calibd bench AREA --json FILE`: OLD.json NEW.json"
        );
    };
    let read = |p: &PathBuf| -> Result<SavedReport> {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
        Ok(SavedReport::parse(&p.display().to_string(), &text)?)
    };
    let (old, new) = (read(old)?, read(new)?);
    let rows = compare(&old, &new);
    print!("{}", render(&old, &new, &rows));
    let slower = rows
        .iter()
        .filter(|r| r.change == Change::Regression)
        .count();
    if slower > 0 {
        bail!("{slower} figure(s) slower beyond the noise of the two runs");
    }
    Ok(())
}

/// The benchmark areas whose figures `--json` can write.
fn numerical_area(a: &str) -> bool {
    matches!(
        a,
        "serial"
            | "serial.fk"
            | "serial.compensate"
            | "serial.dispersion"
            | "pcr"
            | "humanoid"
            | "humanoid.detmax"
            | "identify"
            | "kernels"
    ) || a
        .strip_prefix("identify:")
        .is_some_and(|n| n.parse::<usize>().is_ok())
}
