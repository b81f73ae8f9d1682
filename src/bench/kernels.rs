//! `calibd bench kernels`: nalgebra against faer on the shapes identification uses (tall
//! Jacobians of 31 and 63 unknowns from 90 to 300,000 rows; square factors from 8 to 255
//! columns), and the crossover from which faer is faster, printed per kernel. The
//! constants of `identify::dense` hold the crossovers measured on the 2-core development
//! machine.

use std::time::{Duration, Instant};

use nalgebra::DMatrix;

use super::Figure;
use crate::identify::Pivoting;
use crate::identify::dense::{self, Backend};
use crate::identify::rank::rank_revealing_loop;
use crate::util::Rng;

/// A random `rows` x `cols` matrix with column scales spread over six decades (as a
/// Jacobian with lengths and angles).
pub fn random_matrix(rows: usize, cols: usize, seed: u64) -> DMatrix<f64> {
    let mut rng = Rng::new(seed);
    let scales: Vec<f64> = (0..cols)
        .map(|c| 10f64.powf(-3.0 + 6.0 * c as f64 / cols.max(1) as f64))
        .collect();
    DMatrix::from_fn(rows, cols, |_, c| rng.normal() * scales[c])
}

/// Time of one call of `f`: calls repeated for at least 30 ms (at least twice), best of
/// three such rounds.
fn per_call<F: FnMut()>(mut f: F) -> Duration {
    f();
    (0..3)
        .map(|_| {
            let t = Instant::now();
            let mut calls = 0u32;
            while calls < 2 || t.elapsed() < Duration::from_millis(30) {
                f();
                calls += 1;
            }
            t.elapsed() / calls
        })
        .min()
        .unwrap_or_default()
}

fn figure(name: String, d: Duration) -> Figure {
    Figure {
        name,
        per_op: d,
        min: d,
        max: d,
        runs: 3,
        ops: 1,
        target: None,
        peak_rss_bytes: None,
        cpu: None,
        cpu_target: None,
    }
}

/// One kernel measured at each size with both implementations: figures, and the smallest
/// size from which faer is faster at that size and every larger one (`None`: never).
fn compare(
    kernel: &str,
    sizes: &[usize],
    shape: impl Fn(usize) -> (usize, usize),
    run: impl Fn(&DMatrix<f64>, Backend),
    figs: &mut Vec<Figure>,
) -> Option<usize> {
    let mut faster = Vec::new();
    for &s in sizes {
        let (r, c) = shape(s);
        let a = random_matrix(r, c, 7 + s as u64);
        let tn = per_call(|| run(&a, Backend::Nalgebra));
        let tf = per_call(|| run(&a, Backend::Faer));
        println!(
            "{kernel:<14} {r:>7} x {c:<4} nalgebra {:>12}  faer {:>12}  faer/nalgebra {:.2}",
            super::fmt(tn),
            super::fmt(tf),
            tf.as_secs_f64() / tn.as_secs_f64().max(1e-12)
        );
        figs.push(figure(format!("{kernel} {r} x {c}, nalgebra"), tn));
        figs.push(figure(format!("{kernel} {r} x {c}, faer"), tf));
        faster.push((s, tf < tn));
    }
    let from = faster.iter().rposition(|(_, f)| !f).map_or(0, |p| p + 1);
    faster.get(from).map(|(s, _)| *s)
}

/// Pivoted QR through our own loop (nalgebra storage, stops at a tolerance) or faer's.
fn pivoted(a: &DMatrix<f64>, b: Backend) {
    if b == Backend::Faer {
        std::hint::black_box(dense::pivoted_qr_faer(a));
    } else {
        std::hint::black_box(rank_revealing_loop(a, &Pivoting::Norm, 0.0));
    }
}

/// Run the kernel comparison and print the crossovers.
pub fn run() -> Vec<Figure> {
    let mut figs = Vec::new();
    let rows = [90, 270, 540, 1_080, 4_320, 30_000, 300_000];
    let mut lines = Vec::new();
    for cols in [31, 63] {
        let c = compare(
            "tall R factor",
            &rows,
            |n| (n, cols),
            |a, b| {
                std::hint::black_box(dense::r_factor_with(a, b));
            },
            &mut figs,
        );
        lines.push(format!(
            "tall R factor ({cols} columns): faer from {c:?} rows (constant: {})",
            dense::QR_FAER_MIN_ROWS
        ));
        let c = compare(
            "J^T J",
            &rows,
            |n| (n, cols),
            |a, b| {
                std::hint::black_box(dense::gram_with(a, b));
            },
            &mut figs,
        );
        lines.push(format!(
            "J^T J ({cols} columns): faer from {c:?} rows (constant: {}, see its note)",
            dense::GRAM_FAER_MIN_ROWS
        ));
    }
    let square = [8, 16, 31, 63, 127, 255];
    let c = compare(
        "SVD (s, V)",
        &square,
        |m| (m, m),
        |a, b| {
            std::hint::black_box(dense::svd_right_with(a, b));
        },
        &mut figs,
    );
    lines.push(format!(
        "SVD of a square factor: faer from {c:?} columns (constant: {})",
        dense::SVD_FAER_MIN_COLS
    ));
    let c = compare("pivoted QR", &square, |m| (m, m), pivoted, &mut figs);
    lines.push(format!(
        "pivoted QR of a square factor: faer from {c:?} columns (constant: {})",
        dense::PIVOTED_QR_FAER_MIN_COLS
    ));
    for l in lines {
        println!("crossover: {l}");
    }
    figs
}
