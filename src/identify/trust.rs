//! Whether an identification can be trusted: physical scales of the unknowns, effect sizes,
//! the spectrum of the physically scaled Jacobian (condition number, near-dependent
//! parameter combinations) and the degeneracy checks that keep a wandering fit from being
//! reported as converged.
//!
//! Scaling each column to unit norm makes a column of rounding noise look as independent as
//! any other; scaling by the parameter's physical scale (how much it plausibly moves) keeps
//! its true size: `J * diag(scale)` holds, per residual, the change caused by a typical move
//! of each unknown, in measurement units, comparable with the measurement noise.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::Unknown;

/// Physical scale of each unknown: its plausible range (a typical magnitude of its error,
/// e.g. 1 mm for a length, 0.5 deg for an angle), or 1 where none is given.
pub fn physical_scales(unknowns: &[Unknown]) -> Vec<f64> {
    unknowns
        .iter()
        .map(|u| {
            if u.plausible_range.is_finite() && u.plausible_range > 0.0 {
                u.plausible_range
            } else {
                1.0
            }
        })
        .collect()
}

/// Effect size of each column: the largest absolute change of any residual caused by a
/// move of the unknown by its scale (`max_i |J_ik| * scale_k`, residual units).
pub fn effect_sizes(j: &DMatrix<f64>, scale: &[f64]) -> Vec<f64> {
    let n = j.nrows();
    (0..j.ncols())
        .map(|k| amax(&j.as_slice()[k * n..(k + 1) * n]) * scale.get(k).copied().unwrap_or(1.0))
        .collect()
}

/// nalgebra's `amax` (a fold of `if m >= |x| { m } else { |x| }` from the first |x|; 0 when
/// empty), bit for bit: without NaN it is the largest of non-negative values, the same in
/// any order, so eight running maxima (independent chains, vectorised) replace the one
/// fold; with a NaN (which resets that fold) nalgebra's own fold answers.
fn amax(v: &[f64]) -> f64 {
    let mut acc = [0.0_f64; 8];
    let mut nan = false;
    let mut chunks = v.chunks_exact(8);
    let mut take = |a: &mut f64, x: &f64| {
        let x = x.abs();
        nan |= x.is_nan();
        *a = if *a >= x { *a } else { x };
    };
    for c in &mut chunks {
        acc.iter_mut().zip(c).for_each(|(a, x)| take(a, x));
    }
    acc.iter_mut()
        .zip(chunks.remainder())
        .for_each(|(a, x)| take(a, x));
    if nan {
        return nalgebra::DVectorView::from_slice(v, v.len()).amax();
    }
    acc.iter().fold(0.0, |m, &a| if m >= a { m } else { a })
}

/// Whether an unknown is an angle (unit `deg` or `rad`), for the half-turn check.
pub fn is_angle(u: &Unknown) -> bool {
    matches!(u.unit.as_str(), "deg" | "rad")
}

/// One direction of the physically scaled Jacobian of the identified set with a small
/// singular value: a combination of parameters the data barely determine.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NearDependent {
    /// Singular value: residual 2-norm change for a unit move along the direction in scaled
    /// unknowns (residual units per scale unit).
    pub singular_value: f64,
    /// Largest single-residual change for that move (residual units).
    pub effect_size: f64,
    /// The largest components of the unit direction in scaled unknowns: (name, coefficient).
    pub combination: Vec<(String, f64)>,
    /// The unknown held at nominal because this combination is below the noise floor (its
    /// dominant component), if any.
    pub held: Option<String>,
}

/// Spectrum of `j * diag(scale)` restricted to the columns `free`.
#[derive(Debug, Clone)]
pub struct Spectrum {
    /// Singular values, largest first.
    pub singular_values: Vec<f64>,
    /// s_max / s_min (infinite if s_min is zero, 1 for an empty set).
    pub condition_number: f64,
    /// Unit right singular vectors (in `free` order, scaled unknowns), smallest singular
    /// value first, with their singular values.
    pub smallest: Vec<(f64, Vec<f64>)>,
}

/// The spectrum of the physically scaled Jacobian of the columns `free` of `j`.
pub fn spectrum(j: &DMatrix<f64>, free: &[usize], scale: &[f64]) -> Spectrum {
    spectrum_of_r(&super::reduced::tall_r(j), free, scale)
}

