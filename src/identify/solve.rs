//! The identification pipeline every method uses: rank detection at the starting point on
//! the physically scaled Jacobian, unknowns whose effect is below the noise held at their
//! start values, near-dependent combinations reported (and held when the data cannot see
//! them), Levenberg-Marquardt on the rest, standard deviations, effect sizes, degeneracy
//! checks (against the nuisance-only fit and implausible moves) and a per-parameter report.

use nalgebra::{DMatrix, DVector};

use super::blocked::{Folded, Want, fold};
use super::lm_blocked::{BlockedStart, levenberg_marquardt_blocked};
use super::reduced::{Rows, Src, expand_cols, tall_r};
use super::trust::{
    DegeneracyCheck, NearDependent, degeneracy, effect_sizes, physical_scales, spectrum_of_r,
};
use super::uncertainty::uncertainty_of_r;
use super::{
    IdentifyError, LmOptions, LmReport, LmStart, Problem, Restricted, Uncertainty,
    levenberg_marquardt_from, rank_revealing, rank_revealing_scaled,
};
use crate::util::{Monitor, SubMonitor};

pub use super::solution::{Dependency, ParamReport, Solution, SolveOptions, Unknown, Unobservable};

/// Which unknowns a fit frees and which it holds.
struct Plan {
    free: Vec<usize>,
    screened: Vec<usize>,
    floor: Option<f64>,
    near: Vec<NearDependent>,
}

/// Plan a fit: hold the structurally identifiable unknowns whose effect is below `floor`;
/// then, while the smallest singular value of the physically scaled Jacobian of the rest is
/// below it, hold the unknown that dominates that least-determined direction. Report the
/// held directions and the three smallest of the final set.
fn plan(
    structural: &[usize],
    effect: &[f64],
    rows: &Rows<'_>,
    scale: &[f64],
    unknowns: &[Unknown],
    floor: Option<f64>,
    report: bool,
) -> Result<Plan, IdentifyError> {
    let below = |v: f64| floor.is_some_and(|f| v < f);
    let (screened, mut free): (Vec<usize>, Vec<usize>) =
        structural.iter().partition(|&&k| below(effect[k]));
    let mut near = Vec::new();
    loop {
        if !report
            && (free.len() <= 1
                || floor.is_none_or(|f| super::lean::clearly_above(rows, &free, scale, f)))
        {
            break;
        }
        let sp = spectrum_of_r(&rows.r, &free, scale);
        let hold = sp
            .smallest
            .first()
            .is_some_and(|(s, _)| below(*s) && free.len() > 1);
        let listed = &sp.smallest[..sp.smallest.len().min(if hold { 1 } else { 3 })];
        let moves: Vec<&[f64]> = listed.iter().map(|(_, v)| &v[..]).collect();
        let effects = rows.effects(&free, &moves, scale)?;
        for ((s, v), &dir_effect) in listed.iter().zip(&effects) {
            let mut comps: Vec<(usize, f64)> = v.iter().copied().enumerate().collect();
            comps.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            near.push(NearDependent {
                singular_value: *s,
                effect_size: dir_effect,
                combination: comps
                    .iter()
                    .take(4)
                    .map(|&(p, c)| (unknowns[free[p]].name.clone(), c))
                    .collect(),
                held: hold.then(|| unknowns[free[comps[0].0]].name.clone()),
            });
        }
        if !hold {
            break;
        }
        let dominant = sp.smallest.first().and_then(|(_, v)| {
            v.iter()
                .enumerate()
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map(|(p, _)| p)
        });
        let Some(p) = dominant else {
            break;
        };
        free.remove(p);
    }
    Ok(Plan {
        free,
        screened,
        floor,
        near,
    })
}

/// One bounded LM run over `free` (others held at `x0`), with `gauges` held at their start.
struct Fit {
    rep: LmReport,
    x: Vec<f64>,
    unc: Uncertainty,
    /// R factor of the final Jacobian (columns of the fit's free unknowns).
    r: DMatrix<f64>,
    /// Largest absolute value per column of the final Jacobian, when the fit folded it in
    /// blocks (`rep.jacobian` is then empty).
    amax: Option<Vec<f64>>,
}

