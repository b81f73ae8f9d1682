//! The calibration plots, drawn with [`super::svg`]: errors before and after calibration
//! on logarithmic axes (an "after" of micrometres stays visible beside a "before" of
//! millimetres), per configuration, as a histogram and as a cumulative distribution; the
//! held-out validation errors; grouped bars per category (axis, marker, model, parameter).
//! Every plot names its unit and the data set it shows. The plots of design and study
//! results (criterion history, dispersion box plots) are in [`super::studies`].

use super::svg::{COLOURS, Frame, Scale, log_range};

/// Errors of one data set before and after calibration.
#[derive(Debug, Clone, Copy)]
pub struct ErrorSet<'a> {
    /// Error of every measurement with the nominal (starting) model.
    pub before: &'a [f64],
    /// Error of every measurement with the calibrated model.
    pub after: &'a [f64],
    /// Unit of the errors (e.g. `mm`).
    pub unit: &'a str,
    /// The data set they belong to, as the plot states it.
    pub dataset: &'a str,
}

/// Series names of the before/after marks (`data-series`).
pub const BEFORE: &str = "before";
/// Series name of the calibrated marks.
pub const AFTER: &str = "after";

const LEGEND_BEFORE: &str = "before calibration (nominal model)";
const LEGEND_AFTER: &str = "after calibration";

/// Bars of the error of every configuration, before and after side by side, on a log axis.
pub fn per_configuration(what: &str, set: &ErrorSet<'_>) -> String {
    let n = set.before.len().max(set.after.len());
    let mut c = Frame::new(
        &format!("{what} per configuration (log scale)"),
        set.dataset,
        "configuration",
        &format!("{what} ({})", set.unit),
    )
    .x((0.5, n as f64 + 0.5), Scale::Linear)
    .y(log_range(set.before.iter().chain(set.after)), Scale::Log)
    .chart();
    for (k, v) in set.before.iter().enumerate() {
        c.bar(BEFORE, k as f64 + 0.58, k as f64 + 1.0, *v, COLOURS[0], 1.0);
    }
    for (k, v) in set.after.iter().enumerate() {
        c.bar(AFTER, k as f64 + 1.0, k as f64 + 1.42, *v, COLOURS[1], 1.0);
    }
    c.x_ticks();
    c.legend(LEGEND_BEFORE, COLOURS[0]);
    c.legend(LEGEND_AFTER, COLOURS[1]);
    c.finish()
}

/// Counts of `values` in `bins` bins equal in log(value) over [lo, hi) (values outside
/// fall into the first or last bin; zero and negative ones into the first).
pub fn log_bin_counts(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<usize> {
    let mut counts = vec![0; bins.max(1)];
    let span = (hi / lo).log10();
    for v in values.iter().filter(|v| v.is_finite()) {
        let f = if *v > 0.0 {
            (v / lo).log10() / span
        } else {
            0.0
        };
        let k = (f * bins as f64)
            .floor()
            .clamp(0.0, (bins.max(1) - 1) as f64) as usize;
        counts[k] += 1;
    }
    counts
}

/// Histograms of the errors before and after on the same log-spaced bins.
pub fn histogram(set: &ErrorSet<'_>, bins_per_decade: usize) -> String {
    let (lo, hi) = log_range(set.before.iter().chain(set.after));
    let bins = ((hi / lo).log10().round() as usize * bins_per_decade).max(1);
    let cb = log_bin_counts(set.before, lo, hi, bins);
    let ca = log_bin_counts(set.after, lo, hi, bins);
    let top = cb.iter().chain(&ca).copied().max().unwrap_or(1).max(1) as f64 * 1.1;
    let mut c = Frame::new(
        "Histogram of errors (log-spaced bins)",
        set.dataset,
        &format!("error ({}, log scale)", set.unit),
        "measurements",
    )
    .x((lo, hi), Scale::Log)
    .y((0.0, top), Scale::Linear)
    .chart();
    let edge = |k: usize| lo * (hi / lo).powf(k as f64 / bins as f64);
    for (series, counts, colour) in [(BEFORE, &cb, COLOURS[0]), (AFTER, &ca, COLOURS[1])] {
        for (k, n) in counts.iter().enumerate().filter(|(_, n)| **n > 0) {
            c.bar(series, edge(k), edge(k + 1), *n as f64, colour, 0.75);
        }
    }
    c.x_ticks();
    c.legend(LEGEND_BEFORE, COLOURS[0]);
    c.legend(LEGEND_AFTER, COLOURS[1]);
    c.finish()
}

/// Cumulative distributions of the errors before and after, on a log error axis.
pub fn cdf(set: &ErrorSet<'_>) -> String {
    let (lo, hi) = log_range(set.before.iter().chain(set.after));
    let mut c = Frame::new(
        "Cumulative distribution of errors",
        set.dataset,
        &format!("error ({}, log scale)", set.unit),
        "fraction of measurements at or below",
    )
    .x((lo, hi), Scale::Log)
    .y((0.0, 1.0), Scale::Linear)
    .chart();
    for (series, v, colour) in [
        (BEFORE, set.before, COLOURS[0]),
        (AFTER, set.after, COLOURS[1]),
    ] {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        s.sort_by(f64::total_cmp);
        let n = s.len() as f64;
        let mut pts = vec![(lo, 0.0)];
        for (i, x) in s.iter().enumerate() {
            pts.push((*x, i as f64 / n));
            pts.push((*x, (i + 1) as f64 / n));
        }
        if let Some(last) = s.last() {
            pts.push((hi.max(*last), 1.0));
        }
        c.line(series, &pts, colour);
    }
    c.x_ticks();
    c.legend(LEGEND_BEFORE, COLOURS[0]);
    c.legend(LEGEND_AFTER, COLOURS[1]);
    c.finish()
}

/// One series of grouped category bars: `data-series` name, legend text, a value per
/// category (none: no bar).
#[derive(Debug, Clone, Copy)]
pub struct Series<'a> {
    /// The `data-series` name.
    pub name: &'a str,
    /// Legend text.
    pub legend: &'a str,
    /// One value per category.
    pub values: &'a [Option<f64>],
}

