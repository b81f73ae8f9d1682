//! The start shared by the fits of many subsets of one measurement set (a dispersion
//! study's 2,000 identifications): every measurement's TCP and Jacobian rows at the
//! starting chain, computed once. A subset's problem evaluated at its start gathers its
//! rows instead of running the chain again: the same values bit for bit, since a row depends
//! only on its measurement, its torques and the chain's parameters (the subset's own
//! ball-centre starts enter the residuals by a subtraction and the Jacobian not at all).

use nalgebra::Vector3;

use super::PointProblem;
use crate::model::chain::JacobianScratch;

/// Every measurement's TCP and chain Jacobian rows at one set of chain parameters.
#[derive(Debug)]
pub struct PointStart {
    /// The chain unknowns' values the rows hold for (bit patterns).
    params: Vec<u64>,
    /// TCP of each measurement, with its torques.
    tcp: Vec<Vector3<f64>>,
    /// d TCP / d (chain unknown c) of measurement i at `jac[i * width + c]`.
    jac: Vec<Vector3<f64>>,
    width: usize,
}

impl PointStart {
    /// The rows of every measurement of `problem` at its chain's own parameter values (the
    /// chain part of [`PointProblem::initial`]).
    pub fn of(problem: &PointProblem) -> Self {
        let chain = &problem.chain;
        let width = problem.ids.len();
        let mut buf = vec![Vector3::zeros(); chain.param_ids().len()];
        let mut scratch = JacobianScratch::default();
        let mut tcp = Vec::with_capacity(problem.meas.len());
        let mut jac = Vec::with_capacity(problem.meas.len() * width);
        for (i, (m, tau)) in problem.meas.iter().zip(&problem.tau).enumerate() {
            tcp.push(chain.tcp(&m.q, Some(tau)).p);
            problem.chain_rows(chain, i, &mut buf, &mut scratch, None);
            jac.extend(
                problem
                    .cols
                    .iter()
                    .map(|&col| buf.get(col).copied().unwrap_or_else(Vector3::zeros)),
            );
        }
        Self {
            params: problem
                .ids
                .iter()
                .map(|id| chain.param(*id).to_bits())
                .collect(),
            tcp,
            jac,
            width,
        }
    }

    /// Measurements it holds.
    pub fn len(&self) -> usize {
        self.tcp.len()
    }

    /// Whether it holds no measurement.
    pub fn is_empty(&self) -> bool {
        self.tcp.is_empty()
    }

    /// Whether the chain unknowns `x` are the ones the rows hold for.
    pub(super) fn holds_for(&self, x: &[f64]) -> bool {
        x.len() >= self.params.len() && self.params.iter().zip(x).all(|(p, v)| *p == v.to_bits())
    }

    /// TCP of measurement `i`.
    pub(super) fn tcp(&self, i: usize) -> Vector3<f64> {
        self.tcp[i]
    }

    /// The Jacobian rows of measurement `i`, one vector per chain unknown.
    pub(super) fn jacobian(&self, i: usize) -> &[Vector3<f64>] {
        &self.jac[i * self.width..(i + 1) * self.width]
    }

    /// Chain unknowns per row.
    pub(super) fn width(&self) -> usize {
        self.width
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use nalgebra::DMatrix;

    use super::PointStart;
    use crate::identify::Problem;
    use crate::measure::PointProblem;
    use crate::twin::SerialTwin;

    /// A subset read from the whole set's start has the start, residuals and Jacobian the
    /// subset computes itself, bit for bit (its own ball-centre starts included); away
    /// from the start (another chain value) it evaluates the chain as before.
    #[test]
    fn a_subset_at_the_shared_start_equals_its_own_evaluation() {
        let twin = SerialTwin::irb120(1);
        let (chain, ids) = (twin.nominal.clone(), twin.nominal.param_ids());
        let meas = twin.centring(30, 2);
        let whole = PointProblem::new(chain.clone(), ids.clone(), twin.plate.clone(), meas.clone())
            .expect("twin data are consistent");
        let start = Arc::new(PointStart::of(&whole));
        assert_eq!(start.len(), meas.len());
        // Every third measurement, from the second on.
        let rows: Vec<usize> = (1..meas.len()).step_by(3).collect();
        let subset: Vec<_> = rows.iter().map(|&i| meas[i].clone()).collect();
        let own = PointProblem::with_torques(
            chain.clone(),
            ids.clone(),
            twin.plate.clone(),
            subset.clone(),
            Some(rows.iter().map(|&i| whole.torques()[i].clone()).collect()),
        )
        .expect("a subset is consistent");
        let shared = own.clone().with_start(start.clone(), rows.clone());
        assert!(shared.start.is_some(), "the rows fit");
        let x = own.initial();
        let xs = shared.initial();
        assert_eq!(bits(&x), bits(&xs), "the starts");
        let (n, m) = (own.residual_count(), own.unknown_count());
        let moved = {
            let mut y = x.clone();
            y[0] += 1e-3;
            y
        };
        for (at, from_start) in [(&x, true), (&moved, false)] {
            let (mut r1, mut r2) = (vec![0.0; n], vec![f64::NAN; n]);
            own.residuals(at, &mut r1).unwrap();
            shared.residuals(at, &mut r2).unwrap();
            assert_eq!(
                bits(&r1),
                bits(&r2),
                "residuals (at the start: {from_start})"
            );
            let (mut j1, mut j2) = (DMatrix::zeros(n, m), DMatrix::from_element(n, m, f64::NAN));
            own.jacobian(at, &mut j1).unwrap();
            shared.jacobian(at, &mut j2).unwrap();
            assert_eq!(
                bits(j1.as_slice()),
                bits(j2.as_slice()),
                "Jacobian (at the start: {from_start})"
            );
            assert_eq!(shared.start_at(at).is_some(), from_start);
        }
        // Rows that do not fit (one too few) leave the problem as it was.
        let short = own.clone().with_start(start, rows[1..].to_vec());
        assert!(short.start.is_none());
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }
}
