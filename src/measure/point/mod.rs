//! Point coincidence and Cartesian measurements of a serial chain: the TCP at joint values
//! q must be at a ball centre (ball-centring, sockets) or at a measured point (laser
//! tracker). Residual = model TCP position - target, three rows per measurement, plus one
//! weighted row per known distance that involves an unknown ball centre.

use std::sync::{Mutex, MutexGuard};

use nalgebra::{DMatrix, Vector3};

use super::{BallPlate, MeasureError};
use crate::identify::{IdentifyError, Problem, Unknown};
use crate::model::chain::JacobianScratch;
use crate::model::trig::{TrigMemo, TrigMemos};
use crate::model::{Chain, ParamId, Quantity};

mod blocks;
mod point_frames;
mod start;

pub use start::PointStart;

/// What the TCP coincided with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    /// The centre of ball `k` (0-based) of the plate.
    Ball(usize),
    /// A point measured in {W} (model length unit).
    Point(Vector3<f64>),
}

/// One measurement: joint values (rad) and what the TCP was at.
#[derive(Debug, Clone, PartialEq)]
pub struct PointMeasurement {
    /// Joint values, rad.
    pub q: Vec<f64>,
    /// Target.
    pub target: Target,
}

impl PointMeasurement {
    /// Where the TCP was: the point, or the centre of its ball among `centres`.
    pub fn target_point(&self, centres: &[Vector3<f64>]) -> Vector3<f64> {
        match self.target {
            Target::Ball(b) => centres[b],
            Target::Point(p) => p,
        }
    }
}

/// The unknowns of the chain parameters `ids`: name, file unit, nominal and plausible range.
pub(crate) fn chain_unknowns(c: &Chain, ids: &[ParamId]) -> Vec<Unknown> {
    ids.iter()
        .map(|id| Unknown {
            name: c.param_name(*id),
            unit: c.units.name(id.quantity()).into(),
            to_report: c.units.to_file(id.quantity()),
            nominal: c.param(*id),
            plausible_range: plausible_range(c, id.quantity()),
            lower: None,
            upper: None,
        })
        .collect()
}

/// An unknown length of a measurement model beyond the chain's parameters (an unknown ball
/// centre coordinate, a distance sensor's anchor or offset), in the chain's length unit.
pub(crate) fn length_unknown(c: &Chain, name: String, nominal: f64) -> Unknown {
    Unknown {
        name,
        unit: c.units.name(Quantity::Length).into(),
        to_report: 1.0,
        nominal,
        plausible_range: plausible_range(c, Quantity::Length),
        lower: None,
        upper: None,
    }
}

/// The nuisance unknowns of a measurement model: the base and tool frame parameters among
/// `ids`, and every unknown after the chain's parameters (up to `count`).
pub(crate) fn frames_and_extras(ids: &[ParamId], count: usize) -> Vec<usize> {
    let frames = ids
        .iter()
        .enumerate()
        .filter(|(_, id)| matches!(id, ParamId::Base(_) | ParamId::Tool(_)))
        .map(|(k, _)| k);
    frames.chain(ids.len()..count).collect()
}

/// Plausible ranges used for effect sizes: 1 mm, 0.5 deg, 0.005 deg/(N*m).
pub fn plausible_range(chain: &Chain, q: Quantity) -> f64 {
    match q {
        Quantity::Length => 1e-3 / chain.units.metre(),
        Quantity::Angle => 0.5f64.to_radians(),
        Quantity::Compliance => 0.005f64.to_radians(),
        Quantity::Scalar => 1.0,
    }
}

/// A chain reused by the evaluations of a problem (one at a time; another evaluation at the
/// same moment copies the chain instead). A copy of the problem starts without one.
#[derive(Debug, Default)]
struct WorkChain(Mutex<Option<Chain>>);

impl WorkChain {
    /// The work chain, unless another evaluation holds it.
    fn take(&self) -> Option<MutexGuard<'_, Option<Chain>>> {
        self.0.try_lock().ok()
    }
}

impl Clone for WorkChain {
    fn clone(&self) -> Self {
        Self::default()
    }
}

