//! ISO 9283 position characteristics in any dimension: pose accuracy AP (distance from the
//! commanded position to the barycentre of the attained ones), pose repeatability RP (mean
//! distance of the attained positions from their barycentre plus three standard
//! deviations) and distance accuracy AD (mean attained distance between two poses minus the
//! commanded one). Shared by the planar 3-PF ([`super::pcr::accuracy`]) and the serial cell.

use serde::Serialize;

use crate::util::stats::mean;

/// AP and RP of one commanded position.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PositionAccuracy {
    /// Pose accuracy AP (length unit of the input).
    pub ap: f64,
    /// Pose repeatability RP (same unit).
    pub rp: f64,
    /// Barycentre of the attained positions.
    pub barycentre: Vec<f64>,
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// Sample standard deviation (n - 1; zero for fewer than two values).
fn sample_std(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// The barycentre of `attained` (each of the commanded position's dimension).
pub fn barycentre(dim: usize, attained: &[Vec<f64>]) -> Vec<f64> {
    (0..dim)
        .map(|k| mean(&attained.iter().map(|p| p[k]).collect::<Vec<_>>()))
        .collect()
}

/// ISO 9283 AP and RP of `commanded` from the positions attained over the cycles (at
/// least one, each of the commanded position's dimension).
pub fn position_accuracy(commanded: &[f64], attained: &[Vec<f64>]) -> PositionAccuracy {
    let b = barycentre(commanded.len(), attained);
    let l: Vec<f64> = attained.iter().map(|p| dist(p, &b)).collect();
    PositionAccuracy {
        ap: dist(&b, commanded),
        rp: mean(&l) + 3.0 * sample_std(&l),
        barycentre: b,
    }
}

/// ISO 9283 distance accuracy AD between two commanded positions from the positions
/// attained in the same cycles (pairs `a[j]`, `b[j]`): mean attained distance minus the
/// commanded distance (signed).
pub fn distance_accuracy(commanded: (&[f64], &[f64]), attained: (&[Vec<f64>], &[Vec<f64>])) -> f64 {
    let d: Vec<f64> = attained
        .0
        .iter()
        .zip(attained.1)
        .map(|(p, q)| dist(p, q))
        .collect();
    mean(&d) - dist(commanded.0, commanded.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ap_rp_and_ad_of_points_placed_by_hand() {
        // Four attained points on a square of half-side 1 around (3, 4, 12): every point is
        // sqrt(2) from the barycentre, no spread; AP = |(3, 4, 12)| = 13.
        let c = [0.0, 0.0, 0.0];
        let att: Vec<Vec<f64>> = [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
            .iter()
            .map(|(x, y)| vec![3.0 + x, 4.0 + y, 12.0])
            .collect();
        let a = position_accuracy(&c, &att);
        assert!((a.ap - 13.0).abs() < 1e-12, "{a:?}");
        assert!((a.rp - 2f64.sqrt()).abs() < 1e-12);
        // Spread: distances 1 and 3 from the barycentre 0 on a line: mean 2, std sqrt(2).
        let b = position_accuracy(&[0.0], &[vec![1.0], vec![-1.0], vec![3.0], vec![-3.0]]);
        let l = [1.0f64, 1.0, 3.0, 3.0];
        let sd = (l.iter().map(|v| (v - 2.0).powi(2)).sum::<f64>() / 3.0).sqrt();
        assert!((b.rp - (2.0 + 3.0 * sd)).abs() < 1e-12 && b.ap.abs() < 1e-12);
        // Commanded 10 apart; attained 10.5 and 9.9 apart: AD = 0.2.
        let ad = distance_accuracy(
            (&[0.0, 0.0], &[10.0, 0.0]),
            (
                &[vec![0.0, 0.0], vec![0.1, 0.0]],
                &[vec![10.5, 0.0], vec![10.0, 0.0]],
            ),
        );
        assert!((ad - 0.2).abs() < 1e-12, "{ad}");
    }
}