/// Grouped bars per category (axis, marker, posture, model) on a log value axis, with
/// slanted category labels.
pub fn category_bars(
    title: &str,
    dataset: &str,
    value_label: &str,
    categories: &[String],
    series: &[Series<'_>],
) -> String {
    let n = categories.len();
    let all: Vec<f64> = series
        .iter()
        .flat_map(|s| s.values.iter().flatten().copied())
        .collect();
    let longest = categories
        .iter()
        .map(|c| c.chars().count())
        .max()
        .unwrap_or(0);
    let mut c = Frame::new(title, dataset, "", value_label)
        .x((0.5, n as f64 + 0.5), Scale::Linear)
        .y(log_range(&all), Scale::Log)
        .extra_bottom((longest as f64 * 4.5).min(140.0))
        .chart();
    let k = series.len().max(1) as f64;
    let w = 0.84 / k;
    for (j, s) in series.iter().enumerate() {
        let colour = COLOURS[j % COLOURS.len()];
        for (i, v) in s.values.iter().enumerate() {
            if let Some(v) = v {
                let a = i as f64 + 0.58 + j as f64 * w;
                c.bar(s.name, a, a + w, *v, colour, 1.0);
            }
        }
        c.legend(s.legend, colour);
    }
    for (i, name) in categories.iter().enumerate() {
        let p = c.px(i as f64 + 1.0);
        c.x_category_at(p, name);
    }
    c.finish()
}

/// Before/after grouped bars per category (two series named [`BEFORE`] and [`AFTER`]).
pub fn before_after_bars(
    title: &str,
    dataset: &str,
    value_label: &str,
    categories: &[String],
    before: &[Option<f64>],
    after: &[Option<f64>],
) -> String {
    category_bars(
        title,
        dataset,
        value_label,
        categories,
        &[
            Series {
                name: BEFORE,
                legend: LEGEND_BEFORE,
                values: before,
            },
            Series {
                name: AFTER,
                legend: LEGEND_AFTER,
                values: after,
            },
        ],
    )
}

/// Commanded against attained positions along a trajectory (ISO 9283 pose accuracy): the
/// commanded path and each attained mean position, its deviation magnified by a power of
/// ten (said in the legend) so that micrometres show on a path of millimetres.
pub fn trajectory(
    commanded: &[(f64, f64)],
    attained: &[(f64, f64)],
    unit: &str,
    dataset: &str,
) -> String {
    let dev = commanded
        .iter()
        .zip(attained)
        .map(|(c, a)| (a.0 - c.0).hypot(a.1 - c.1))
        .fold(0.0, f64::max);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in commanded {
        (x0, x1, y0, y1) = (x0.min(*x), x1.max(*x), y0.min(*y), y1.max(*y));
    }
    let span = (x1 - x0).max(y1 - y0).max(f64::MIN_POSITIVE);
    let k = if dev > 0.0 {
        10f64.powf((0.15 * span / dev).log10().floor()).max(1.0)
    } else {
        1.0
    };
    let shown: Vec<(f64, f64)> = commanded
        .iter()
        .zip(attained)
        .map(|(c, a)| (c.0 + k * (a.0 - c.0), c.1 + k * (a.1 - c.1)))
        .collect();
    // Equal scales on both axes: pixels per unit the same (plot area 622 x 291 px).
    let pad = 0.15 * span;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let half_y = (span / 2.0 + pad).max((x1 - x0) / 2.0 * 291.0 / 622.0 + pad);
    let half_x = half_y * 622.0 / 291.0;
    let mut c = Frame::new(
        "Commanded and attained positions (ISO 9283)",
        dataset,
        &format!("x ({unit})"),
        &format!("y ({unit})"),
    )
    .x((cx - half_x, cx + half_x), Scale::Linear)
    .y((cy - half_y, cy + half_y), Scale::Linear)
    .chart();
    let mut path = commanded.to_vec();
    if let Some(first) = commanded.first() {
        path.push(*first);
    }
    c.line("commanded-path", &path, "#999999");
    c.points("commanded", commanded, COLOURS[0]);
    c.points(AFTER, &shown, COLOURS[1]);
    for (a, b) in commanded.iter().zip(&shown) {
        c.line("deviation", &[*a, *b], COLOURS[1]);
    }
    c.x_ticks();
    c.legend("commanded", COLOURS[0]);
    c.legend(
        &if k > 1.0 {
            format!("attained (mean of repetitions), deviation x{k}")
        } else {
            "attained (mean of repetitions)".to_string()
        },
        COLOURS[1],
    );
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::super::svg::series_marks;
    use super::*;

    /// The case: before 1.5-4 mm, after about 0.003 mm.
    const BEFORE_MM: [f64; 4] = [1.5, 2.2, 4.0, 3.1];
    const AFTER_MM: [f64; 4] = [0.0031, 0.0024, 0.0042, 0.0029];

    fn set() -> ErrorSet<'static> {
        ErrorSet {
            before: &BEFORE_MM,
            after: &AFTER_MM,
            unit: "mm",
            dataset: "calibration set: 4 configurations",
        }
    }

    #[test]
    fn after_bars_have_a_visible_extent_beside_the_before_bars() {
        let svg = per_configuration("Position error", &set());
        let (b, a) = (series_marks(&svg, BEFORE), series_marks(&svg, AFTER));
        assert_eq!(b.len(), 4);
        assert_eq!(a.len(), 4);
        // Bars in order, values as given.
        let values: Vec<f64> = a.iter().map(|m| m.value).collect();
        assert_eq!(values, AFTER_MM);
        // Axis 0.001..10 mm (4 decades over 291 px): 0.0024 mm is 0.38 decades up.
        for m in &a {
            assert!(
                m.extent > 20.0,
                "after bar of {} mm is {} px",
                m.value,
                m.extent
            );
        }
        // Order preserved: the larger error has the taller bar.
        assert!(a[3].extent > a[1].extent && b[2].extent > b[0].extent);
        assert!(b.iter().all(|m| m.extent > 150.0));
        assert!(svg.contains("(mm)") && svg.contains("calibration set: 4 configurations"));
    }

    #[test]
    fn histogram_and_cdf_show_both_series() {
        let svg = histogram(&set(), 4);
        let counted = |s: &str| -> f64 { series_marks(&svg, s).iter().map(|m| m.value).sum() };
        assert_eq!(counted(BEFORE), 4.0);
        assert_eq!(counted(AFTER), 4.0);
        assert!(series_marks(&svg, AFTER).iter().all(|m| m.extent > 20.0));
        let c = cdf(&set());
        assert_eq!(c.matches("data-series=\"after\"").count(), 1);
        assert!(c.contains("mm, log scale"));
    }

    #[test]
    fn log_bins_count_every_value_once() {
        let v = [0.0, 0.001, 0.005, 0.012, 0.5, 10.0];
        // Two bins per decade over [0.001, 10): edges 0.001, 0.00316, 0.01, ..., 10.
        let c = log_bin_counts(&v, 0.001, 10.0, 8);
        assert_eq!(c.iter().sum::<usize>(), v.len());
        assert_eq!(c, vec![2, 1, 1, 0, 0, 1, 0, 1]);
    }

    #[test]
    fn trajectory_magnifies_micrometre_deviations_on_a_millimetre_path() {
        let cmd = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)];
        let att = [(0.001, 0.0), (2.0, 0.002), (1.999, 2.0), (0.0, 2.001)];
        let svg = trajectory(&cmd, &att, "mm", "trajectory: square 2 mm");
        assert!(svg.contains("deviation x100"), "{svg}");
        assert_eq!(series_marks(&svg, AFTER).len(), 4);
        assert_eq!(series_marks(&svg, "commanded").len(), 4);
    }

    #[test]
    fn category_bars_draw_every_present_value() {
        let cats = vec!["x".to_string(), "y".into(), "z".into()];
        let svg = before_after_bars(
            "RMS error per axis",
            "calibration set",
            "RMS error (mm)",
            &cats,
            &[Some(2.0), Some(1.0), Some(3.0)],
            &[Some(0.002), None, Some(0.004)],
        );
        assert_eq!(series_marks(&svg, BEFORE).len(), 3);
        let a = series_marks(&svg, AFTER);
        assert_eq!(a.len(), 2);
        assert!(a.iter().all(|m| m.extent > 20.0));
        assert!(svg.contains(">z</text>"));
    }
}