/// The identification problem: unknowns = the chosen chain parameters, then the centres of
/// the plate's unknown balls (x, y, z each).
#[derive(Debug, Clone)]
pub struct PointProblem {
    chain: Chain,
    ids: Vec<ParamId>,
    cols: Vec<usize>,
    plate: BallPlate,
    free_balls: Vec<usize>,
    meas: Vec<PointMeasurement>,
    tau: Vec<Vec<f64>>,
    /// Joint sines and cosines of each measurement's last evaluation.
    trig: TrigMemos,
    /// The chain evaluations run on, its parameters set in place.
    work: WorkChain,
    /// Rows shared with other subsets of the same measurements at the start (see
    /// [`PointStart`]), with each measurement's row there.
    start: Option<(std::sync::Arc<PointStart>, Vec<usize>)>,
    /// Weight of the distance rows (residual per unit of distance error).
    pub distance_weight: f64,
}

impl PointProblem {
    /// Build the problem. Static torques are evaluated once per configuration with the
    /// starting model (compliance off), as the spec prescribes.
    pub fn new(
        chain: Chain,
        ids: Vec<ParamId>,
        plate: BallPlate,
        meas: Vec<PointMeasurement>,
    ) -> Result<Self, MeasureError> {
        Self::with_torques(chain, ids, plate, meas, None)
    }

    /// [`PointProblem::new`] given the static torques of the measurements with the
    /// starting model (as [`Chain::static_torques`] gives them), when the caller has them.
    pub fn with_torques(
        chain: Chain,
        ids: Vec<ParamId>,
        plate: BallPlate,
        meas: Vec<PointMeasurement>,
        torques: Option<Vec<Vec<f64>>>,
    ) -> Result<Self, MeasureError> {
        for (r, m) in meas.iter().enumerate() {
            if let Target::Ball(k) = m.target {
                if k >= plate.len() {
                    return Err(MeasureError::Row {
                        row: r + 1,
                        reason: format!("ball {} but the plate has {} balls", k + 1, plate.len()),
                    });
                }
            }
        }
        let free_balls = plate.unknown_balls();
        for &b in &free_balls {
            if !meas.iter().any(|m| m.target == Target::Ball(b)) {
                return Err(MeasureError::Plate(format!(
                    "ball {} has an unknown centre and no measurement",
                    b + 1
                )));
            }
        }
        let cols = ids
            .iter()
            .map(|id| chain.param_index(*id).unwrap_or(usize::MAX))
            .collect();
        let tau = match torques {
            Some(t) if t.len() == meas.len() => t,
            _ => start_torques(&chain, &meas),
        };
        let trig = TrigMemos::new(meas.len(), chain.joints.len());
        Ok(Self {
            chain,
            ids,
            cols,
            plate,
            free_balls,
            meas,
            tau,
            trig,
            work: WorkChain::default(),
            start: None,
            distance_weight: 10.0,
        })
    }

    /// This problem reading its start from `start`, measurement k at row `rows[k]` there
    /// (the rows of a problem over a superset with the same chain, unknowns and torques);
    /// unchanged when they do not fit.
    pub fn with_start(mut self, start: std::sync::Arc<PointStart>, rows: Vec<usize>) -> Self {
        if rows.len() == self.meas.len()
            && rows.iter().all(|&r| r < start.len())
            && start.width() == self.ids.len()
        {
            self.start = Some((start, rows));
        }
        self
    }

    /// The shared start and this problem's rows in it, when `x`'s chain unknowns are the
    /// ones it holds for.
    fn start_at(&self, x: &[f64]) -> Option<(&PointStart, &[usize])> {
        self.start
            .as_ref()
            .filter(|(s, _)| s.holds_for(&x[..self.ids.len().min(x.len())]))
            .map(|(s, rows)| (&**s, &rows[..]))
    }

    /// The measurements.
    pub fn measurements(&self) -> &[PointMeasurement] {
        &self.meas
    }

    /// Static torques used for each measurement.
    pub fn torques(&self) -> &[Vec<f64>] {
        &self.tau
    }

