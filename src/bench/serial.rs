//! `calibd bench serial`: `serial.fk` jobs from a CSV file to a CSV file (streamed at 50,000
//! and 1,000,000 rows, and at 50,000 through the whole result as before streaming), FK +
//! gravity torques, one 31-parameter identification from 360 measurements, DETMAX 75 of 360,
//! the identifications of a dispersion study alone, a 2,000-identification dispersion
//! study, and the `serial.compensate` solver per target, all on the IRB 120 twin.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::{Figure, time};
use crate::design::{DetmaxOptions, detmax};
use crate::jobs::serial::design::DesignPool;
use crate::jobs::serial::identify::IdentifyInputs;
use crate::jobs::{DirResolver, JobError, Resolver};
use crate::jobs::{NoReferences, prepare};
use crate::run::rows::CsvSink;
use crate::twin::SerialTwin;
use crate::util::{NoMonitor, Rng};

/// A dispersion job over twin data as inline JSON.
pub fn dispersion_job(sizes: &[usize], repetitions: usize) -> serde_json::Value {
    crate::jobs::examples::twin_dispersion(sizes, repetitions)
}

/// The identification inputs of the twin's dispersion job (its 360 ball-centring
/// measurements and model), as the study prepares them.
pub fn dispersion_inputs() -> Result<IdentifyInputs, JobError> {
    let job = dispersion_job(&[75], 1);
    let plate = serde_json::from_value(job["ball_plate"].clone()).ok();
    crate::jobs::serial::identify::parse_inputs(
        &crate::jobs::Inputs::new(&NoReferences),
        &job["model"],
        None,
        &job["measurements"],
        plate.as_ref(),
        None,
        Default::default(),
    )
}

/// Write a `serial.fk` job over the IRB 120 twin into `dir`: the model file, a joints CSV
/// of `rows` random configurations (degrees) and `fk.json` naming both; the job file's path.
pub fn write_fk_job(dir: &Path, rows: usize) -> std::io::Result<PathBuf> {
    let twin = SerialTwin::irb120(1);
    std::fs::write(
        dir.join("irb120.json"),
        serde_json::to_string_pretty(&twin.file)?,
    )?;
    let file = std::fs::File::create(dir.join("joints.csv"))?;
    let mut sink = CsvSink::new(
        std::io::BufWriter::new(file),
        &["q1", "q2", "q3", "q4", "q5", "q6"],
    )?;
    let mut rng = Rng::new(5);
    for _ in 0..rows {
        let q: Vec<f64> = twin
            .random_q(&mut rng)
            .iter()
            .map(|v| v.to_degrees())
            .collect();
        sink.row(&q)?;
    }
    sink.finish()?;
    let job =
        serde_json::json!({"kind": "serial.fk", "model": "irb120.json", "joints": "joints.csv"});
    let path = dir.join("fk.json");
    std::fs::write(&path, serde_json::to_string_pretty(&job)?)?;
    Ok(path)
}

/// Reads references whole, as every job read its tables before streaming: the `serial.fk`
/// job then parses the table, computes the poses table and its JSON rows.
#[derive(Debug)]
pub struct WholeFiles(pub DirResolver);

impl Resolver for WholeFiles {
    fn read(&self, field: &str, reference: &str) -> Result<Vec<u8>, JobError> {
        self.0.read(field, reference)
    }
}

/// `calibd run fk.json --out poses.csv` in process: validate the job from its file, then
/// write the poses CSV, streamed (`whole` false) or from the job's result (`whole` true,
/// the path before streaming: tables and result held in memory).
pub fn run_fk_job(job: &Path, out: &Path, whole: bool) -> Result<usize, JobError> {
    let text = std::fs::read_to_string(job).map_err(|e| JobError::io("reading", Some(job), e))?;
    let doc: serde_json::Value = serde_json::from_str(&text).map_err(|e| JobError::Input {
        field: "job".into(),
        reference: job.display().to_string(),
        message: format!("not valid JSON: {e}"),
    })?;
    let dir = DirResolver {
        dir: job.parent().map(Path::to_path_buf).unwrap_or_default(),
    };
    if !whole {
        let prepared = prepare(&doc, &dir)?;
        return crate::jobs::offline::write_main_csv(&prepared, out, &NoMonitor);
    }
    let done = prepare(&doc, &WholeFiles(dir))?.run(&NoMonitor)?;
    let t = done
        .main_table
        .ok_or_else(|| JobError::internal("the whole-table run", "serial.fk has no main table"))?;
    std::fs::write(out, t.to_csv()).map_err(|e| JobError::io("writing", Some(out), e))?;
    Ok(t.rows.len())
}