/// [`spectrum`] from the R factor of the Jacobian (or any matrix with the same `R^T R`,
/// the Jacobian itself included):
/// `J = Q R`, so `J[:, free] diag(scale)` and `R[:, free] diag(scale)` have the same
/// singular values and right vectors, and the tall Jacobian is reduced only once.
pub fn spectrum_of_r(r: &DMatrix<f64>, free: &[usize], scale: &[f64]) -> Spectrum {
    let m = free.len();
    if m == 0 {
        return Spectrum {
            singular_values: vec![],
            condition_number: 1.0,
            smallest: vec![],
        };
    }
    let mut js = DMatrix::zeros(r.nrows(), m);
    for (p, &k) in free.iter().enumerate() {
        js.set_column(p, &(r.column(k) * scale.get(k).copied().unwrap_or(1.0)));
    }
    // Same singular values and right vectors from R of a QR of a taller matrix.
    // nalgebra here: a tall input is below the crossover (its arithmetic as before).
    let r = if js.nrows() > m {
        super::dense::r_factor_with(&js, super::dense::Backend::Nalgebra)
    } else {
        js
    };
    let Some((s, vt)) = super::dense::svd_right(&r) else {
        return Spectrum {
            singular_values: vec![],
            condition_number: f64::INFINITY,
            smallest: vec![],
        };
    };
    let mut order: Vec<usize> = (0..s.len()).collect();
    order.sort_by(|a, b| s[*b].total_cmp(&s[*a]));
    let sorted: Vec<f64> = order.iter().map(|&i| s[i]).collect();
    let smax = sorted.first().copied().unwrap_or(0.0);
    let smin = if s.len() < m {
        0.0
    } else {
        sorted.last().copied().unwrap_or(0.0)
    };
    let smallest = order
        .iter()
        .rev()
        .map(|&i| (s[i], (0..m).map(|k| vt[(i, k)]).collect()))
        .collect();
    Spectrum {
        singular_values: sorted,
        condition_number: if smin > 0.0 {
            smax / smin
        } else {
            f64::INFINITY
        },
        smallest,
    }
}

/// Why a result is degenerate, and which unknowns are to blame.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Degeneracy {
    /// Human-readable reasons.
    pub reasons: Vec<String>,
    /// Offending unknowns.
    pub names: Vec<String>,
}

/// Inputs of [`degeneracy`].
#[derive(Debug, Clone, Copy)]
pub struct DegeneracyCheck<'a> {
    /// Descriptions of all unknowns.
    pub unknowns: &'a [Unknown],
    /// Physical scale of each unknown.
    pub scale: &'a [f64],
    /// Start values.
    pub x0: &'a [f64],
    /// Final values.
    pub x: &'a [f64],
    /// A move beyond `factor * scale` is implausible.
    pub factor: f64,
    /// Final data cost.
    pub cost: f64,
    /// Cost of the fit of the nuisance unknowns only (frames, unknown points), if computed.
    pub nuisance_cost: Option<f64>,
}

/// Whole turns an angle may run through before it counts as a runaway (its value modulo a
/// turn is compared with the scale rule; a few turns are a mount's rotation absorbed).
const RUNAWAY_TURNS: f64 = 1000.0;