    /// Starting unknowns: the chain's values, and each unknown ball at the mean of the
    /// starting model's TCP positions measured on it.
    pub fn initial(&self) -> Vec<f64> {
        let mut x: Vec<f64> = self.ids.iter().map(|id| self.chain.param(*id)).collect();
        let start = self.start_at(&x);
        for &b in &self.free_balls {
            let pts: Vec<Vector3<f64>> = self
                .meas
                .iter()
                .zip(&self.tau)
                .enumerate()
                .filter(|(_, (m, _))| m.target == Target::Ball(b))
                .map(|(k, (m, t))| match start {
                    Some((s, rows)) => s.tcp(rows[k]),
                    None => self.chain.tcp(&m.q, Some(t)).p,
                })
                .collect();
            let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p) / pts.len() as f64;
            x.extend([c.x, c.y, c.z]);
        }
        x
    }

    /// Names, units and ranges of the unknowns, in order.
    pub fn unknowns(&self) -> Vec<Unknown> {
        let c = &self.chain;
        let mut out = chain_unknowns(c, &self.ids);
        let x0 = self.initial();
        for (k, &b) in self.free_balls.iter().enumerate() {
            for (a, axis) in ["x", "y", "z"].iter().enumerate() {
                out.push(length_unknown(
                    c,
                    format!("ball{}.{axis}", b + 1),
                    x0[self.ids.len() + 3 * k + a],
                ));
            }
        }
        out
    }

    /// Indices of the nuisance unknowns: base and tool frame parameters and unknown ball
    /// centres (what a fit of the frames alone would move).
    pub fn nuisance(&self) -> Vec<usize> {
        frames_and_extras(&self.ids, self.unknown_count())
    }

    /// Column order for priority rank detection: the parameters' priority classes
    /// ([`ParamId::priority`]), chain order within a class, unknown ball centres last.
    pub fn priority_order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.unknown_count()).collect();
        order.sort_by_key(|&k| (self.ids.get(k).map_or(u8::MAX, |id| id.priority()), k));
        order
    }

    /// The chain with the chain part of `x` applied.
    pub fn model(&self, x: &[f64]) -> Chain {
        let mut c = self.chain.clone();
        c.set_params(&self.ids, &x[..self.ids.len()]);
        c
    }

    /// `f` of [`PointProblem::model`], on the work chain when it is free: the same parameter
    /// values set in place (every unknown is set, the others stay nominal), without copying
    /// the joints.
    fn with_chain<R>(&self, x: &[f64], f: impl FnOnce(&Chain) -> R) -> R {
        match self.work.take() {
            Some(mut work) => {
                let c = work.get_or_insert_with(|| self.chain.clone());
                c.set_params(&self.ids, &x[..self.ids.len()]);
                f(c)
            }
            None => f(&self.model(x)),
        }
    }

    /// Ball centres for unknowns `x` (fixed ones from the plate).
    pub fn centres(&self, x: &[f64]) -> Vec<Vector3<f64>> {
        let mut out: Vec<Vector3<f64>> = self
            .plate
            .centres
            .iter()
            .map(|c| c.unwrap_or_else(Vector3::zeros))
            .collect();
        for (k, &b) in self.free_balls.iter().enumerate() {
            let o = self.ids.len() + 3 * k;
            out[b] = Vector3::new(x[o], x[o + 1], x[o + 2]);
        }
        out
    }

    /// The weighted distance rows (after the three rows per measurement) of `r`.
    fn distance_rows(&self, centres: &[Vector3<f64>], r: &mut [f64]) {
        let base = 3 * self.meas.len();
        for (k, &(i, j, d)) in self.plate.distances.iter().enumerate() {
            r[base + k] = self.distance_weight * ((centres[i] - centres[j]).norm() - d);
        }
    }

    fn free_slot(&self, ball: usize) -> Option<usize> {
        self.free_balls
            .iter()
            .position(|&b| b == ball)
            .map(|k| self.ids.len() + 3 * k)
    }

    /// The first unknown of the ball centre measurement `m` was taken on, when that centre
    /// is unknown (its three columns hold -1 in the measurement's rows).
    fn ball_slot(&self, m: &PointMeasurement) -> Option<usize> {
        match m.target {
            Target::Ball(b) => self.free_slot(b),
            Target::Point(_) => None,
        }
    }
}

