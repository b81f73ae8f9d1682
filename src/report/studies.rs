//! The plots of design and study results, drawn with [`super::svg`]: the history of an
//! observability criterion against the design's progress (DETMAX exchanges, NOCP blocks of
//! postures) and the box plots of a dispersion study on a logarithmic error axis (the
//! TriCal Table 7 view). Every plot names its unit and the data set it shows.

use super::svg::{COLOURS, Frame, Scale, log_range};

/// Series name of a criterion history's points (`data-series`).
pub const HISTORY: &str = "history";
/// Series name of the point a design kept (when it is not the last one).
pub const CHOSEN: &str = "chosen";

/// What a history plot shows.
#[derive(Debug, Clone, Copy)]
pub struct History<'a> {
    /// Title (what is plotted).
    pub title: &'a str,
    /// The data set (and method) the history belongs to.
    pub dataset: &'a str,
    /// x axis label with unit (e.g. "accepted DETMAX exchange").
    pub x_label: &'a str,
    /// y axis label with unit (e.g. "O1 (dimensionless)").
    pub y_label: &'a str,
    /// (x, criterion) in the order the design went through them.
    pub points: &'a [(f64, f64)],
    /// The point the design kept, when it is not the last one (NOCP's plateau rule keeps
    /// the set before the last block).
    pub chosen: Option<(f64, f64)>,
}

/// A criterion against the design's progress: a line through the points, each point
/// marked (`data-series="history"`, `data-value` the criterion), on a linear axis from 0
/// so the gain reads as a ratio of heights.
pub fn history(h: &History<'_>) -> String {
    let finite: Vec<(f64, f64)> = h
        .points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let (x0, x1) = finite
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (x, _)| {
            (a.min(*x), b.max(*x))
        });
    let (x0, x1) = if x0.is_finite() { (x0, x1) } else { (0.0, 1.0) };
    let pad = ((x1 - x0) * 0.05).max(0.5);
    let top = finite.iter().map(|p| p.1).fold(0.0, f64::max).max(1e-300) * 1.1;
    let mut c = Frame::new(h.title, h.dataset, h.x_label, h.y_label)
        .x((x0 - pad, x1 + pad), Scale::Linear)
        .y((0.0, top), Scale::Linear)
        .chart();
    c.line("history-line", &finite, COLOURS[1]);
    c.points(HISTORY, &finite, COLOURS[1]);
    c.legend("criterion after each step", COLOURS[1]);
    if let Some(p) = h.chosen {
        c.points(CHOSEN, &[p], COLOURS[0]);
        c.legend("the set kept", COLOURS[0]);
    }
    c.x_ticks();
    c.finish()
}

/// Box plots (min, q1, median, q3, max) of `series` per calibration set size, on a
/// logarithmic axis of `what` (`unit`); the x axis names each size.
pub fn boxplots_log(
    boxes: &[(f64, [f64; 5])],
    what: &str,
    series: &str,
    dataset: &str,
    unit: &str,
) -> String {
    let k = boxes.len() as f64;
    let mut c = Frame::new(
        &format!("{what} against calibration set size (log scale)"),
        dataset,
        "configurations in the calibration set",
        &format!("{what} ({unit}, log scale)"),
    )
    .x((0.5, k + 0.5), Scale::Linear)
    .y(log_range(boxes.iter().flat_map(|b| b.1.iter())), Scale::Log)
    .chart();
    for (i, (n, q)) in boxes.iter().enumerate() {
        let x = i as f64 + 1.0;
        c.boxplot(series, x, 0.5, *q, COLOURS[2]);
        let p = c.px(x);
        c.x_label_at(p, &format!("{n}"));
    }
    c.legend(
        "box: quartiles q1-q3, line: median, whiskers: min-max",
        COLOURS[2],
    );
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::super::svg::{series_boxes, series_marks};
    use super::*;

    #[test]
    fn history_marks_every_step_and_the_kept_set() {
        let pts = [(0.0, 0.2), (1.0, 0.35), (2.0, 0.41)];
        let svg = history(&History {
            title: "O1 during DETMAX",
            dataset: "pool of 50 configurations",
            x_label: "accepted exchange",
            y_label: "O1 (dimensionless)",
            points: &pts,
            chosen: Some((1.0, 0.35)),
        });
        let m = series_marks(&svg, HISTORY);
        assert_eq!(
            m.iter().map(|m| m.value).collect::<Vec<_>>(),
            [0.2, 0.35, 0.41]
        );
        // Linear from 0: heights in the ratio of the values.
        assert!((m[2].extent / m[0].extent - 0.41 / 0.2).abs() < 0.05);
        assert_eq!(series_marks(&svg, CHOSEN).len(), 1);
        assert!(svg.contains("O1 (dimensionless)") && svg.contains("pool of 50"));
    }

    #[test]
    fn dispersion_boxes_sit_on_a_log_axis_with_their_quartiles() {
        let boxes = [
            (10.0, [0.05, 0.08, 0.1, 0.2, 0.9]),
            (40.0, [0.004, 0.005, 0.006, 0.007, 0.01]),
        ];
        let svg = boxplots_log(
            &boxes,
            "Mean validation error",
            "mean",
            "validation set",
            "mm",
        );
        assert!(svg.contains("data-y-scale=\"log\""));
        assert_eq!(series_boxes(&svg, "mean"), [boxes[0].1, boxes[1].1]);
        // Both boxes visible although their errors differ by a factor of 15.
        assert!(series_marks(&svg, "mean").iter().all(|m| m.extent > 5.0));
        assert!(svg.contains(">40</text>") && svg.contains("mm, log scale"));
    }
}