/// `serial.fk` from a joints CSV file to a poses CSV file: streamed at 50,000 and 1,000,000
/// rows, and at 50,000 through the whole result (the path before streaming). The streamed
/// figures come first, while the process's memory is still low.
pub fn fk_tables() -> Vec<Figure> {
    let Ok(dir) = tempfile_dir() else {
        eprintln!("serial.fk benchmarks skipped: no temporary folder");
        return Vec::new();
    };
    let mut figs = Vec::new();
    let cases = [
        (
            50_000,
            false,
            5,
            "serial.fk 50,000 rows, CSV file -> CSV file, streamed",
        ),
        (
            1_000_000,
            false,
            3,
            "serial.fk 1,000,000 rows, CSV file -> CSV file, streamed",
        ),
        (
            50_000,
            true,
            5,
            "serial.fk 50,000 rows, whole table + result JSON (before)",
        ),
    ];
    for (rows, whole, runs, name) in cases {
        let job = match write_fk_job(&dir, rows) {
            Ok(j) => j,
            Err(e) => {
                eprintln!("serial.fk benchmark skipped: {e}");
                continue;
            }
        };
        let out = dir.join("poses.csv");
        figs.push(time(name, runs, 1, None, || {
            let n = run_fk_job(&job, &out, whole).expect("the twin job runs");
            assert_eq!(n, rows);
        }));
    }
    let _ = std::fs::remove_dir_all(&dir);
    figs
}