/// Static torques of every configuration with `chain` (compliance off), on every core for
/// large sets.
pub fn start_torques(chain: &Chain, meas: &[PointMeasurement]) -> Vec<Vec<f64>> {
    let ranges = measurement_ranges(meas.len());
    let mut tau: Vec<Vec<f64>> = vec![Vec::new(); meas.len()];
    let mut rest = &mut tau[..];
    let mut parts = Vec::with_capacity(ranges.len());
    for range in &ranges {
        let (head, tail) = rest.split_at_mut(range.len());
        parts.push((range.start, head));
        rest = tail;
    }
    on_threads(parts, &|(start, out): (usize, &mut [Vec<f64>])| {
        for (k, t) in out.iter_mut().enumerate() {
            *t = chain.static_torques(&meas[start + k].q);
        }
    });
    tau
}

/// Each range's memos (`joints` per measurement) out of `all`, or none for every range.
fn memo_parts<'m>(
    all: Option<&'m mut [TrigMemo]>,
    ranges: &[std::ops::Range<usize>],
    joints: usize,
) -> Vec<Option<&'m mut [TrigMemo]>> {
    let Some(mut rest) = all else {
        return ranges.iter().map(|_| None).collect();
    };
    ranges
        .iter()
        .map(|r| {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(r.len() * joints);
            rest = tail;
            Some(head)
        })
        .collect()
}

/// Measurements from which residuals and Jacobians are evaluated on every core (fewer run
/// on the calling thread: a dispersion study already runs its identifications in
/// parallel, with at most a few hundred measurements each).
pub const PARALLEL_MIN_MEASUREMENTS: usize = 1024;

/// Contiguous ranges of `n` measurements, one per worker.
fn measurement_ranges(n: usize) -> Vec<std::ops::Range<usize>> {
    let threads = if n < PARALLEL_MIN_MEASUREMENTS {
        1
    } else {
        std::thread::available_parallelism().map_or(1, |t| t.get())
    };
    crate::util::parts::ranges(n, threads)
}

/// `f` on each part, on scoped threads when there are several (a worker's panic is
/// passed on).
fn on_threads<T: Send>(parts: Vec<T>, f: &(dyn Fn(T) + Sync)) {
    if parts.len() <= 1 {
        parts.into_iter().for_each(f);
        return;
    }
    std::thread::scope(|s| {
        let handles: Vec<_> = parts.into_iter().map(|p| s.spawn(move || f(p))).collect();
        for h in handles {
            if let Err(e) = h.join() {
                std::panic::resume_unwind(e);
            }
        }
    });
}

impl Problem for PointProblem {
    fn residual_count(&self) -> usize {
        3 * self.meas.len() + self.plate.distances.len()
    }

