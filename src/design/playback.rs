//! Playing calibration postures: an order that keeps joint-space travel short (nearest
//! neighbour from the start posture, then 2-opt on the open path) and quintic segments with
//! zero velocity and acceleration at both ends.

/// Euclidean joint-space distance.
fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Length of the path `start -> postures[order[0]] -> ...` (rad).
pub fn travel(postures: &[Vec<f64>], order: &[usize], start: Option<&[f64]>) -> f64 {
    let mut total = 0.0;
    let mut prev: Option<&[f64]> = start;
    for &i in order {
        if let Some(p) = prev {
            total += dist(p, &postures[i]);
        }
        prev = Some(&postures[i]);
    }
    total
}

/// An order of `postures` with short joint-space travel from `start` (or from the first
/// posture): nearest neighbour, then 2-opt moves until none shortens the path.
pub fn order_postures(postures: &[Vec<f64>], start: Option<&[f64]>) -> Vec<usize> {
    let n = postures.len();
    if n == 0 {
        return Vec::new();
    }
    let mut left: Vec<usize> = (0..n).collect();
    let mut order = Vec::with_capacity(n);
    let mut here: Vec<f64> = match start {
        Some(s) => s.to_vec(),
        None => {
            order.push(left.remove(0));
            postures[order[0]].clone()
        }
    };
    while !left.is_empty() {
        let (k, _) = left
            .iter()
            .enumerate()
            .map(|(k, &i)| (k, dist(&here, &postures[i])))
            .fold((0, f64::INFINITY), |a, v| if v.1 < a.1 { v } else { a });
        let i = left.remove(k);
        here = postures[i].clone();
        order.push(i);
    }
    // 2-opt on the open path (reversing order[i..=j]).
    let fixed_start = start.is_none();
    let mut improved = true;
    let mut guard = 0;
    while improved && guard < 100 {
        improved = false;
        guard += 1;
        let first = usize::from(fixed_start);
        for i in first..n {
            for j in i + 1..n {
                let before = |k: usize| -> Option<&[f64]> {
                    if k == 0 {
                        start
                    } else {
                        Some(&postures[order[k - 1]])
                    }
                };
                let a = before(i);
                let (b, c) = (&postures[order[i]], &postures[order[j]]);
                let d = order.get(j + 1).map(|&k| &postures[k]);
                let old = a.map_or(0.0, |a| dist(a, b)) + d.map_or(0.0, |d| dist(c, d));
                let new = a.map_or(0.0, |a| dist(a, c)) + d.map_or(0.0, |d| dist(b, d));
                if new < old - 1e-12 {
                    order[i..=j].reverse();
                    improved = true;
                }
            }
        }
    }
    order
}

/// Position, velocity and acceleration of the quintic from `q0` to `q1` in `duration` s at
/// time `t` (clamped to the segment): `s = 10 u^3 - 15 u^4 + 6 u^5`, `u = t / duration`.
pub fn quintic(q0: &[f64], q1: &[f64], duration: f64, t: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let u = (t / duration).clamp(0.0, 1.0);
    let s = u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
    let ds = 30.0 * u * u * (1.0 - u) * (1.0 - u) / duration;
    let dds = 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / (duration * duration);
    let dq: Vec<f64> = q0.iter().zip(q1).map(|(a, b)| b - a).collect();
    (
        q0.iter().zip(&dq).map(|(a, d)| a + s * d).collect(),
        dq.iter().map(|d| ds * d).collect(),
        dq.iter().map(|d| dds * d).collect(),
    )
}

/// The trajectory through `postures` in order, one quintic segment of `duration` s between
/// consecutive postures, sampled every `dt` s: rows of (t, q).
pub fn sample_trajectory(postures: &[Vec<f64>], duration: f64, dt: f64) -> Vec<(f64, Vec<f64>)> {
    let mut out = Vec::new();
    let steps = (duration / dt).round().max(1.0) as usize;
    for (k, w) in postures.windows(2).enumerate() {
        let t0 = k as f64 * duration;
        for s in 0..steps {
            let t = s as f64 * duration / steps as f64;
            out.push((t0 + t, quintic(&w[0], &w[1], duration, t).0));
        }
    }
    if let Some(last) = postures.last() {
        out.push((
            postures.len().saturating_sub(1) as f64 * duration,
            last.clone(),
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;

    #[test]
    fn quintic_meets_its_boundary_conditions() {
        let (a, b) = (vec![0.2, -1.0], vec![1.2, 0.5]);
        let (p0, v0, a0) = quintic(&a, &b, 5.0, 0.0);
        let (p1, v1, a1) = quintic(&a, &b, 5.0, 5.0);
        let (pm, vm, _) = quintic(&a, &b, 5.0, 2.5);
        for k in 0..2 {
            assert!((p0[k] - a[k]).abs() < 1e-15 && (p1[k] - b[k]).abs() < 1e-15);
            assert!(v0[k].abs() < 1e-15 && v1[k].abs() < 1e-15);
            assert!(a0[k].abs() < 1e-15 && a1[k].abs() < 1e-15);
            // Symmetric profile: half way at mid time, peak speed 15/8 of the mean speed.
            assert!((pm[k] - 0.5 * (a[k] + b[k])).abs() < 1e-12);
            assert!((vm[k] - 1.875 * (b[k] - a[k]) / 5.0).abs() < 1e-12);
        }
        // Velocity is the derivative of position.
        let h = 1e-6;
        let (pa, _, _) = quintic(&a, &b, 5.0, 1.3 + h);
        let (pb, v, _) = quintic(&a, &b, 5.0, 1.3 - h);
        assert!(((pa[0] - pb[0]) / (2.0 * h) - quintic(&a, &b, 5.0, 1.3).1[0]).abs() < 1e-8);
        let _ = v;
        let tr = sample_trajectory(&[a.clone(), b.clone(), a.clone()], 5.0, 0.5);
        assert_eq!(tr.len(), 21);
        assert_eq!(tr.last().unwrap().0, 10.0);
    }

    #[test]
    fn ordering_finds_the_line_order_and_shortens_random_tours() {
        // Points on a line, shuffled: the shortest open path from 0 visits them in order.
        let mut rng = Rng::new(2);
        let mut xs: Vec<f64> = (1..=9).map(|k| k as f64).collect();
        rng.shuffle(&mut xs);
        let pts: Vec<Vec<f64>> = xs.iter().map(|x| vec![*x, 0.0]).collect();
        let order = order_postures(&pts, Some(&[0.0, 0.0]));
        let visited: Vec<f64> = order.iter().map(|&i| xs[i]).collect();
        assert_eq!(visited, (1..=9).map(|k| k as f64).collect::<Vec<_>>());
        let pts: Vec<Vec<f64>> = (0..30)
            .map(|_| (0..7).map(|_| rng.range(-2.0, 2.0)).collect())
            .collect();
        let id: Vec<usize> = (0..30).collect();
        let order = order_postures(&pts, None);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, id);
        assert!(travel(&pts, &order, None) < 0.7 * travel(&pts, &id, None));
    }
}
