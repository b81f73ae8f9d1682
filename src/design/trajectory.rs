//! Commanded planar trajectories for accuracy tests (ISO 9283 style): a square of a given
//! side and a circle of a given diameter, centred on the origin of {W} with theta = 0.

use crate::geometry::Pose2;

/// The poses of a square of side `side` centred on `centre`: the corners and
/// `points_per_side - 2` evenly spaced points on each edge, counter-clockwise from the
/// lower-left corner (`4 (points_per_side - 1)` poses; at least the 4 corners).
pub fn square(centre: &Pose2, side: f64, points_per_side: usize) -> Vec<Pose2> {
    let n = points_per_side.max(2) - 1;
    let h = 0.5 * side;
    let corners = [(-h, -h), (h, -h), (h, h), (-h, h)];
    let mut out = Vec::with_capacity(4 * n);
    for e in 0..4 {
        let (a, b) = (corners[e], corners[(e + 1) % 4]);
        for k in 0..n {
            let t = k as f64 / n as f64;
            out.push(Pose2::new(
                centre.x + a.0 + t * (b.0 - a.0),
                centre.y + a.1 + t * (b.1 - a.1),
                centre.theta,
            ));
        }
    }
    out
}

/// `points` poses evenly spaced on a circle of diameter `diameter` centred on `centre`,
/// counter-clockwise from the +x axis.
pub fn circle(centre: &Pose2, diameter: f64, points: usize) -> Vec<Pose2> {
    let r = 0.5 * diameter;
    (0..points)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / points as f64;
            Pose2::new(centre.x + r * a.cos(), centre.y + r * a.sin(), centre.theta)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_and_circle_have_the_stated_size() {
        let c = Pose2::new(0.001, -0.002, 0.0);
        let sq = square(&c, 0.002, 5);
        assert_eq!(sq.len(), 16);
        let perimeter: f64 = (0..sq.len())
            .map(|k| {
                let (a, b) = (sq[k], sq[(k + 1) % sq.len()]);
                (a.x - b.x).hypot(a.y - b.y)
            })
            .sum();
        assert!((perimeter - 0.008).abs() < 1e-15);
        assert!(
            sq.iter()
                .all(|p| (p.x - c.x).abs() <= 0.001 + 1e-15 && (p.y - c.y).abs() <= 0.001 + 1e-15)
        );
        let ci = circle(&c, 0.003, 12);
        assert_eq!(ci.len(), 12);
        assert!(
            ci.iter()
                .all(|p| ((p.x - c.x).hypot(p.y - c.y) - 0.0015).abs() < 1e-15)
        );
        assert!(
            (ci[3].y - c.y - 0.0015).abs() < 1e-15,
            "a quarter turn is +y"
        );
    }
}
