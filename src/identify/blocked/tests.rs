//! The folded (blocked) path against the held (dense) one: the fold's sums against the
//! whole Jacobian, and whole identifications of the IRB 120 twin solved both ways.

use nalgebra::{DMatrix, DVector};

use super::{BLOCK_ROWS, Want, fold, fold_in_parts};
use crate::identify::{Blocking, Problem, Solution, SolveOptions, solve_with};
use crate::measure::PointProblem;
use crate::twin::SerialTwin;
use crate::util::NoMonitor;

/// The twin's centring problem over `per_ball` measurements per ball, identifying `names`
/// (None: the twin file's list).
fn problem(per_ball: usize, all_params: bool) -> PointProblem {
    let twin = SerialTwin::irb120(1);
    let ids = if all_params {
        twin.nominal.param_ids()
    } else {
        twin.file
            .identify
            .iter()
            .filter_map(|n| twin.nominal.param_by_name(n).ok())
            .collect()
    };
    let meas = twin.centring(per_ball, 2);
    PointProblem::new(twin.nominal.clone(), ids, twin.plate.clone(), meas)
        .expect("twin data are consistent")
}

fn close(a: f64, b: f64, scale: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * scale.max(f64::MIN_POSITIVE)
}

/// Every sum of the fold (blocks, the distance rows, one part or five shared by the
/// cores) equals the one of the whole Jacobian evaluated at once: `J^T J`, `J^T r`,
/// `R^T R`, column maxima, row effects.
#[test]
fn the_fold_equals_the_whole_jacobian() {
    for parts in [1, 5] {
        fold_equals_the_whole_jacobian(parts);
    }
}

fn fold_equals_the_whole_jacobian(parts: usize) {
    let p = problem(700, false);
    let x = p.initial();
    let (n, m) = (p.residual_count(), p.unknown_count());
    let mut j = DMatrix::zeros(n, m);
    p.jacobian(&x, &mut j).unwrap();
    let r = DVector::from_fn(n, |i, _| ((i * 7919) % 1000) as f64 / 1000.0 - 0.5);
    let w = DVector::from_fn(m, |k, _| if k % 2 == 0 { 1e-3 } else { -2e-3 });
    let moves = [w.clone()];
    let want = Want {
        gram: true,
        r_factor: true,
        amax: true,
        residuals: Some(r.as_slice()),
        moves: &moves,
    };
    let f = fold_in_parts(&p, &x, None, &want, parts)
        .unwrap()
        .expect("blocked form");
    assert_eq!(f.rows, n);
    assert!(n > 2 * parts * BLOCK_ROWS, "several blocks per part");
    let gram = j.tr_mul(&j);
    let rtr = f.r.tr_mul(&f.r);
    let jtr = j.tr_mul(&r);
    for p_ in 0..m {
        let s = gram[(p_, p_)].sqrt();
        assert!(
            close(f.amax[p_], j.column(p_).amax(), j.column(p_).amax(), 0.0),
            "column max {p_}"
        );
        assert!(close(f.jtr[p_], jtr[p_], s * r.norm(), 1e-13), "J^T r {p_}");
        for q in 0..m {
            let s = (gram[(p_, p_)] * gram[(q, q)]).sqrt();
            assert!(close(f.gram[(p_, q)], gram[(p_, q)], s, 1e-13), "J^T J");
            assert!(close(rtr[(p_, q)], gram[(p_, q)], s, 1e-12), "R^T R");
        }
    }
    let effect = (&j * &w).amax();
    assert!(close(f.effects[0], effect, effect, 1e-14));
    // Columns picked: the same sums of those columns.
    let cols = [3, 0, 7];
    let f = fold(
        &p,
        &x,
        Some(&cols),
        &Want {
            amax: true,
            ..Want::default()
        },
    )
    .unwrap()
    .expect("blocked form");
    for (c, &k) in cols.iter().enumerate() {
        assert_eq!(f.amax[c], j.column(k).amax());
    }
}

