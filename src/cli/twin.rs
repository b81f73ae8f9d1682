//! `calibd twin WHICH`: a digital twin's data set written into a folder.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// Options of `calibd twin`.
#[derive(Debug, clap::Args)]
pub(crate) struct TwinArgs {
    /// Which twin: `serial` (IRB 120 ball-centring cell), `pcr` (3-PF robot under its
    /// microscope), `pattern` (microscope frames of the platform's pattern, PNG, with
    /// their true poses and a `pcr.pattern_pose` job).
    which: String,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the true parameters and of the data.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[command(flatten)]
    pattern: PatternArgs,
}

/// Options of `calibd twin pattern`.
#[derive(Debug, clap::Args)]
#[command(next_help_heading = "twin pattern")]
struct PatternArgs {
    /// `periodic` (cosine grid, position modulo the period) or `encoded` (dots with missing
    /// ones coding the period's index: absolute position).
    #[arg(long, default_value = "periodic")]
    kind: String,
    /// Number of frames.
    #[arg(long, default_value_t = 10)]
    count: usize,
    /// Side of the square frames (px).
    #[arg(long, default_value_t = 1024)]
    size_px: usize,
    /// Period of the pattern (um).
    #[arg(long, default_value_t = 10.0)]
    period_um: f64,
    /// Pixel size in the object plane (um).
    #[arg(long, default_value_t = 1.0)]
    pixel_um: f64,
    /// 8 or 16 bits per pixel.
    #[arg(long, default_value_t = 16)]
    bits: u8,
    /// Gaussian noise, standard deviation as a fraction of full scale.
    #[arg(long, default_value_t = 0.01)]
    noise: f64,
}

/// `calibd twin`: write the twin's files and say what was written.
pub(crate) fn twin(a: TwinArgs) -> Result<()> {
    write_twin(&a.which, &a.out, a.seed, &a.pattern)
}

/// The files of twin `which` (seed `seed`) into `out`.
fn write_twin(which: &str, out: &Path, seed: u64, pattern: &PatternArgs) -> Result<()> {
    if which == "pattern" {
        use calibd::jobs::pcr::pattern_pose::{PatternTwin, twin_files};
        use calibd::measure::pattern::PatternKind;
        let kind = match pattern.kind.as_str() {
            "periodic" => PatternKind::Periodic,
            "encoded" => PatternKind::Encoded,
            k => bail!("unknown pattern kind `{k}` (known: periodic, encoded)"),
        };
        let files = twin_files(&PatternTwin {
            kind,
            count: pattern.count,
            size_px: pattern.size_px,
            period_um: pattern.period_um,
            pixel_um: pattern.pixel_um,
            bit_depth: pattern.bits,
            noise_frac: pattern.noise,
            seed,
        })?;
        std::fs::create_dir_all(out)?;
        for (name, bytes) in &files {
            std::fs::write(out.join(name), bytes).with_context(|| format!("writing {name}"))?;
        }
        eprintln!(
            "wrote {} frames (frame_000.png ...), truth.csv and pattern_pose.json to {}",
            pattern.count,
            out.display()
        );
        return Ok(());
    }
    if which == "pcr" {
        std::fs::create_dir_all(out)?;
        for (name, text) in calibd::jobs::pcr::twin_files(seed)? {
            std::fs::write(out.join(&name), text).with_context(|| format!("writing {name}"))?;
        }
        eprintln!(
            "wrote pcr3pf.json, pcr3pf_true.json, calibration.csv (99 rows), validation.csv (56 rows), joints.csv (20 rows) and poses.csv (16 rows) to {}",
            out.display()
        );
        return Ok(());
    }
    if which != "serial" {
        bail!("unknown twin `{which}` (known: serial, pcr, pattern)");
    }
    let twin = calibd::twin::SerialTwin::irb120(seed);
    std::fs::create_dir_all(out)?;
    let dof = twin.nominal.dof();
    let centring = calibd::jobs::serial::measurement_table(&twin.centring(120, seed + 1), dof);
    let tracker = calibd::jobs::serial::measurement_table(&twin.tracker(200, seed + 2), dof);
    std::fs::write(out.join("centring.csv"), centring.to_csv())?;
    std::fs::write(out.join("tracker.csv"), tracker.to_csv())?;
    std::fs::write(
        out.join("irb120.json"),
        serde_json::to_string_pretty(&twin.file)?,
    )?;
    let truth = twin.file.with_chain(&twin.truth);
    std::fs::write(
        out.join("irb120_true.json"),
        serde_json::to_string_pretty(&truth)?,
    )?;
    eprintln!(
        "wrote centring.csv (360 rows), tracker.csv (200 rows), irb120.json and irb120_true.json to {}",
        out.display()
    );
    Ok(())
}