    fn unknown_count(&self) -> usize {
        self.ids.len() + 3 * self.free_balls.len()
    }

    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        if let Some((start, rows)) = self.start_at(x) {
            let centres = self.centres(x);
            for (k, m) in self.meas.iter().enumerate() {
                let e = start.tcp(rows[k]) - m.target_point(&centres);
                r[3 * k..3 * k + 3].copy_from_slice(e.as_slice());
            }
            self.distance_rows(&centres, r);
            return Ok(());
        }
        self.with_chain(x, |chain| {
            let centres = self.centres(x);
            let base = 3 * self.meas.len();
            let ranges = measurement_ranges(self.meas.len());
            let nj = chain.joints.len();
            let mut memos = self.trig.try_take();
            let memos = memos
                .as_deref_mut()
                .filter(|v| v.len() == nj * self.meas.len());
            let mut rest = &mut r[..base];
            let mut parts = Vec::with_capacity(ranges.len());
            for (range, memo) in
                ranges
                    .iter()
                    .zip(memo_parts(memos.map(|v| &mut v[..]), &ranges, nj))
            {
                let (head, tail) = rest.split_at_mut(3 * range.len());
                parts.push((range.clone(), head, memo));
                rest = tail;
            }
            type Part<'a> = (
                std::ops::Range<usize>,
                &'a mut [f64],
                Option<&'a mut [TrigMemo]>,
            );
            let fill = |(range, out, mut memo): Part<'_>| {
                for (row, i) in range.clone().enumerate() {
                    let (m, tau) = (&self.meas[i], &self.tau[i]);
                    let target = m.target_point(&centres);
                    let frame = match memo.as_deref_mut() {
                        Some(mm) => {
                            chain.tcp_memo(&m.q, Some(tau), &mut mm[nj * row..nj * (row + 1)])
                        }
                        None => chain.tcp(&m.q, Some(tau)),
                    };
                    let e = frame.p - target;
                    out[3 * row..3 * row + 3].copy_from_slice(e.as_slice());
                }
            };
            on_threads(parts, &fill);
            self.distance_rows(&centres, r);
            Ok(())
        })
    }

    /// With every chain parameter held (a nuisance-only fit), the cheap form of
    /// [`point_frames`]: each measurement's flange frame computed once.
    fn held(&self, x: &[f64], free: &[usize]) -> Option<Box<dyn Problem + '_>> {
        point_frames::FramesFit::new(self, x, free).map(|f| Box::new(f) as Box<dyn Problem + '_>)
    }

    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        self.fill_jacobian(x, None, j);
        Ok(())
    }

    fn jacobian_columns(
        &self,
        x: &[f64],
        cols: &[usize],
        j: &mut DMatrix<f64>,
    ) -> Result<bool, IdentifyError> {
        self.fill_jacobian(x, Some(cols), j);
        Ok(true)
    }

    fn jacobian_blocks(
        &self,
        x: &[f64],
        cols: Option<&[usize]>,
        block_rows: usize,
        visitors: &mut [&mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)],
    ) -> Result<bool, IdentifyError> {
        self.visit_jacobian_blocks(x, cols, block_rows, visitors);
        Ok(true)
    }
}

impl PointProblem {
    /// The output column of each unknown for the columns `cols` (None: all), and which
    /// chain parameters the chain must differentiate (empty: all).
    fn column_map(&self, cols: Option<&[usize]>) -> (Vec<Option<usize>>, Vec<bool>) {
        let m = self.unknown_count();
        let at: Vec<Option<usize>> = match cols {
            None => (0..m).map(Some).collect(),
            Some(cols) => {
                let mut at = vec![None; m];
                for (c, &k) in cols.iter().enumerate() {
                    at[k] = Some(c);
                }
                at
            }
        };
        let wanted: Vec<bool> = match cols {
            None => Vec::new(),
            Some(_) => {
                let mut w = vec![false; self.chain.param_ids().len()];
                for (c, &col) in self.cols.iter().enumerate() {
                    if let (Some(slot), Some(_)) = (w.get_mut(col), at[c]) {
                        *slot = true;
                    }
                }
                w
            }
        };
        (at, wanted)
    }

