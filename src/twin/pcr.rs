//! Twin of the 3-PF robot under its microscope: true robot parameters and extrinsics drawn
//! around the model file's nominal values with the file's standard uncertainties, and a
//! microscope whose readings carry the repeatability noise (9.13 nm per position coordinate,
//! 1.2 urad in angle by default). Seeded; no I/O.

use crate::geometry::Pose2;
use crate::measure::pcr::{PcrMeasurement, reading};
use crate::model::pcr::file::{Extrinsics, Repeatability};
use crate::model::pcr::{Equilibrium, Pcr, PcrError, PcrFile, PcrParams, ROBOT_PARAMS};
use crate::util::Rng;

/// The nominal 3-PF model shipped with calibd (copied from `../shared/data/robots`).
pub const PCR3PF_JSON: &str = include_str!("../../tests/data/robots/pcr3pf.json");

/// True draws are normal with the file's standard uncertainty, redrawn beyond this many
/// uncertainties, so the truth lies inside the identification bounds (3 uncertainties).
pub const TRUNCATION: f64 = 2.5;

/// The robot as it really is, and its microscope.
#[derive(Debug, Clone)]
pub struct PcrTwin {
    /// The nominal model file (what the identification starts from).
    pub file: PcrFile,
    /// True robot parameters.
    pub true_params: PcrParams,
    /// True extrinsics.
    pub true_extrinsics: Extrinsics,
    /// The true robot, solvable.
    pub truth: Pcr,
    /// Microscope noise: standard deviation per position coordinate (m) and of the angle (rad).
    pub noise: Repeatability,
}

fn truncated_normal(rng: &mut Rng) -> f64 {
    loop {
        let v = rng.normal();
        if v.abs() <= TRUNCATION {
            return v;
        }
    }
}

impl PcrTwin {
    /// A twin of `file` whose true errors are drawn from `seed`.
    pub fn new(file: &PcrFile, seed: u64) -> Result<Self, PcrError> {
        let mut rng = Rng::new(seed);
        let nominal = file.params();
        let u = file.uncertainty.robot();
        let mut truth = nominal;
        for (k, uk) in u.iter().enumerate().take(ROBOT_PARAMS) {
            truth.set(k, nominal.get(k) + uk * truncated_normal(&mut rng));
        }
        let ue = file.uncertainty.extrinsics();
        let ext: [f64; 6] = std::array::from_fn(|k| {
            file.extrinsics.to_array()[k] + ue[k] * truncated_normal(&mut rng)
        });
        let robot = Pcr::new(truth, file.limits())?;
        Ok(Self {
            file: file.clone(),
            true_params: truth,
            true_extrinsics: Extrinsics::from_array(&ext),
            truth: robot,
            noise: file.repeatability,
        })
    }

    /// The twin of the shipped nominal model.
    pub fn nominal(seed: u64) -> Result<Self, PcrError> {
        let file = PcrFile::parse(PCR3PF_JSON).map_err(|e| PcrError::InvalidParameter {
            name: "embedded model".into(),
            value: f64::NAN,
            reason: e.to_string(),
        })?;
        Self::new(&file, seed)
    }

    /// The true platform poses at `qs`, solved along the list (warm starts).
    pub fn true_poses(&self, qs: &[[f64; 3]]) -> Result<Vec<Equilibrium>, PcrError> {
        let mut out: Vec<Equilibrium> = Vec::with_capacity(qs.len());
        for q in qs {
            let eq = match out.last() {
                Some(prev) => self.truth.fk_from(prev, q).or_else(|_| self.truth.fk(q))?,
                None => self.truth.fk(q)?,
            };
            out.push(eq);
        }
        Ok(out)
    }

    /// A noisy microscope reading of a true platform pose.
    pub fn read(&self, platform: &Pose2, rng: &mut Rng) -> Pose2 {
        let z = reading(&self.true_extrinsics, platform);
        Pose2::new(
            z.x + self.noise.position * rng.normal(),
            z.y + self.noise.position * rng.normal(),
            z.theta + self.noise.orientation * rng.normal(),
        )
    }

    /// Measurements at `qs`: true poses read by the microscope with noise from `seed`.
    pub fn measure(&self, qs: &[[f64; 3]], seed: u64) -> Result<Vec<PcrMeasurement>, PcrError> {
        let mut rng = Rng::new(seed);
        Ok(self
            .true_poses(qs)?
            .iter()
            .zip(qs)
            .map(|(eq, q)| PcrMeasurement {
                q: *q,
                z: self.read(&eq.pose, &mut rng),
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::pcr::measured_pose;

    #[test]
    fn truth_is_within_bounds_and_readings_carry_the_stated_noise() {
        let twin = PcrTwin::nominal(4).expect("twin");
        let nominal = twin.file.params();
        let u = twin.file.uncertainty.robot();
        let mut moved = 0;
        for k in 0..ROBOT_PARAMS {
            let d = (twin.true_params.get(k) - nominal.get(k)).abs();
            assert!(d <= TRUNCATION * u[k] + 1e-18, "parameter {k}");
            moved += usize::from(d > 0.0);
        }
        assert_eq!(moved, ROBOT_PARAMS);
        let q = [0.001, -0.0005, 0.002];
        let truth = twin.truth.fk(&q).expect("fk").pose;
        let mut rng = Rng::new(1);
        let n = 4000;
        let (mut sx, mut sxx, mut st) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let back = measured_pose(&twin.true_extrinsics, &twin.read(&truth, &mut rng));
            // In {W} the noise is rotated by stheta: the radial spread is what is fixed.
            let (dx, dy) = (back.x - truth.x, back.y - truth.y);
            sx += dx;
            sxx += dx * dx + dy * dy;
            st += (back.theta - truth.theta).powi(2);
        }
        let rms = (sxx / (2.0 * n as f64)).sqrt();
        assert!(
            (rms / twin.noise.position - 1.0).abs() < 0.05,
            "position noise {rms:e}"
        );
        assert!((sx / n as f64).abs() < 1e-9);
        let ang = (st / n as f64).sqrt();
        assert!(
            (ang / twin.noise.orientation - 1.0).abs() < 0.05,
            "angle noise {ang:e}"
        );
    }
}