impl Fit {
    /// Largest absolute value per column of the final Jacobian.
    fn column_amax(&self) -> Vec<f64> {
        self.amax.clone().unwrap_or_else(|| {
            effect_sizes(&self.rep.jacobian, &vec![1.0; self.rep.jacobian.ncols()])
        })
    }
}

/// The Jacobian at the start point: held, or folded in blocks (a problem too tall to hold
/// it, see [`Blocking`]).
enum Start0 {
    Dense(DMatrix<f64>),
    Folded(Folded),
}

/// Whether [`solve_with`] holds the Jacobian or folds it block by block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blocking {
    /// Folded from [`super::blocked::BLOCKED_MIN_ELEMENTS`] elements on, when the problem
    /// evaluates its Jacobian in blocks.
    Auto,
    /// Always held.
    Dense,
    /// Folded whenever the problem evaluates its Jacobian in blocks.
    Folded,
}

/// The start of every fit of [`solve`]: `x0`, its residuals and full Jacobian (a fit over
/// some columns starts from those columns instead of evaluating them again), and whether
/// the fit's uncertainty is wanted.
#[derive(Clone, Copy)]
struct FitStart<'a> {
    x0: &'a [f64],
    r0: &'a DVector<f64>,
    j0: &'a Start0,
    uncertainty: bool,
    /// Fit through the problem's cheap held form ([`Problem::held`]) where it has one.
    cheap: bool,
}

fn run_fit(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    start: &FitStart<'_>,
    free: &[usize],
    lm: &LmOptions,
    monitor: &dyn Monitor,
) -> Result<Fit, IdentifyError> {
    let x0 = start.x0;
    let restricted = Restricted::new(problem, x0.to_vec(), free.to_vec());
    let pick = |f: &dyn Fn(&Unknown) -> Option<f64>, default: f64| -> Option<Vec<f64>> {
        free.iter().any(|&k| f(&unknowns[k]).is_some()).then(|| {
            free.iter()
                .map(|&k| f(&unknowns[k]).unwrap_or(default))
                .collect()
        })
    };
    let lm_opts = LmOptions {
        lower: pick(&|u: &Unknown| u.lower, f64::NEG_INFINITY),
        upper: pick(&|u: &Unknown| u.upper, f64::INFINITY),
        ..lm.clone()
    };
    let xs0: Vec<f64> = free.iter().map(|&k| x0[k]).collect();
    let cheap = start.cheap.then(|| problem.held(x0, free)).flatten();
    let target: &dyn Problem = cheap.as_deref().unwrap_or(&restricted);
    let folded = match start.j0 {
        Start0::Folded(f) => {
            let first = BlockedStart {
                residuals: start.r0.clone(),
                gram: DMatrix::from_fn(free.len(), free.len(), |p, q| f.gram[(free[p], free[q])]),
                jtr: DVector::from_fn(free.len(), |p, _| f.jtr[free[p]]),
            };
            levenberg_marquardt_blocked(target, &xs0, Some(first), &lm_opts, monitor)?
        }
        Start0::Dense(_) => None,
    };
    let (rep, r, amax) = match (folded, start.j0) {
        (Some(b), _) => (b.rep, b.r, Some(b.amax)),
        (None, Start0::Dense(j0)) => {
            let first = LmStart {
                residuals: start.r0.clone(),
                jacobian: DMatrix::from_fn(j0.nrows(), free.len(), |i, c| j0[(i, free[c])]),
            };
            let rep = levenberg_marquardt_from(target, &xs0, Some(first), &lm_opts, monitor)?;
            let r = tall_r(&rep.jacobian);
            (rep, r, None)
        }
        // A target without a blocked form (a cheap held form): it evaluates its own start.
        (None, Start0::Folded(_)) => {
            let rep = levenberg_marquardt_from(target, &xs0, None, &lm_opts, monitor)?;
            let r = tall_r(&rep.jacobian);
            (rep, r, None)
        }
    };
    let rows = rep.residuals.len();
    let unc = if start.uncertainty {
        uncertainty_of_r(&r, rows, &rep.residuals)
    } else {
        sigma_only(rows, free.len(), &rep.residuals)
    };
    let x = restricted.expand(&rep.x);
    Ok(Fit {
        rep,
        x,
        unc,
        r,
        amax,
    })
}

