//! Sensitivity analysis of the 3-PF model (the paper's Table 2): central finite differences
//! of the platform pose (x, y, theta) with respect to every robot parameter over a set of
//! configurations, reported per parameter type as the largest magnitude over configurations
//! and limbs.
//!
//! Without an external load the model is scale-free in `E` (the integration never sees it),
//! so `E` comes out exactly zero; the diameters only enter through their ratios, so a common
//! change of all three `d_i` (row `d (all)`) comes out exactly zero too.

use serde::{Deserialize, Serialize};

use super::params::{E_INDEX, LIMB_FIELDS, ROBOT_PARAMS};
use super::{Equilibrium, Pcr, PcrError};
use crate::util::Monitor;

/// One row of Table 2.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensitivityRow {
    /// Parameter type (`Ax`, ..., `d`, `d (all)`, `E`).
    pub parameter: String,
    /// Unit of the parameter.
    pub unit: String,
    /// Finite-difference step used (parameter unit).
    pub step: f64,
    /// Largest |dx/dp| over configurations and limbs.
    pub dx: f64,
    /// Largest |dy/dp|.
    pub dy: f64,
    /// Largest |dtheta/dp|.
    pub dtheta: f64,
    /// Unit of dx and dy (`m/m`, `m/rad`, `m/Pa`).
    pub position_unit: String,
    /// Unit of dtheta (`rad/m`, `rad/rad`, `rad/Pa`).
    pub angle_unit: String,
}

/// The 26 configurations of the default analysis: the 3 x 3 x 3 grid over the central
/// `fraction` of each joint range, without its centre (the home pose).
pub fn central_configurations(limits: &[[f64; 2]; 3], fraction: f64) -> Vec<[f64; 3]> {
    let level = |k: usize, s: f64| {
        let [lo, hi] = limits[k];
        let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo) * fraction);
        mid + s * half
    };
    let mut out = Vec::with_capacity(26);
    for a in [-1.0, 0.0, 1.0] {
        for b in [-1.0, 0.0, 1.0] {
            for c in [-1.0, 0.0, 1.0] {
                if (a, b, c) != (0.0, 0.0, 0.0) {
                    out.push([level(0, a), level(1, b), level(2, c)]);
                }
            }
        }
    }
    out
}

/// Table 2 over `configs`, with finite-difference steps `steps[type]` (one per entry of
/// [`LIMB_FIELDS`], then E). Every pose is solved warm from the configuration's solution.
pub fn sensitivity(
    robot: &Pcr,
    configs: &[[f64; 3]],
    steps: &[f64; 10],
    monitor: &dyn Monitor,
) -> Result<Vec<SensitivityRow>, PcrError> {
    let p0 = *robot.params();
    // One pose derivative: central difference over a parameter change applied by `apply`.
    let derivative = |eq: &Equilibrium,
                      q: &[f64; 3],
                      h: f64,
                      apply: &dyn Fn(&mut super::PcrParams, f64)|
     -> Result<[f64; 3], PcrError> {
        let pose = |sign: f64| -> Result<[f64; 3], PcrError> {
            let mut p = p0;
            apply(&mut p, sign * h);
            let r = robot.with_params(p)?;
            let e = r.fk_from(eq, q)?;
            Ok([e.pose.x, e.pose.y, e.pose.theta])
        };
        let (a, b) = (pose(1.0)?, pose(-1.0)?);
        Ok(std::array::from_fn(|c| (a[c] - b[c]) / (2.0 * h)))
    };
    let mut rows: Vec<[f64; 3]> = vec![[0.0; 3]; 11];
    for (n, q) in configs.iter().enumerate() {
        if monitor.is_cancelled() {
            return Err(PcrError::NotConverged {
                reason: "cancelled".into(),
                iterations: 0,
                residual: f64::NAN,
            });
        }
        monitor.progress(n as f64 / configs.len() as f64, "sensitivity");
        let eq = robot.fk(q)?;
        for k in 0..ROBOT_PARAMS {
            let t = if k == E_INDEX { 9 } else { k % 9 };
            let d = derivative(&eq, q, steps[t], &|p, h| p.set(k, p.get(k) + h))?;
            let row = if k == E_INDEX { 10 } else { t };
            for c in 0..3 {
                rows[row][c] = rows[row][c].max(d[c].abs());
            }
        }
        let all_d = |p: &mut super::PcrParams, h: f64| {
            for l in &mut p.limbs {
                l.d += h;
            }
        };
        let d = derivative(&eq, q, steps[8], &all_d)?;
        for c in 0..3 {
            rows[9][c] = rows[9][c].max(d[c].abs());
        }
    }
    monitor.progress(1.0, "sensitivity");
    let names: Vec<&str> = LIMB_FIELDS
        .iter()
        .copied()
        .chain(["d (all)", "E"])
        .collect();
    Ok(names
        .iter()
        .enumerate()
        .map(|(r, name)| {
            let unit = match *name {
                "E" => "Pa",
                "gamma" | "alpha" | "beta" => "rad",
                _ => "m",
            };
            let step = match r {
                9 => steps[8],
                10 => steps[9],
                _ => steps[r],
            };
            SensitivityRow {
                parameter: name.to_string(),
                unit: unit.into(),
                step,
                dx: rows[r][0],
                dy: rows[r][1],
                dtheta: rows[r][2],
                position_unit: format!("m/{unit}"),
                angle_unit: format!("rad/{unit}"),
            }
        })
        .collect())
}

/// Default finite-difference steps: 1 % of the model file's standard uncertainty of each
/// type (`Ax` .. `d`, then `E`).
pub fn default_steps(u: &super::file::Uncertainty) -> [f64; 10] {
    let r = u.robot();
    let mut s: [f64; 10] = std::array::from_fn(|k| 0.01 * if k < 9 { r[k] } else { u.E });
    for v in &mut s {
        if *v <= 0.0 {
            *v = 1e-9;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::pcr::PcrFile;
    use crate::util::NoMonitor;

    #[test]
    fn e_and_common_diameter_have_exactly_zero_influence() {
        let text = std::fs::read_to_string("tests/data/robots/pcr3pf.json").expect("data");
        let file = PcrFile::parse(&text).expect("file");
        let robot = file.robot().expect("robot");
        let configs = central_configurations(robot.limits(), 0.4);
        assert_eq!(configs.len(), 26);
        let rows = sensitivity(
            &robot,
            &configs[..6],
            &default_steps(&file.uncertainty),
            &NoMonitor,
        )
        .expect("table");
        let get = |n: &str| rows.iter().find(|r| r.parameter == n).expect("row");
        for n in ["E", "d (all)"] {
            let r = get(n);
            assert_eq!((r.dx, r.dy, r.dtheta), (0.0, 0.0, 0.0), "{n}");
        }
        // One diameter alone changes the stiffness ratio: a real influence.
        assert!(get("d").dtheta > 1e-3, "{:?}", get("d"));
        // Rigid-body parameters: a clamp displacement moves the platform by about as much.
        let ax = get("Ax");
        assert!(ax.dx > 0.3 && ax.dx < 3.0, "{ax:?}");
        // A rod length acts like a stage displacement along the rod: theta ~ 1 / (10 mm).
        let l = get("l");
        assert!(l.dtheta > 10.0 && l.dtheta < 300.0, "{l:?}");
    }
}
