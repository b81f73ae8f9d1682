//! Distance measurements of a serial chain: a draw-wire sensor, an interferometer or a laser
//! tracker in distance-only mode reads the distance from the TCP to a fixed point (the
//! anchor) whose position is unknown, with an unknown length offset (the sensor's zero).
//! Residual = |TCP(q) - A| + L0 - L, one row per measurement. The anchor A (3 lengths) and
//! the offset L0 are nuisance unknowns appended after the chain parameters.
//!
//! A distance to a point is invariant under rotations about it and under every rigid motion
//! of {W}: the base frame (6 parameters) only acts through the anchor's position in {B}, so
//! with a free anchor the base parameters are structurally unidentifiable, as is the tool
//! orientation; rank detection holds them.

use nalgebra::{DMatrix, Matrix4, Vector3, Vector4};

use super::MeasureError;
use super::point::{chain_unknowns, frames_and_extras, length_unknown};
use crate::identify::{IdentifyError, Problem, Unknown};
use crate::model::{Chain, ParamId};

/// One distance measurement: joint values (rad) and the measured length (model length unit).
#[derive(Debug, Clone, PartialEq)]
pub struct DistanceMeasurement {
    /// Joint values, rad.
    pub q: Vec<f64>,
    /// Measured length (sensor reading, model length unit).
    pub length: f64,
}

/// The identification problem: unknowns = the chosen chain parameters, then the anchor
/// (x, y, z in {W}) and the length offset.
#[derive(Debug, Clone)]
pub struct DistanceProblem {
    chain: Chain,
    ids: Vec<ParamId>,
    cols: Vec<usize>,
    meas: Vec<DistanceMeasurement>,
    tau: Vec<Vec<f64>>,
}

/// Names of the four nuisance unknowns, in order.
pub const DISTANCE_NUISANCE: [&str; 4] = ["anchor.x", "anchor.y", "anchor.z", "length_offset"];

impl DistanceProblem {
    /// Build the problem (static torques once per configuration with the starting model).
    pub fn new(
        chain: Chain,
        ids: Vec<ParamId>,
        meas: Vec<DistanceMeasurement>,
    ) -> Result<Self, MeasureError> {
        if meas.len() < 5 {
            return Err(MeasureError::Row {
                row: meas.len(),
                reason: "distance measurements need at least 5 rows (anchor and offset)".into(),
            });
        }
        for (r, m) in meas.iter().enumerate() {
            if !m.length.is_finite() {
                return Err(MeasureError::Row {
                    row: r + 1,
                    reason: format!("length {} is not finite", m.length),
                });
            }
        }
        let cols = ids
            .iter()
            .map(|id| chain.param_index(*id).unwrap_or(usize::MAX))
            .collect();
        let tau = meas.iter().map(|m| chain.static_torques(&m.q)).collect();
        Ok(Self {
            chain,
            ids,
            cols,
            meas,
            tau,
        })
    }

    /// The measurements.
    pub fn measurements(&self) -> &[DistanceMeasurement] {
        &self.meas
    }

    /// Number of chain parameters among the unknowns.
    pub fn chain_unknowns(&self) -> usize {
        self.ids.len()
    }

    /// Starting unknowns: the chain's values, then anchor and offset fitted to the starting
    /// model's TCP positions (see [`fit_anchor`]).
    pub fn initial(&self) -> Vec<f64> {
        let mut x: Vec<f64> = self.ids.iter().map(|id| self.chain.param(*id)).collect();
        let pts: Vec<Vector3<f64>> = self
            .meas
            .iter()
            .zip(&self.tau)
            .map(|(m, t)| self.chain.tcp(&m.q, Some(t)).p)
            .collect();
        let l: Vec<f64> = self.meas.iter().map(|m| m.length).collect();
        let (a, l0) = fit_anchor(&pts, &l);
        x.extend([a.x, a.y, a.z, l0]);
        x
    }

    /// Names, units and ranges of the unknowns, in order.
    pub fn unknowns(&self) -> Vec<Unknown> {
        let c = &self.chain;
        let mut out = chain_unknowns(c, &self.ids);
        let x0 = self.initial();
        for (k, name) in DISTANCE_NUISANCE.iter().enumerate() {
            out.push(length_unknown(c, (*name).into(), x0[self.ids.len() + k]));
        }
        out
    }