/// The uncertainty without its spectrum: the residual sigma only (std NaN).
fn sigma_only(n: usize, m: usize, r: &DVector<f64>) -> Uncertainty {
    let dof = n.saturating_sub(m);
    Uncertainty {
        std: vec![f64::NAN; m],
        sigma: if dof > 0 {
            (r.norm_squared() / dof as f64).sqrt()
        } else {
            f64::NAN
        },
        dof,
        condition_number: f64::NAN,
        singular_values: vec![],
        covariance: None,
    }
}

/// The R factor of a tall matrix (the matrix itself otherwise): the same column norms,
/// pivoted QR and dependencies, for the rank detection.
fn reduced(a: &DMatrix<f64>) -> DMatrix<f64> {
    if a.nrows() > a.ncols() {
        super::dense::r_factor(a)
    } else {
        a.clone()
    }
}

/// Identify `unknowns` from `x0`: rank detection on the physically scaled Jacobian, effect
/// screening, bounded LM, uncertainty, degeneracy checks, report.
pub fn solve(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    opts: &SolveOptions,
    monitor: &dyn Monitor,
) -> Result<Solution, IdentifyError> {
    solve_with(problem, unknowns, x0, opts, Blocking::Auto, monitor)
}

/// [`solve`], holding the Jacobian or folding it in blocks as `blocking` says (the same
/// solution to rounding either way).
pub fn solve_with(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    opts: &SolveOptions,
    blocking: Blocking,
    monitor: &dyn Monitor,
) -> Result<Solution, IdentifyError> {
    let (n, m) = (problem.residual_count(), problem.unknown_count());
    if unknowns.len() != m || x0.len() != m {
        return Err(IdentifyError::Model(format!(
            "{} unknown descriptions and {} start values for {m} unknowns",
            unknowns.len(),
            x0.len()
        )));
    }
    monitor.progress(0.0, "rank detection");
    let mut r0 = DVector::zeros(n);
    problem.residuals(x0, r0.as_mut_slice())?;
    if let Some(index) = r0.iter().position(|v| !v.is_finite()) {
        return Err(IdentifyError::NonFinite { index });
    }
    let fold_it = match blocking {
        Blocking::Auto => n * m >= super::blocked::BLOCKED_MIN_ELEMENTS,
        Blocking::Dense => false,
        Blocking::Folded => true,
    };
    let folded = if fold_it {
        let want = Want {
            gram: true,
            r_factor: true,
            amax: true,
            residuals: Some(r0.as_slice()),
            ..Want::default()
        };
        fold(problem, x0, None, &want)?
    } else {
        None
    };
    let j0 = match folded {
        Some(f) => Start0::Folded(f),
        None => {
            let mut j0 = DMatrix::zeros(n, m);
            problem.jacobian(x0, &mut j0)?;
            Start0::Dense(j0)
        }
    };
    let scale = physical_scales(unknowns);
    let effect = match &j0 {
        Start0::Dense(j) => effect_sizes(j, &scale),
        Start0::Folded(f) => (0..m).map(|k| f.amax[k] * scale[k]).collect(),
    };
    // The tall Jacobian is reduced once: rank and dependencies work on its R factor (the
    // one the rank detection computes of a tall matrix itself), the spectra of the plans
    // on R from the crossover on and on the Jacobian below it (their arithmetic as before).
    // Rows that only fix a gauge are left out of the rank detection; a small dense
    // Jacobian is its own rows for the plans, so with gauge rows the R factor of all rows
    // is not needed (`rq0` None): one factorisation of the start, not two.
    let data_rows = n.saturating_sub(problem.gauge_rows());
    let small = matches!(&j0, Start0::Dense(_) if n < super::dense::QR_FAER_MIN_ROWS);
    let (rq_data, rq0) = match &j0 {
        Start0::Dense(j) if data_rows < n => (
            reduced(&j.rows(0, data_rows).into_owned()),
            (!small).then(|| reduced(j)),
        ),
        Start0::Dense(j) => {
            let r = reduced(j);
            (r.clone(), Some(r))
        }
        Start0::Folded(f) => (f.r.clone(), Some(f.r.clone())),
    };
    let rq_data = &rq_data;
    // Unknowns held by the caller enter the rank detection as zero columns (so no other
    // column is dropped for them); their dependencies are those of their real columns.
    let held_cols: Vec<usize> = opts.hold.iter().map(|h| h.0).filter(|&k| k < m).collect();
    let zeroed = (!held_cols.is_empty()).then(|| {
        let mut z = rq_data.clone();
        held_cols.iter().for_each(|&k| z.column_mut(k).fill(0.0));
        z
    });
    let rq_rank = zeroed.as_ref().unwrap_or(rq_data);
    let mut rank = if opts.physical_rank {
        rank_revealing_scaled(rq_rank, &scale, &opts.pivoting, opts.rank_tolerance)
    } else {
        rank_revealing(rq_rank, &opts.pivoting, opts.rank_tolerance)
    };
    for (c, dep) in rank.dropped.iter().zip(rank.dependencies.iter_mut()) {
        if held_cols.contains(c) {
            *dep = super::rank::dependency(rq_data, &rank.kept, *c);
        }
    }
    let rf0 = match (&j0, rq0) {
        (Start0::Dense(j), _) if small => j.clone(),
        (_, Some(r)) => r,
        (Start0::Dense(j), None) => reduced(j),
        (Start0::Folded(f), None) => f.r.clone(),
    };
    let src0 = match &j0 {
        Start0::Dense(j) => Src::Dense(j),
        Start0::Folded(_) => Src::Blocked {
            problem,
            x: x0,
            r: &rf0,
            rows: n,
        },
    };
    let mut structural = rank.kept.clone();
    structural.sort_unstable();
    let given_floor = opts.effect_fraction.zip(opts.noise).map(|(f, v)| f * v);
    let all: Vec<usize> = (0..m).collect();
    let start_rows = Rows {
        blocks: vec![(src0, all.clone())],
        r: rf0.clone(),
    };
    let mut pl = plan(
        &structural,
        &effect,
        &start_rows,
        &scale,
        unknowns,
        given_floor,
        opts.near_dependent,
    )?;
    let start = FitStart {
        x0,
        r0: &r0,
        j0: &j0,
        uncertainty: opts.uncertainty,
        cheap: false,
    };
    let sub = SubMonitor::new(monitor, 0.05, 0.6);
    let mut fit = run_fit(problem, unknowns, &start, &pl.free, &opts.lm, &sub)?;
    // Without a stated noise, the fitted sigma sets the floor; refit once if it holds more.
    if let (None, Some(f)) = (opts.noise, opts.effect_fraction) {
        let floor = f * fit.unc.sigma;
        if floor.is_finite() {
            // Judge on the start and the first solution together (rows stacked): an unknown
            // or combination is held only if the data cannot see it at either point, since
            // a fitted frame can make an effect that vanishes at nominal a real one.
            // (The stacked rows through their blocks and the R factor of [R0; R_fit].)
            let fit_effect = fit.column_amax();
            let mut effect_both = effect.clone();
            for (p, &k) in pl.free.iter().enumerate() {
                effect_both[k] = effect_both[k].max(fit_effect[p] * scale[k]);
            }
            let r_fit = expand_cols(&fit.r, &pl.free, m);
            let mut stacked = DMatrix::zeros(rf0.nrows() + r_fit.nrows(), m);
            stacked.rows_mut(0, rf0.nrows()).copy_from(&rf0);
            stacked
                .rows_mut(rf0.nrows(), r_fit.nrows())
                .copy_from(&r_fit);
            let fit_src = match fit.amax {
                Some(_) => Src::Blocked {
                    problem,
                    x: &fit.x,
                    r: &fit.r,
                    rows: n,
                },
                None => Src::Dense(&fit.rep.jacobian),
            };
            let both = Rows {
                blocks: vec![(src0, all.clone()), (fit_src, pl.free.clone())],
                r: stacked,
            };
            let again = plan(
                &structural,
                &effect_both,
                &both,
                &scale,
                unknowns,
                Some(floor),
                opts.near_dependent,
            )?;
            let more = again.free != pl.free;
            pl = again;
            if more {
                let sub = SubMonitor::new(monitor, 0.6, 0.85);
                fit = run_fit(problem, unknowns, &start, &pl.free, &opts.lm, &sub)?;
            }
        }
    }
    let free = pl.free.clone();
    let Fit { rep, x, unc, r, .. } = fit;
    let residuals = rep.residuals.rows(0, n).into_owned();
    let cost_after = residuals.norm_squared();
    monitor.progress(0.85, "nuisance-only fit");
    let nuisance_cost = match &opts.nuisance {
        None => None,
        Some(list) => {
            let nf: Vec<usize> = free.iter().copied().filter(|k| list.contains(k)).collect();
            if nf.is_empty() {
                Some(r0.norm_squared())
            } else if nf == free {
                None
            } else {
                let sub = SubMonitor::new(monitor, 0.85, 0.95);
                // Only its cost is used: the cheap form of the problem serves (the same
                // cost to rounding).
                let lean = FitStart {
                    uncertainty: false,
                    cheap: true,
                    ..start
                };
                match run_fit(problem, unknowns, &lean, &nf, &opts.lm, &sub) {
                    Ok(f) => Some(f.rep.cost),
                    Err(IdentifyError::Cancelled) => return Err(IdentifyError::Cancelled),
                    Err(_) => None,
                }
            }
        }
    };
    monitor.progress(0.95, "uncertainty");
    let condition_number = if opts.uncertainty {
        spectrum_of_r(&expand_cols(&r, &free, m), &free, &scale).condition_number
    } else {
        f64::NAN
    };
    let degenerate = degeneracy(&DegeneracyCheck {
        unknowns,
        scale: &scale,
        x0,
        x: &x,
        factor: opts.degenerate_factor,
        cost: cost_after,
        nuisance_cost,
    });
    let noise = opts.noise.unwrap_or(unc.sigma);
    let mut params = Vec::with_capacity(m);
    let mut weakly = Vec::new();
    for (k, u) in unknowns.iter().enumerate() {
        let pos = free.iter().position(|&f| f == k);
        if pos.is_some() && effect[k] < noise {
            weakly.push(u.name.clone());
        }
        let at_bound = pos.and_then(|p| match rep.at_bound[p] {
            -1 => Some("lower".into()),
            1 => Some("upper".into()),
            _ => None,
        });
        params.push(ParamReport {
            name: u.name.clone(),
            unit: u.unit.clone(),
            nominal: u.nominal * u.to_report,
            value: x[k] * u.to_report,
            std: pos
                .filter(|_| opts.uncertainty)
                .map(|p| unc.std[p] * u.to_report),
            identifiable: pos.is_some(),
            effect_size: effect[k],
            at_bound,
        });
    }
    let dependencies = rank
        .dropped
        .iter()
        .zip(&rank.dependencies)
        .map(|(&c, dep)| Dependency {
            name: unknowns[c].name.clone(),
            combination: dep
                .iter()
                .take(6)
                .map(|&(k, v)| (unknowns[k].name.clone(), v))
                .collect(),
            reason: opts.hold.iter().find(|h| h.0 == c).map(|h| h.1.clone()),
        })
        .collect();
    let unobservable = pl
        .screened
        .iter()
        .map(|&k| Unobservable {
            name: unknowns[k].name.clone(),
            effect_size: effect[k],
            threshold: pl.floor.unwrap_or(0.0),
        })
        .collect();
    let held: Vec<usize> = structural
        .iter()
        .copied()
        .filter(|k| !pl.free.contains(k) && !pl.screened.contains(k))
        .collect();
    let mut dropped: Vec<usize> = rank
        .dropped
        .iter()
        .chain(&pl.screened)
        .chain(&held)
        .copied()
        .collect();
    dropped.sort_unstable();
    Ok(Solution {
        x,
        params,
        unidentifiable: dropped.iter().map(|&k| unknowns[k].name.clone()).collect(),
        dependencies,
        unobservable,
        near_dependent: pl.near,
        condition_number,
        nuisance_cost,
        degenerate,
        weakly_observable: weakly,
        free,
        stop: rep.stop,
        iterations: rep.iterations,
        cost_before: rep.initial_cost.min(r0.norm_squared()),
        cost_after,
        residuals_before: r0,
        residuals,
        uncertainty: unc,
        robust: None,
        held_gauge: None,
    })
}