/// The identification folded in blocks gives the held one's result: the same values, cost,
/// standard deviations and condition to 1e-9 (relative to each value's size or its
/// standard deviation's), the same rank report, on a full-rank set and on every parameter
/// of the chain (rank deficient: base and link parameters duplicate each other).
#[test]
fn folded_identification_equals_the_dense_one() {
    for all_params in [false, true] {
        let p = problem(1_000, all_params);
        let x0 = p.initial();
        let unknowns = p.unknowns();
        let o = SolveOptions::default();
        let dense = solve_with(&p, &unknowns, &x0, &o, Blocking::Dense, &NoMonitor).unwrap();
        let folded = solve_with(&p, &unknowns, &x0, &o, Blocking::Folded, &NoMonitor).unwrap();
        let case = if all_params {
            "all parameters"
        } else {
            "twin set"
        };
        assert!(dense.converged() && folded.converged(), "{case}");
        assert_eq!(folded.unidentifiable, dense.unidentifiable, "{case}");
        assert_eq!(folded.free, dense.free, "{case}");
        let deps = |s: &Solution| -> Vec<(String, Vec<String>)> {
            s.dependencies
                .iter()
                .map(|d| {
                    let names = d.combination.iter().map(|(n, _)| n.clone()).collect();
                    (d.name.clone(), names)
                })
                .collect()
        };
        assert_eq!(deps(&folded), deps(&dense), "{case}");
        if all_params {
            assert!(
                !dense.dependencies.is_empty(),
                "the full set is rank deficient"
            );
        }
        let near = |s: &Solution| -> Vec<(Vec<String>, Option<String>)> {
            s.near_dependent
                .iter()
                .map(|d| {
                    let names = d.combination.iter().map(|(n, _)| n.clone()).collect();
                    (names, d.held.clone())
                })
                .collect()
        };
        assert_eq!(near(&folded), near(&dense), "{case}");
        for (a, b) in folded.near_dependent.iter().zip(&dense.near_dependent) {
            assert!(close(
                a.singular_value,
                b.singular_value,
                b.singular_value,
                1e-9
            ));
            assert!(close(a.effect_size, b.effect_size, b.effect_size, 1e-9));
        }
        assert!(
            close(folded.cost_after, dense.cost_after, dense.cost_after, 1e-9),
            "{case}: cost {} vs {}",
            folded.cost_after,
            dense.cost_after
        );
        for (a, b) in folded.params.iter().zip(&dense.params) {
            assert_eq!(a.name, b.name);
            assert_eq!(a.identifiable, b.identifiable);
            let size = b.value.abs().max(b.std.unwrap_or(0.0));
            assert!(
                close(a.value, b.value, size, 1e-9),
                "{case} {}: {} vs {} (std {:?})",
                a.name,
                a.value,
                b.value,
                b.std
            );
            match (a.std, b.std) {
                (Some(x), Some(y)) => assert!(close(x, y, y, 1e-9), "{case} {} std", a.name),
                (x, y) => assert_eq!(x.is_some(), y.is_some()),
            }
            assert!(close(a.effect_size, b.effect_size, b.effect_size, 1e-12));
        }
        assert!(close(
            folded.condition_number,
            dense.condition_number,
            dense.condition_number,
            1e-9
        ));
        assert!(close(
            folded.uncertainty.sigma,
            dense.uncertainty.sigma,
            dense.uncertainty.sigma,
            1e-9
        ));
        let rms = |s: &Solution| (s.cost_after / s.residuals.len() as f64).sqrt();
        assert!(
            close(rms(&folded), rms(&dense), rms(&dense), 1e-9),
            "{case}"
        );
        eprintln!(
            "{case}: dense {} iterations ({:?}), folded {} ({:?})",
            dense.iterations, dense.stop, folded.iterations, folded.stop
        );
    }
}