/// A fresh folder under the system's temporary folder.
fn tempfile_dir() -> std::io::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("calibd-bench-fk-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// The identification part of a dispersion study: DETMAX sets of each of `sizes` (four
/// seeds each, selected once, outside the timing), each identified as the study does
/// (values only) and as `serial.identify` does (with standard deviations); time per
/// identification.
fn dispersion_identifications(
    inputs: &IdentifyInputs,
    dp: &DesignPool,
    sizes: &[usize],
) -> Vec<Figure> {
    let sets: Vec<Vec<usize>> = sizes
        .iter()
        .flat_map(|&n| (0..4).map(move |r| (n, r)))
        .filter_map(|(n, r)| {
            let o = DetmaxOptions {
                n,
                seed: ((n as u64) << 32) ^ (r + 1),
                max_excursion: 4,
                path: false,
            };
            detmax(&dp.pool, &o, &NoMonitor).ok().map(|s| s.selected)
        })
        .collect();
    let mut sink = 0.0;
    let mut figs = Vec::new();
    // The 600 us budget is the study's, which identifies values only; the figure with
    // standard deviations is what one `serial.identify` job pays, shown beside it.
    for (name, values_only, target) in [
        (
            "dispersion identification (DETMAX set of 20..100 of 360), values only",
            true,
            Some(Duration::from_micros(600)),
        ),
        (
            "dispersion identification (DETMAX set of 20..100 of 360), with std",
            false,
            None,
        ),
    ] {
        figs.push(time(name, 5, sets.len(), target, || {
            for set in &sets {
                let r = if values_only {
                    inputs.identify_values(Some(set), &NoMonitor)
                } else {
                    inputs.identify(Some(set), &NoMonitor)
                };
                sink += r.map_or(0.0, |(_, s)| s.cost_after);
            }
        }));
    }
    std::hint::black_box(sink);
    figs
}

/// `serial.compensate`'s solver on one core: the joints of targets made by the twin's true
/// model (geometry, beta, compliance under gravity) at `qs`, the reference at home.
fn compensate(twin: &SerialTwin, qs: &[Vec<f64>], sink: &mut f64) -> Figure {
    use crate::model::compensate::{Compensator, Scratch, Tolerances};
    let tol = Tolerances {
        position: 1e-4,
        angle: 1e-5f64.to_radians(),
        singular_sin: 1e-3,
        singular_shoulder: 1.0,
    };
    let solver = Compensator::new(twin.truth.clone(), tol, 5.0).expect("the IRB 120 is an OPW arm");
    let targets: Vec<_> = qs
        .iter()
        .map(|q| {
            let tau = twin.truth.static_torques(q);
            twin.truth.tcp(q, Some(&tau))
        })
        .collect();
    let mut s = Scratch::default();
    time(
        "serial.compensate solver per target (IRB 120, calibrated model with compliance, one core)",
        11,
        targets.len(),
        Some(Duration::from_micros(10)),
        || {
            for t in &targets {
                *sink += solver.solve(t, &[0.0; 6], &mut s).q[0];
            }
        },
    )
}

/// The `serial.compensate` figure alone (`calibd bench serial.compensate`).
pub fn compensate_figures() -> Vec<Figure> {
    let twin = SerialTwin::irb120(1);
    let mut rng = Rng::new(9);
    let qs: Vec<Vec<f64>> = (0..10_000).map(|_| twin.random_q(&mut rng)).collect();
    let mut sink = 0.0;
    let fig = compensate(&twin, &qs, &mut sink);
    std::hint::black_box(sink);
    vec![fig]
}

/// The whole dispersion study of `sizes` x 223 repetitions (2,007 identifications for
/// the nine sizes 20..100), as a job runs it: wall and CPU time of one study.
fn dispersion_study(sizes: &[usize], sink: &mut f64) -> Figure {
    let study = prepare(&dispersion_job(sizes, 223), &NoReferences).expect("valid dispersion job");
    time(
        "dispersion study, 9 sizes x 223 = 2,007 identifications (all cores)",
        3,
        1,
        Some(Duration::from_millis(1500)),
        || {
            let r = study.run(&NoMonitor).expect("study runs");
            *sink += r.result["identifications"].as_f64().unwrap_or(0.0);
        },
    )
    .with_cpu_target(Duration::from_millis(2500))
}

/// `calibd bench serial.dispersion`: the dispersion study's figure alone.
pub fn dispersion_figures() -> Vec<Figure> {
    let sizes: Vec<usize> = (2..=10).map(|k| 10 * k).collect();
    let mut sink = 0.0;
    let fig = dispersion_study(&sizes, &mut sink);
    std::hint::black_box(sink);
    vec![fig]
}

/// Run the serial benchmarks.
pub fn run() -> Vec<Figure> {
    let mut figs = fk_tables();
    let twin = SerialTwin::irb120(1);
    let mut rng = Rng::new(9);
    let qs: Vec<Vec<f64>> = (0..10_000).map(|_| twin.random_q(&mut rng)).collect();
    let c = twin.nominal.clone();
    let mut sink = 0.0;
    figs.push(time(
        "FK + gravity torques per configuration (IRB 120)",
        15,
        qs.len(),
        Some(Duration::from_micros(1)),
        || {
            for q in &qs {
                let tau = c.static_torques(q);
                sink += c.tcp(q, Some(&tau)).p.x;
            }
        },
    ));
    figs.push(compensate(&twin, &qs, &mut sink));
    let meas = twin.centring(120, 2);
    figs.push(time(
        "identification, 31 parameters, 360 measurements",
        11,
        1,
        Some(Duration::from_millis(20)),
        || sink += super::identify::identify_once(&twin, &meas),
    ));
    let prepared = dispersion_inputs().expect("twin inputs are valid");
    let dp = DesignPool::new(&prepared).expect("pool builds");
    let mut seed = 0;
    figs.push(time(
        "DETMAX, 75 of 360 configurations",
        11,
        1,
        Some(Duration::from_millis(100)),
        || {
            seed += 1;
            let s = detmax(
                &dp.pool,
                &DetmaxOptions {
                    n: 75,
                    seed,
                    max_excursion: 6,
                    path: true,
                },
                &NoMonitor,
            )
            .expect("not cancelled");
            sink += s.log_det;
        },
    ));
    let sizes: Vec<usize> = (2..=10).map(|k| 10 * k).collect();
    figs.extend(dispersion_identifications(&prepared, &dp, &sizes));
    figs.push(dispersion_study(&sizes, &mut sink));
    std::hint::black_box(sink);
    figs
}
