//! The Agile Justin acceptance run (issue 13, item 5): the cumulative calibration table of
//! Tenhumberg and Baeuml (Humanoids 2021) with the published figures beside ours, and a
//! 5-fold held-out figure of the full model.
//!
//!     cargo run --release --example justin_elastic [subtree|bodies] [DATA_DIR]
//!
//! `subtree` lumps each joint's carried mass moment with its compliances (linear
//! coefficients); `bodies` (the default) identifies link weights shared by every joint that
//! carries them and per-joint compliances (bilinear).
//!
//! The data (`../shared/data/real/dlr_agile_justin/` by default, relative to the repository)
//! have no licence file and stay outside the repository; without them this says so and exits.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let lumping = match std::env::args().nth(1).as_deref() {
        Some("subtree") => calibd::model::elastic::Lumping::Subtree,
        Some("bodies") | None => calibd::model::elastic::Lumping::Bodies,
        Some(other) => return Err(format!("`{other}`: subtree or bodies").into()),
    };
    let dir = std::env::args().nth(2).map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real/dlr_agile_justin"),
        PathBuf::from,
    );
    let read = |f: &str| std::fs::read_to_string(dir.join(f));
    let (Ok(dh), Ok(guess), Ok(csv)) = (
        read("nominal_dh.yaml"),
        read("initial_guess.yaml"),
        read("measurements_flat.csv"),
    ) else {
        println!("skipped: Agile Justin data {} not found", dir.display());
        return Ok(());
    };
    let (model, obs) = calibd::measure::justin::setup(&dh, &guess, &csv, lumping)?;
    let report = calibd::measure::justin::run(&model, &obs, 5, 2021, &Steps)?;
    println!("lumping: {lumping:?}");
    print!("{}", calibd::measure::justin::table(&report));
    for s in &report.steps {
        println!("{}: held {:?}", s.name, s.held);
    }
    Ok(())
}

/// Prints each finished cumulative step (the messages that end in `mm`).
struct Steps;

impl calibd::util::Monitor for Steps {
    fn progress(&self, _fraction: f64, stage: &str) {
        if stage.ends_with("(mean / std / max)") {
            eprintln!("{stage}");
        }
    }
    fn is_cancelled(&self) -> bool {
        false
    }
}
