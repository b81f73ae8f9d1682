//! Validation outside the training range: per joint, the range the validation rows span
//! against the range the calibration rows span. A calibrated model is only known to be
//! good where it was fitted; held-out errors of poses beyond that say how it extrapolates.

/// One joint axis as the result names it.
#[derive(Debug, Clone)]
pub struct JointAxis {
    /// Joint name.
    pub name: String,
    /// Unit the ranges are reported in (`deg`, `mm`, ...).
    pub unit: String,
    /// Factor from the rows' values to `unit`.
    pub to_unit: f64,
    /// How far (rows' units) validation may go past the training range before it counts
    /// as outside: measurement jitter, not extrapolation.
    pub margin: f64,
}

impl JointAxis {
    /// A revolute joint with values in rad, reported in deg, margin 1 deg.
    pub fn revolute(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            unit: "deg".into(),
            to_unit: 1f64.to_degrees(),
            margin: 1f64.to_radians(),
        }
    }

    /// A prismatic joint in `unit` (also the rows' unit), margin 1 % of the training span.
    pub fn prismatic(name: impl Into<String>, unit: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            unit: unit.into(),
            to_unit: 1.0,
            margin: 0.0,
        }
    }
}

/// A joint whose validation range leaves its training range.
#[derive(Debug, Clone, PartialEq)]
pub struct OutOfRange {
    /// Joint name.
    pub joint: String,
    /// Unit of the ranges.
    pub unit: String,
    /// Training range [min, max].
    pub training: [f64; 2],
    /// Validation range [min, max].
    pub validation: [f64; 2],
    /// Validation rows outside the training range (plus margin).
    pub outside: usize,
    /// Validation rows.
    pub rows: usize,
}

impl OutOfRange {
    /// A sentence for the verdict.
    pub fn message(&self) -> String {
        format!(
            "joint {}: validation spans [{:.1}, {:.1}] {u}, training [{:.1}, {:.1}] {u}; {} of {} \
             validation rows lie outside the training range, so their held-out errors measure \
             extrapolation, not the accuracy where the model was fitted",
            self.joint,
            self.validation[0],
            self.validation[1],
            self.training[0],
            self.training[1],
            self.outside,
            self.rows,
            u = self.unit
        )
    }
}

fn range(rows: &[&[f64]], k: usize) -> Option<[f64; 2]> {
    rows.iter()
        .filter_map(|q| q.get(k).copied())
        .filter(|v| v.is_finite())
        .fold(None, |r, v| match r {
            None => Some([v, v]),
            Some([lo, hi]) => Some([lo.min(v), hi.max(v)]),
        })
}

/// The joints (`axes[k]` is column `k` of the rows) whose validation rows leave the
/// training rows' range by more than the axis margin plus 1 % of the training span.
pub fn out_of_range(
    axes: &[JointAxis],
    train: &[&[f64]],
    validation: &[&[f64]],
) -> Vec<OutOfRange> {
    axes.iter()
        .enumerate()
        .filter_map(|(k, axis)| {
            let [lo, hi] = range(train, k)?;
            let [vlo, vhi] = range(validation, k)?;
            let margin = axis.margin + 0.01 * (hi - lo);
            let outside = validation
                .iter()
                .filter_map(|q| q.get(k))
                .filter(|v| **v < lo - margin || **v > hi + margin)
                .count();
            (outside > 0).then(|| OutOfRange {
                joint: axis.name.clone(),
                unit: axis.unit.clone(),
                training: [lo * axis.to_unit, hi * axis.to_unit],
                validation: [vlo * axis.to_unit, vhi * axis.to_unit],
                outside,
                rows: validation.len(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joint_beyond_the_training_range_is_named_with_both_ranges() {
        let d = |v: f64| v.to_radians();
        let train: Vec<Vec<f64>> = (0..20)
            .map(|i| vec![d(i as f64), d(-120.0 + 4.0 * i as f64)])
            .collect();
        let val: Vec<Vec<f64>> = vec![
            vec![d(5.0), d(-60.0)],
            vec![d(10.0), d(69.0)],
            vec![d(19.5), d(-42.0)],
        ];
        let t: Vec<&[f64]> = train.iter().map(Vec::as_slice).collect();
        let v: Vec<&[f64]> = val.iter().map(Vec::as_slice).collect();
        let axes = [JointAxis::revolute("q1"), JointAxis::revolute("q6")];
        let out = out_of_range(&axes, &t, &v);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].joint, "q6");
        // -42 deg is 2 deg past -44, beyond the margin (1 deg + 1 % of the 76 deg span).
        assert_eq!(out[0].outside, 2);
        assert!((out[0].validation[1] - 69.0).abs() < 1e-9);
        assert!((out[0].training[1] + 44.0).abs() < 1e-9);
        assert!(
            out[0].message().contains("[-120.0, -44.0] deg"),
            "{}",
            out[0].message()
        );
        // Inside the training range: nothing to say.
        assert!(out_of_range(&axes, &t, &t).is_empty());
    }
}
