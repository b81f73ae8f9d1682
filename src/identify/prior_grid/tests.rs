use nalgebra::{DMatrix, DVector};

use super::*;
use crate::identify::prior::{Prior, solve_map};
use crate::identify::{Problem, SolveOptions, Unknown};
use crate::util::NoMonitor;

/// r = J x - b.
struct Linear {
    j: DMatrix<f64>,
    b: DVector<f64>,
}

impl Problem for Linear {
    fn residual_count(&self) -> usize {
        self.j.nrows()
    }
    fn unknown_count(&self) -> usize {
        self.j.ncols()
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let v = &self.j * DVector::from_column_slice(x) - &self.b;
        r.copy_from_slice(v.as_slice());
        Ok(())
    }
    fn jacobian(&self, _x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        j.copy_from(&self.j);
        Ok(())
    }
}

/// Seeded standard normal numbers (Box-Muller over SplitMix64).
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// Ridge data: `per` coefficients with prior std `tau_a` (group a), `per` with `tau_b`
/// (group b), columns scaled so that data and prior weigh about the same in each group.
struct Ridge {
    x: DMatrix<f64>,
    y: DVector<f64>,
    per: usize,
    noise: f64,
}

fn ridge(n: usize, per: usize, tau: [f64; 2], noise: f64, seed: u64) -> Ridge {
    let mut g = Normal(seed);
    // Column scale c: n c^2 / noise^2 ~ 1 / tau^2.
    let scale = tau.map(|t| noise / (t * (n as f64).sqrt()));
    let x = DMatrix::from_fn(n, 2 * per, |_, c| g.next() * scale[c / per]);
    let beta = DVector::from_fn(2 * per, |c, _| g.next() * tau[c / per]);
    let y = &x * beta + DVector::from_fn(n, |_, _| g.next() * noise);
    Ridge { x, y, per, noise }
}

fn rows(m: &DMatrix<f64>, idx: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(idx.len(), m.ncols(), |r, c| m[(idx[r], c)])
}

fn unknowns(m: usize) -> Vec<Unknown> {
    (0..m)
        .map(|k| Unknown {
            name: format!("x{k}"),
            unit: "mm".into(),
            to_report: 1.0,
            nominal: 0.0,
            plausible_range: 1.0,
            lower: None,
            upper: None,
        })
        .collect()
}

/// The score through the MAP pipeline: fit on `train` with stds `(a, b)`, residuals of
/// `test`.
fn map_score(
    d: &Ridge,
    a: f64,
    b: f64,
    train: &[usize],
    test: &[usize],
) -> Result<(f64, usize), IdentifyError> {
    let m = d.x.ncols();
    let p = Linear {
        j: rows(&d.x, train),
        b: DVector::from_fn(train.len(), |r, _| d.y[train[r]]),
    };
    let prior = Prior {
        sigma: (0..m)
            .map(|c| Some(if c < d.per { a } else { b }))
            .collect(),
        mean: vec![0.0; m],
        noise: d.noise,
        weight: 1.0,
    };
    let (sol, _) = solve_map(
        &p,
        &unknowns(m),
        &vec![0.0; m],
        &prior,
        &SolveOptions::default(),
        &NoMonitor,
    )?;
    let r = rows(&d.x, test) * DVector::from_column_slice(&sol.x)
        - DVector::from_fn(test.len(), |r, _| d.y[test[r]]);
    Ok((r.norm_squared(), test.len()))
}

