//! Ball plates: where the balls (or sockets) are in the world frame {W}. Three balls from
//! ballbar distances define {W} (`../shared/spec/serial-robot.md`); more balls, or balls known
//! only by some distances, become unknowns of the identification; a plate that cannot fix
//! every rotation (two balls) leaves a gauge freedom that rank detection reports.

use nalgebra::Vector3;

use super::MeasureError;

/// The balls of a plate: known centres, or unknown ones tied by distances.
#[derive(Debug, Clone, PartialEq)]
pub struct BallPlate {
    /// Centre of each ball in {W} if fixed by the definition, `None` if an unknown.
    pub centres: Vec<Option<Vector3<f64>>>,
    /// Known distances (0-based ball indices) that involve at least one unknown ball.
    pub distances: Vec<(usize, usize, f64)>,
    /// The freedom of {W} that the plate leaves, if any (e.g. two balls: rotation about
    /// the line through them).
    pub gauge: Option<String>,
}

impl BallPlate {
    /// Three balls from ballbar distances: ball 1 at the origin, ball 2 on +x, ball 3 in the
    /// xy-plane with y > 0.
    pub fn from_ballbar(d12: f64, d13: f64, d23: f64) -> Result<Self, MeasureError> {
        for (name, d) in [("d12", d12), ("d13", d13), ("d23", d23)] {
            if !(d.is_finite() && d > 0.0) {
                return Err(MeasureError::Plate(format!(
                    "{name} = {d} must be a positive distance"
                )));
            }
        }
        let px = (d12 * d12 + d13 * d13 - d23 * d23) / (2.0 * d12);
        let py2 = d13 * d13 - px * px;
        if !(py2 > 0.0) {
            return Err(MeasureError::Plate(format!(
                "d12 = {d12}, d13 = {d13}, d23 = {d23} do not form a triangle"
            )));
        }
        Ok(Self {
            centres: vec![
                Some(Vector3::zeros()),
                Some(Vector3::new(d12, 0.0, 0.0)),
                Some(Vector3::new(px, py2.sqrt(), 0.0)),
            ],
            distances: vec![],
            gauge: None,
        })
    }

    /// Balls with known centres in {W}.
    pub fn from_positions(p: &[[f64; 3]]) -> Result<Self, MeasureError> {
        if p.is_empty() {
            return Err(MeasureError::Plate("`positions` is empty".into()));
        }
        if let Some(k) = p.iter().position(|v| v.iter().any(|c| !c.is_finite())) {
            return Err(MeasureError::Plate(format!("positions[{k}] is not finite")));
        }
        Ok(Self {
            centres: p.iter().map(|v| Some(Vector3::from(*v))).collect(),
            distances: vec![],
            gauge: None,
        })
    }

    /// `n` balls known by pairwise distances (1-based indices in `distances`). Ball 1 is the
    /// origin and ball 2 lies on +x (d12 is required); ball 3 is placed in the xy-plane when d13
    /// and d23 are both known; every other ball is an unknown tied by its distances.
    pub fn from_distances(
        n: usize,
        distances: &[(usize, usize, f64)],
    ) -> Result<Self, MeasureError> {
        if n < 2 {
            return Err(MeasureError::Plate(format!(
                "`balls` = {n}: at least two balls are needed"
            )));
        }
        let mut d = std::collections::HashMap::new();
        for (k, &(i, j, v)) in distances.iter().enumerate() {
            if i == j || i < 1 || j < 1 || i > n || j > n {
                return Err(MeasureError::Plate(format!(
                    "distances[{k}]: ball indices {i}, {j} must differ and lie in 1..={n}"
                )));
            }
            if !(v.is_finite() && v > 0.0) {
                return Err(MeasureError::Plate(format!(
                    "distances[{k}]: {v} is not a positive distance"
                )));
            }
            d.insert((i.min(j), i.max(j)), v);
        }
        let d12 = *d.get(&(1, 2)).ok_or_else(|| {
            MeasureError::Plate(
                "the distance between balls 1 and 2 is required: it defines the x axis".into(),
            )
        })?;
        let mut centres = vec![Some(Vector3::zeros()), Some(Vector3::new(d12, 0.0, 0.0))];
        let mut gauge = None;
        if n == 2 {
            gauge = Some(
                "rotation of the world frame about the line through balls 1 and 2".to_string(),
            );
        } else if let (Some(&d13), Some(&d23)) = (d.get(&(1, 3)), d.get(&(2, 3))) {
            let p = Self::from_ballbar(d12, d13, d23)?;
            centres.push(p.centres[2]);
        } else {
            centres.push(None);
        }
        centres.extend((centres.len()..n).map(|_| None));
        let fixed = |k: usize| centres[k].is_some();
        let distances = d
            .into_iter()
            .filter(|&((i, j), _)| !(fixed(i - 1) && fixed(j - 1)))
            .map(|((i, j), v)| (i - 1, j - 1, v))
            .collect::<Vec<_>>();
        Ok(Self {
            centres,
            distances,
            gauge,
        })
    }

    /// Number of balls.
    pub fn len(&self) -> usize {
        self.centres.len()
    }

    /// True if the plate has no ball.
    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    /// Indices of the balls whose centres are unknowns.
    pub fn unknown_balls(&self) -> Vec<usize> {
        (0..self.centres.len())
            .filter(|&k| self.centres[k].is_none())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ballbar_triangle_reproduces_its_distances() {
        let p = BallPlate::from_ballbar(200.0, 150.0, 180.0).unwrap();
        let c: Vec<_> = p.centres.iter().map(|c| c.unwrap()).collect();
        assert!(((c[1] - c[0]).norm() - 200.0).abs() < 1e-12);
        assert!(((c[2] - c[0]).norm() - 150.0).abs() < 1e-12);
        assert!(((c[2] - c[1]).norm() - 180.0).abs() < 1e-12);
        assert!(c[2].y > 0.0 && c[2].z == 0.0);
        assert!(BallPlate::from_ballbar(100.0, 10.0, 10.0).is_err());
    }

    #[test]
    fn two_sockets_leave_a_gauge_and_bad_indices_are_named() {
        let p = BallPlate::from_distances(2, &[(1, 2, 0.05)]).unwrap();
        assert!(p.gauge.is_some());
        assert!(p.unknown_balls().is_empty());
        let e = BallPlate::from_distances(3, &[(1, 4, 0.05)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("distances[0]") && e.contains("1..=3"), "{e}");
        let p = BallPlate::from_distances(
            4,
            &[
                (1, 2, 1.0),
                (1, 3, 1.0),
                (2, 3, 1.0),
                (1, 4, 1.0),
                (2, 4, 1.0),
                (3, 4, 1.0),
            ],
        )
        .unwrap();
        assert_eq!(p.unknown_balls(), vec![3]);
        assert_eq!(p.distances.len(), 3);
    }
}