    /// The Jacobian at `x` into `j`: every unknown's column, or those of `cols` (column
    /// `c` of `j` is unknown `cols[c]`; the chain computes only those).
    fn fill_jacobian(&self, x: &[f64], cols: Option<&[usize]>, j: &mut DMatrix<f64>) {
        let (at, wanted) = self.column_map(cols);
        if let Some((start, rows)) = self.start_at(x).filter(|_| cols.is_none()) {
            j.as_mut_slice().fill(0.0);
            for (k, m) in self.meas.iter().enumerate() {
                for (c, v) in start.jacobian(rows[k]).iter().enumerate() {
                    if let Some(oc) = at[c] {
                        for a in 0..3 {
                            j[(3 * k + a, oc)] = v[a];
                        }
                    }
                }
                self.ball_columns(m, k, &at, j);
            }
            self.distance_columns(&self.centres(x), &at, j);
            return;
        }
        self.with_chain(x, |chain| {
            let centres = self.centres(x);
            j.as_mut_slice().fill(0.0);
            let (n, width) = j.shape();
            let ranges = measurement_ranges(self.meas.len());
            let nj = chain.joints.len();
            let mut memos = self.trig.try_take();
            let memos = memos
                .as_deref_mut()
                .filter(|v| v.len() == nj * self.meas.len());
            // Each worker gets its rows of every column (column-major storage: one slice per
            // column and worker).
            type Part<'a> = (
                std::ops::Range<usize>,
                Vec<&'a mut [f64]>,
                Option<&'a mut [TrigMemo]>,
            );
            let mut parts: Vec<Part<'_>> = ranges
                .iter()
                .zip(memo_parts(memos.map(|v| &mut v[..]), &ranges, nj))
                .map(|(r, memo)| (r.clone(), Vec::with_capacity(width), memo))
                .collect();
            for column in j.as_mut_slice().chunks_mut(n.max(1)) {
                let mut rest = column;
                for (range, slices, _) in parts.iter_mut() {
                    let (head, tail) = rest.split_at_mut(3 * range.len());
                    slices.push(head);
                    rest = tail;
                }
            }
            let fill = |(range, mut out, mut memo): Part<'_>| {
                let mut buf = vec![Vector3::zeros(); chain.param_ids().len()];
                let mut scratch = JacobianScratch::default();
                scratch.set_wanted(wanted.clone());
                for (row, i) in range.clone().enumerate() {
                    let m = &self.meas[i];
                    let memo_i = memo
                        .as_deref_mut()
                        .map(|mm| &mut mm[nj * row..nj * (row + 1)]);
                    self.chain_rows(chain, i, &mut buf, &mut scratch, memo_i);
                    for (c, &col) in self.cols.iter().enumerate() {
                        if let (Some(v), Some(oc)) = (buf.get(col), at[c]) {
                            for a in 0..3 {
                                out[oc][3 * row + a] = v[a];
                            }
                        }
                    }
                    if let Some(o) = self.ball_slot(m) {
                        for a in 0..3 {
                            if let Some(oc) = at[o + a] {
                                out[oc][3 * row + a] = -1.0;
                            }
                        }
                    }
                }
            };
            on_threads(parts, &fill);
            self.distance_columns(&centres, &at, j);
        })
    }

    /// Measurement k's ball-centre columns (-1 on its free ball's axes) into `j`.
    fn ball_columns(
        &self,
        m: &PointMeasurement,
        k: usize,
        at: &[Option<usize>],
        j: &mut DMatrix<f64>,
    ) {
        if let Some(o) = self.ball_slot(m) {
            for a in 0..3 {
                if let Some(oc) = at[o + a] {
                    j[(3 * k + a, oc)] = -1.0;
                }
            }
        }
    }

    /// The plate's distance rows (after the three rows per measurement) into `j`.
    fn distance_columns(
        &self,
        centres: &[Vector3<f64>],
        at: &[Option<usize>],
        j: &mut DMatrix<f64>,
    ) {
        let base = 3 * self.meas.len();
        for k in 0..self.plate.distances.len() {
            self.distance_row(centres, k, |u, v| {
                if let Some(oc) = at[u] {
                    j[(base + k, oc)] = v;
                }
            });
        }
    }

    /// The nonzero entries (unknown, value) of the Jacobian's row of plate distance k.
    fn distance_row(&self, centres: &[Vector3<f64>], k: usize, mut f: impl FnMut(usize, f64)) {
        let (bi, bj, _) = self.plate.distances[k];
        let diff = centres[bi] - centres[bj];
        let u = diff / diff.norm().max(f64::MIN_POSITIVE);
        for (ball, sign) in [(bi, 1.0), (bj, -1.0)] {
            if let Some(o) = self.free_slot(ball) {
                for a in 0..3 {
                    f(o + a, self.distance_weight * sign * u[a]);
                }
            }
        }
    }

    /// d TCP / d (chain parameter) of measurement i into `buf` (one vector per chain
    /// parameter), its joint sines and cosines through `memo` when given.
    fn chain_rows(
        &self,
        chain: &Chain,
        i: usize,
        buf: &mut [Vector3<f64>],
        scratch: &mut JacobianScratch,
        memo: Option<&mut [TrigMemo]>,
    ) {
        let (m, tau) = (&self.meas[i], &self.tau[i]);
        chain.point_jacobian_memo(&m.q, Some(tau), &Vector3::zeros(), buf, scratch, memo);
    }
}