/// The same K-fold RMS in closed form: ridge `(X^T X / s^2 + D)^-1 X^T y / s^2`.
fn closed_form_rms(d: &Ridge, a: f64, b: f64, parts: &[Vec<usize>]) -> f64 {
    let (mut sum, mut cnt) = (0.0, 0);
    for (f, test) in parts.iter().enumerate() {
        let train: Vec<usize> = parts
            .iter()
            .enumerate()
            .filter(|(g, _)| *g != f)
            .flat_map(|(_, p)| p.iter().copied())
            .collect();
        let xt = rows(&d.x, &train);
        let yt = DVector::from_fn(train.len(), |r, _| d.y[train[r]]);
        let s2 = d.noise * d.noise;
        let mut h = xt.tr_mul(&xt) / s2;
        for c in 0..h.ncols() {
            let sd = if c < d.per { a } else { b };
            h[(c, c)] += 1.0 / (sd * sd);
        }
        let beta = h
            .cholesky()
            .expect("positive definite")
            .solve(&(xt.tr_mul(&yt) / s2));
        let r = rows(&d.x, test) * beta - DVector::from_fn(test.len(), |r, _| d.y[test[r]]);
        sum += r.norm_squared();
        cnt += test.len();
    }
    (sum / cnt as f64).sqrt()
}

fn axis(start: i32, end: i32, min: i32, max: i32) -> LogAxis {
    LogAxis {
        base: 1.0,
        ratio: 2.0,
        start,
        end,
        min,
        max,
    }
}

/// Ridge regression with two groups of coefficients whose prior stds are known (0.05 and
/// 2): started far below both, the grid extends until its optimum is interior; every cell
/// equals the closed-form K-fold RMS, the choice is their argmin, and the chosen stds are
/// within a factor 2.5 of the true ones (the Bayes-optimal ridge is the true prior).
#[test]
fn the_grid_extends_to_an_interior_optimum_near_the_true_prior() {
    let d = ridge(400, 30, [0.05, 2.0], 0.3, 11);
    let group: Vec<usize> = (0..d.y.len()).collect();
    let axes = [axis(-12, -10, -20, 20), axis(-3, -1, -20, 20)];
    let c = choose_grid(&axes, &group, 5, 3, |a, b, tr, te| {
        map_score(&d, a, b, tr, te)
    })
    .expect("chooses");
    assert!(!c.at_edge, "{c:?}");
    assert!(c.extensions >= 6, "extensions {}", c.extensions);
    let parts = grouped_folds(&group, 5, 3);
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for cell in &c.cells {
        let cf = closed_form_rms(&d, cell.a, cell.b, &parts);
        assert!(
            (cell.rms - cf).abs() < 1e-8 * cf,
            "cell ({}, {}): {} vs closed form {cf}",
            cell.a,
            cell.b,
            cell.rms
        );
        if cf < best.0 {
            best = (cf, cell.a, cell.b);
        }
    }
    assert_eq!((c.a, c.b), (best.1, best.2));
    // Interior on both axes: smaller and larger values were tried.
    for (v, f) in [(c.a, 0usize), (c.b, 1)] {
        let on = |cell: &GridCell| if f == 0 { cell.a } else { cell.b };
        assert!(c.cells.iter().any(|x| on(x) < v) && c.cells.iter().any(|x| on(x) > v));
    }
    let (lo, hi) = c.range();
    assert!(lo == c.rms && hi > lo);
    for (got, truth) in [(c.a, 0.05), (c.b, 2.0)] {
        assert!(
            (got / truth).log2().abs() < 2.5f64.log2(),
            "chosen {got} vs true {truth}"
        );
    }
}

/// When the limits stop the growth, the edge optimum is flagged.
#[test]
fn an_optimum_beyond_the_limits_is_flagged_at_the_edge() {
    let d = ridge(200, 10, [0.05, 2.0], 0.3, 5);
    let group: Vec<usize> = (0..d.y.len()).collect();
    let axes = [axis(-12, -10, -12, -10), axis(-2, 2, -20, 20)];
    let c = choose_grid(&axes, &group, 5, 3, |a, b, tr, te| {
        map_score(&d, a, b, tr, te)
    })
    .expect("chooses");
    assert!(c.at_edge);
    assert_eq!(c.a, 2f64.powi(-10));
    // A bad axis is refused, naming the axis.
    let bad = [axis(0, 1, 0, 1), axis(0, 2, 0, 2)];
    let e = choose_grid(&bad, &group, 5, 3, |_, _, _, _| Ok((0.0, 1))).unwrap_err();
    assert!(e.to_string().contains("grid axis"), "{e}");
}
