//! `calibd bench compare OLD.json NEW.json`: two saved benchmark runs (`calibd bench AREA
//! --json FILE`) side by side, figure by figure: the ratio of the medians, and a verdict that
//! counts a change only beyond the noise the two runs themselves show (their min-max spread).

use std::collections::BTreeMap;

use serde::Deserialize;

/// A figure as `--json` writes it (times in seconds per operation).
#[derive(Debug, Clone, Deserialize)]
pub struct SavedFigure {
    /// What was measured.
    pub name: String,
    /// Median time per operation (s).
    pub median_per_op_s: f64,
    /// Fastest run per operation (s).
    pub min_per_op_s: f64,
    /// Slowest run per operation (s).
    pub max_per_op_s: f64,
    /// CPU time of the median run per operation (s), when measured.
    #[serde(default)]
    pub cpu_per_op_s: Option<f64>,
    /// Peak resident memory during the runs (bytes), when measured.
    #[serde(default)]
    pub peak_rss_bytes: Option<u64>,
}

/// One area of a saved run.
#[derive(Debug, Clone, Deserialize)]
pub struct SavedArea {
    /// `serial`, `pcr`, ...
    pub area: String,
    /// Its figures.
    pub figures: Vec<SavedFigure>,
}

/// A saved run.
#[derive(Debug, Clone, Deserialize)]
pub struct SavedReport {
    /// calibd version that ran it.
    pub version: String,
    /// When it ended (UTC).
    pub finished_at: String,
    /// Logical CPUs of the machine.
    pub cpus: usize,
    /// Figures per area.
    pub areas: Vec<SavedArea>,
}

/// Why a saved run cannot be read.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct CompareError {
    /// The file.
    pub file: String,
    /// What was wrong.
    pub message: String,
}

impl SavedReport {
    /// Parse the JSON `text` of `file` (named in errors).
    pub fn parse(file: &str, text: &str) -> Result<Self, CompareError> {
        let r: SavedReport = serde_json::from_str(text).map_err(|e| CompareError {
            file: file.into(),
            message: format!("not a `calibd bench --json` file: {e}"),
        })?;
        for a in &r.areas {
            for f in &a.figures {
                let t = [f.median_per_op_s, f.min_per_op_s, f.max_per_op_s];
                if t.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                    return Err(CompareError {
                        file: file.into(),
                        message: format!(
                            "figure `{}` of area `{}` has a time that is not a finite number >= 0",
                            f.name, a.area
                        ),
                    });
                }
            }
        }
        Ok(r)
    }
}

/// What a change of one figure amounts to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// Slower beyond the noise.
    Regression,
    /// Faster beyond the noise.
    Improvement,
    /// Within the noise.
    Same,
    /// Only in the new run.
    New,
    /// Only in the old run.
    Gone,
}

impl Change {
    /// The word printed.
    pub fn as_str(self) -> &'static str {
        match self {
            Change::Regression => "SLOWER",
            Change::Improvement => "faster",
            Change::Same => "same",
            Change::New => "new",
            Change::Gone => "gone",
        }
    }
}

/// One figure of the comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Area.
    pub area: String,
    /// Figure name.
    pub name: String,
    /// Old median per operation (s).
    pub old_s: Option<f64>,
    /// New median per operation (s).
    pub new_s: Option<f64>,
    /// New / old median.
    pub ratio: Option<f64>,
    /// The relative change counted as noise for this figure.
    pub noise: f64,
    /// The verdict.
    pub change: Change,
    /// New / old peak resident memory, when both runs measured it.
    pub memory_ratio: Option<f64>,
}

/// Smallest relative change ever counted (timer and scheduling jitter of a quiet machine).
pub const MIN_NOISE: f64 = 0.05;

/// Relative spread of a figure's runs: (max - min) / median.
fn spread(f: &SavedFigure) -> f64 {
    if f.median_per_op_s > 0.0 {
        (f.max_per_op_s - f.min_per_op_s) / f.median_per_op_s
    } else {
        0.0
    }
}