    /// Indices of the nuisance unknowns: base and tool frame parameters, anchor and offset.
    pub fn nuisance(&self) -> Vec<usize> {
        frames_and_extras(&self.ids, self.unknown_count())
    }

    /// Column order of rank detection (strict priority): anchor and offset first (the
    /// measurement's own unknowns: without them no distance can be modelled), then the tool
    /// frame, then the joint parameters by priority class ([`ParamId::priority`]) and chain
    /// order, the base frame last. A distance to a free anchor cannot see the base frame
    /// (it only moves the anchor in {0}), so the base parameters are the ones held, at
    /// nominal, which keeps the anchor meaningful in {W} of the model.
    pub fn priority_order(&self) -> Vec<usize> {
        let n = self.ids.len();
        let mut order: Vec<usize> = (n..self.unknown_count()).collect();
        let mut chain: Vec<usize> = (0..n).collect();
        chain.sort_by_key(|&k| {
            let class = match self.ids[k] {
                ParamId::Tool(_) => 0,
                ParamId::Base(_) => 10,
                id => 1 + id.priority(),
            };
            (class, k)
        });
        order.extend(chain);
        order
    }

    /// The chain with the chain part of `x` applied.
    pub fn model(&self, x: &[f64]) -> Chain {
        let mut c = self.chain.clone();
        c.set_params(&self.ids, &x[..self.ids.len()]);
        c
    }

    /// Anchor and offset of unknowns `x`.
    pub fn anchor(&self, x: &[f64]) -> (Vector3<f64>, f64) {
        let o = self.ids.len();
        (Vector3::new(x[o], x[o + 1], x[o + 2]), x[o + 3])
    }
}

/// Signed distance errors `|TCP - A| + L0 - L` of a model (each configuration with the
/// model's own static deflection) against measurements.
pub fn distance_errors(
    chain: &Chain,
    anchor: &Vector3<f64>,
    offset: f64,
    meas: &[DistanceMeasurement],
) -> Vec<f64> {
    meas.iter()
        .map(|m| {
            let p = chain.tcp(&m.q, Some(&chain.static_torques(&m.q))).p;
            (p - anchor).norm() + offset - m.length
        })
        .collect()
}

/// Anchor A and offset L0 such that |p_i - A| + L0 ~ L_i: the linearisation
/// |p|^2 - L^2 = 2 p.A - 2 L L0 + (L0^2 - |A|^2) solved by linear least squares (the last
/// term as a fifth free unknown), then Gauss-Newton steps on the true residuals.
pub fn fit_anchor(p: &[Vector3<f64>], l: &[f64]) -> (Vector3<f64>, f64) {
    let mut ata = nalgebra::Matrix5::<f64>::zeros();
    let mut atb = nalgebra::Vector5::<f64>::zeros();
    for (pi, &li) in p.iter().zip(l) {
        let row = nalgebra::Vector5::new(2.0 * pi.x, 2.0 * pi.y, 2.0 * pi.z, -2.0 * li, 1.0);
        ata += row * row.transpose();
        atb += row * (pi.norm_squared() - li * li);
    }
    let mut a = Vector3::zeros();
    let mut l0 = 0.0;
    if let Some(s) = ata.try_inverse().map(|m| m * atb) {
        a = Vector3::new(s[0], s[1], s[2]);
        l0 = s[3];
    } else if !p.is_empty() {
        a = p.iter().fold(Vector3::zeros(), |s, v| s + v) / p.len() as f64;
    }
    for _ in 0..20 {
        let mut jtj = Matrix4::<f64>::zeros();
        let mut jtr = Vector4::<f64>::zeros();
        for (pi, &li) in p.iter().zip(l) {
            let d = pi - a;
            let n = d.norm().max(f64::MIN_POSITIVE);
            let u = d / n;
            let row = Vector4::new(-u.x, -u.y, -u.z, 1.0);
            let r = n + l0 - li;
            jtj += row * row.transpose();
            jtr += row * r;
        }
        let Some(step) = jtj.try_inverse().map(|m| m * jtr) else {
            break;
        };
        a -= Vector3::new(step[0], step[1], step[2]);
        l0 -= step[3];
        if step.norm() < 1e-12 * (1.0 + a.norm()) {
            break;
        }
    }
    (a, l0)
}