/// The degeneracy checks: a non-finite value, a move beyond `factor` scales (angles modulo
/// a turn), an angle that ran through more than [`RUNAWAY_TURNS`] turns, or a final cost
/// above the nuisance-only fit's. `None` if sane.
pub fn degeneracy(c: &DegeneracyCheck<'_>) -> Option<Degeneracy> {
    let mut reasons = Vec::new();
    let mut names: Vec<String> = Vec::new();
    let mut blame = |name: &str| {
        if !names.iter().any(|n| n == name) {
            names.push(name.to_string());
        }
    };
    // An angle that moved by whole turns has not moved: compare it modulo 2 pi (a joint
    // offset may absorb a mount's rotation and land a few turns away, e.g. MUKCa's joint 7).
    let delta_of = |k: usize| {
        let d = c.x[k] - c.x0[k];
        if is_angle(&c.unknowns[k]) && d.is_finite() {
            let tau = std::f64::consts::TAU;
            d - tau * (d / tau).round()
        } else {
            d
        }
    };
    let moves: Vec<f64> = (0..c.unknowns.len())
        .map(|k| delta_of(k) / c.scale[k])
        .collect();
    for (k, u) in c.unknowns.iter().enumerate() {
        let delta = delta_of(k);
        if !c.x[k].is_finite() {
            reasons.push(format!("{} is not finite", u.name));
            blame(&u.name);
        } else if moves[k].abs() > c.factor {
            reasons.push(format!(
                "{} moved by {:.3e} {} ({:.3e} times its scale)",
                u.name,
                delta * u.to_report,
                u.unit,
                moves[k].abs()
            ));
            blame(&u.name);
        } else if is_angle(u) && (c.x[k] - c.x0[k]).abs() > RUNAWAY_TURNS * std::f64::consts::TAU {
            reasons.push(format!(
                "{} ran through {:.3e} turns: the data keep it only modulo a turn, if at all",
                u.name,
                (c.x[k] - c.x0[k]).abs() / std::f64::consts::TAU
            ));
            blame(&u.name);
        }
    }
    if let Some(nc) = c.nuisance_cost {
        // Rounding allowance: the full fit contains the nuisance fit, so it can only be
        // worse if it wandered off.
        if c.cost.is_nan() || c.cost > nc * (1.0 + 1e-9) + f64::MIN_POSITIVE {
            reasons.push(format!(
                "final cost {:.6e} is above the cost {:.6e} of the fit of frames and unknown \
                 points only",
                c.cost, nc
            ));
            // The three largest moves in scaled units carry the blame.
            let mut order: Vec<usize> = (0..moves.len()).collect();
            order.sort_by(|a, b| moves[*b].abs().total_cmp(&moves[*a].abs()));
            for &k in order.iter().take(3) {
                blame(&c.unknowns[k].name);
            }
        }
    }
    (!reasons.is_empty()).then_some(Degeneracy { reasons, names })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unknown(name: &str, unit: &str, scale: f64) -> Unknown {
        Unknown {
            name: name.into(),
            unit: unit.into(),
            to_report: 1.0,
            nominal: 0.0,
            plausible_range: scale,
            lower: None,
            upper: None,
        }
    }

    #[test]
    fn flags_implausible_moves_runaway_angles_and_a_cost_above_the_nuisance_fit() {
        let u = [
            unknown("len", "mm", 1.0),
            unknown("ang", "rad", 10.0),
            unknown("ok", "mm", 1.0),
        ];
        let scale = physical_scales(&u);
        let base = DegeneracyCheck {
            unknowns: &u,
            scale: &scale,
            x0: &[0.0, 0.0, 0.0],
            x: &[0.5, 0.1, 0.2],
            factor: 1000.0,
            cost: 1.0,
            nuisance_cost: Some(2.0),
        };
        assert!(degeneracy(&base).is_none());
        // 1001 mm on a 1 mm scale; 2,000 turns of an angle.
        let runaway = 2000.0 * std::f64::consts::TAU + 0.1;
        let d = degeneracy(&DegeneracyCheck {
            x: &[1001.0, runaway, 0.2],
            ..base
        })
        .expect("degenerate");
        assert_eq!(d.names, vec!["len".to_string(), "ang".to_string()]);
        // Two whole turns and 0.64 rad (a mount's rotation absorbed by a joint offset, as
        // on MUKCa's joint 7) is a move of 0.64 rad, not a degenerate fit.
        let turns = -2.0 * std::f64::consts::TAU + 0.64;
        assert!(
            degeneracy(&DegeneracyCheck {
                x: &[0.5, turns, 0.2],
                ..base
            })
            .is_none()
        );
        // Modulo a turn, a move beyond 1000 scales still counts: 0.64 rad on a 1e-4 rad scale.
        let tight = [
            unknown("len", "mm", 1.0),
            unknown("ang", "rad", 1e-4),
            unknown("ok", "mm", 1.0),
        ];
        let tight_scale = physical_scales(&tight);
        let d = degeneracy(&DegeneracyCheck {
            unknowns: &tight,
            scale: &tight_scale,
            x: &[0.5, turns, 0.2],
            ..base
        })
        .expect("degenerate");
        assert_eq!(d.names, vec!["ang".to_string()]);
        let d = degeneracy(&DegeneracyCheck { cost: 2.1, ..base }).expect("degenerate");
        assert_eq!(d.reasons.len(), 1);
        assert_eq!(d.names[0], "len");
    }

    #[test]
    fn spectrum_of_a_scaled_pair_finds_the_weak_combination() {
        // Columns (1, 1, 0) and (1, 1, 1e-6): scaled by 1 and 2, the weak direction is
        // close to (1, -2) / sqrt(5) in scaled unknowns.
        let j = DMatrix::from_row_slice(3, 2, &[1.0, 1.0, 1.0, 1.0, 0.0, 1e-6]);
        let s = spectrum(&j, &[0, 1], &[1.0, 0.5]);
        let (smin, v) = &s.smallest[0];
        assert!(*smin < 1e-6, "{smin}");
        let ratio = v[0] / v[1];
        assert!((ratio + 0.5).abs() < 1e-6, "{v:?}");
        assert!(s.condition_number > 1e5);
    }

    /// Every length to 40, mixed signs and scales, NaN here and there, all NaN: nalgebra's
    /// value bit for bit.
    #[test]
    fn amax_equals_nalgebra() {
        for n in 0..=40 {
            let mut v: Vec<f64> = (0..n)
                .map(|i| ((i * 7919 % 101) as f64 - 50.0) * 10f64.powi((i % 7) as i32 - 3))
                .collect();
            let want = nalgebra::DVector::from_vec(v.clone()).amax();
            assert_eq!(amax(&v).to_bits(), want.to_bits(), "{n}");
            if n > 2 {
                v[n / 2] = f64::NAN;
                v[0] = -0.0;
                let want = nalgebra::DVector::from_vec(v.clone()).amax();
                assert_eq!(amax(&v).to_bits(), want.to_bits(), "{n} with NaN");
                let nan = vec![f64::NAN; n];
                assert!(amax(&nan).is_nan() && nalgebra::DVector::from_vec(nan).amax().is_nan());
            }
        }
    }
}