/// Compare every figure of `old` and `new` (matched by area and name), in the new run's
/// order, then the figures that are gone. A change counts when the ratio of the medians
/// leaves 1 by more than the larger spread of the two runs (at least [`MIN_NOISE`]).
/// A name is matched up to its first `": "`: what follows (a rate some figures carry in
/// their name, e.g. `pattern_pose 1024x1024: 198 images/s`) changes from run to run.
pub fn compare(old: &SavedReport, new: &SavedReport) -> Vec<Row> {
    let key = |a: &str, n: &str| {
        let stem = n.split_once(": ").map_or(n, |(stem, _)| stem);
        (a.to_string(), stem.to_string())
    };
    let olds: BTreeMap<(String, String), &SavedFigure> = old
        .areas
        .iter()
        .flat_map(|a| a.figures.iter().map(move |f| (key(&a.area, &f.name), f)))
        .collect();
    let mut seen = std::collections::BTreeSet::new();
    let mut rows = Vec::new();
    for a in &new.areas {
        for f in &a.figures {
            let k = key(&a.area, &f.name);
            seen.insert(k.clone());
            let Some(o) = olds.get(&k) else {
                rows.push(Row {
                    area: a.area.clone(),
                    name: f.name.clone(),
                    old_s: None,
                    new_s: Some(f.median_per_op_s),
                    ratio: None,
                    noise: spread(f).max(MIN_NOISE),
                    change: Change::New,
                    memory_ratio: None,
                });
                continue;
            };
            let noise = spread(o).max(spread(f)).max(MIN_NOISE);
            let ratio = (o.median_per_op_s > 0.0).then(|| f.median_per_op_s / o.median_per_op_s);
            let change = match ratio {
                Some(r) if r > 1.0 + noise => Change::Regression,
                Some(r) if r < 1.0 / (1.0 + noise) => Change::Improvement,
                _ => Change::Same,
            };
            let memory_ratio = o
                .peak_rss_bytes
                .zip(f.peak_rss_bytes)
                .filter(|(a, _)| *a > 0)
                .map(|(a, b)| b as f64 / a as f64);
            rows.push(Row {
                area: a.area.clone(),
                name: f.name.clone(),
                old_s: Some(o.median_per_op_s),
                new_s: Some(f.median_per_op_s),
                ratio,
                noise,
                change,
                memory_ratio,
            });
        }
    }
    for ((area, name), o) in &olds {
        if !seen.contains(&(area.clone(), name.clone())) {
            rows.push(Row {
                area: area.clone(),
                name: name.clone(),
                old_s: Some(o.median_per_op_s),
                new_s: None,
                ratio: None,
                noise: spread(o).max(MIN_NOISE),
                change: Change::Gone,
                memory_ratio: None,
            });
        }
    }
    rows
}

/// The comparison as a table for a terminal, with a summary line.
pub fn render(old: &SavedReport, new: &SavedReport, rows: &[Row]) -> String {
    let d = |s: Option<f64>| {
        s.map(|v| super::fmt(std::time::Duration::from_secs_f64(v)))
            .unwrap_or_else(|| "-".into())
    };
    let w = rows
        .iter()
        .map(|r| r.area.len() + r.name.len() + 1)
        .max()
        .unwrap_or(6);
    let mut out = format!(
        "old: calibd {} at {} ({} CPUs)\nnew: calibd {} at {} ({} CPUs)\n{:<w$}  {:>10}  {:>10}  {:>7}  {:>6}  {:<6}  memory\n",
        old.version,
        old.finished_at,
        old.cpus,
        new.version,
        new.finished_at,
        new.cpus,
        "figure",
        "old",
        "new",
        "new/old",
        "noise",
        "change"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<w$}  {:>10}  {:>10}  {:>7}  {:>5.0}%  {:<6}  {}\n",
            format!("{}/{}", r.area, r.name),
            d(r.old_s),
            d(r.new_s),
            r.ratio
                .map(|x| format!("{x:.2}x"))
                .unwrap_or_else(|| "-".into()),
            r.noise * 100.0,
            r.change.as_str(),
            r.memory_ratio
                .map(|x| format!("{x:.2}x"))
                .unwrap_or_default(),
        ));
    }
    let n = |c: Change| rows.iter().filter(|r| r.change == c).count();
    out.push_str(&format!(
        "{} slower, {} faster, {} within the noise, {} new, {} gone\n",
        n(Change::Regression),
        n(Change::Improvement),
        n(Change::Same),
        n(Change::New),
        n(Change::Gone)
    ));
    out
}

#[cfg(test)]
mod tests;