impl Problem for DistanceProblem {
    fn residual_count(&self) -> usize {
        self.meas.len()
    }

    fn unknown_count(&self) -> usize {
        self.ids.len() + 4
    }

    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let chain = self.model(x);
        let (a, l0) = self.anchor(x);
        for (i, (m, tau)) in self.meas.iter().zip(&self.tau).enumerate() {
            r[i] = (chain.tcp(&m.q, Some(tau)).p - a).norm() + l0 - m.length;
        }
        Ok(())
    }

    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let chain = self.model(x);
        let (a, _) = self.anchor(x);
        let o = self.ids.len();
        j.as_mut_slice().fill(0.0);
        let mut buf = vec![Vector3::zeros(); chain.param_ids().len()];
        for (i, (m, tau)) in self.meas.iter().zip(&self.tau).enumerate() {
            let p = chain.point_jacobian(&m.q, Some(tau), &Vector3::zeros(), &mut buf);
            let d = p - a;
            let u = d / d.norm().max(f64::MIN_POSITIVE);
            for (c, &col) in self.cols.iter().enumerate() {
                if let Some(v) = buf.get(col) {
                    j[(i, c)] = u.dot(v);
                }
            }
            for k in 0..3 {
                j[(i, o + k)] = -u[k];
            }
            j[(i, o + 3)] = 1.0;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::problem::central_differences;
    use crate::twin::SerialTwin;
    use crate::util::Rng;

    fn problem(seed: u64) -> (DistanceProblem, Vec<f64>) {
        let twin = SerialTwin::irb120(seed);
        let mut rng = Rng::new(seed);
        let anchor = Vector3::new(400.0, -300.0, -100.0);
        let offset = 25.0;
        let lim = [0.9, 0.8, 0.8, 1.5, 1.2, 2.0];
        let meas: Vec<DistanceMeasurement> = (0..30)
            .map(|_| {
                let q: Vec<f64> = lim
                    .iter()
                    .map(|l| l * (2.0 * rng.uniform() - 1.0))
                    .collect();
                let p = twin.true_tcp(&q);
                DistanceMeasurement {
                    length: (p - anchor).norm() - offset,
                    q,
                }
            })
            .collect();
        let mut names: Vec<String> = twin.file.identify.clone();
        names.extend(["tool.x", "tool.y", "tool.z"].map(String::from));
        let ids = names
            .iter()
            .map(|n| twin.nominal.param_by_name(n).unwrap())
            .collect();
        let p = DistanceProblem::new(twin.nominal.clone(), ids, meas).unwrap();
        let x = p.initial();
        (p, x)
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let (p, mut x) = problem(3);
        // Move away from the start a little so no term is trivially zero.
        for (k, v) in x.iter_mut().enumerate() {
            *v += 1e-3 * ((k % 7) as f64 - 3.0);
        }
        let (n, m) = (p.residual_count(), p.unknown_count());
        let mut ja = DMatrix::zeros(n, m);
        let mut jn = DMatrix::zeros(n, m);
        p.jacobian(&x, &mut ja).unwrap();
        central_differences(&p, &x, &mut jn).unwrap();
        for c in 0..m {
            let scale = jn.column(c).norm().max(1e-9);
            let err = (ja.column(c) - jn.column(c)).norm() / scale;
            assert!(err < 1e-5, "column {c}: relative error {err}");
        }
    }

    #[test]
    fn anchor_fit_recovers_a_known_anchor() {
        let mut rng = Rng::new(9);
        let a = Vector3::new(120.0, -40.0, 310.0);
        let pts: Vec<Vector3<f64>> = (0..40)
            .map(|_| {
                Vector3::new(
                    600.0 * rng.uniform() - 300.0,
                    600.0 * rng.uniform() - 300.0,
                    400.0 * rng.uniform(),
                )
            })
            .collect();
        let l: Vec<f64> = pts.iter().map(|p| (p - a).norm() - 33.0).collect();
        let (fa, fl) = fit_anchor(&pts, &l);
        assert!((fa - a).norm() < 1e-6, "{fa:?}");
        assert!((fl + 33.0).abs() < 1e-6, "{fl}");
    }
}
