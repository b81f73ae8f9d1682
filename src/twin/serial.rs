//! Twin of the IRB 120 ball-centring cell: true parameters, a three-ball plate, centring
//! configurations found on the true robot (TCP within epsilon of a ball centre), and a
//! laser tracker for validation.

use nalgebra::Vector3;

use crate::measure::{BallPlate, PointMeasurement, Target};
use crate::model::dh::DhFile;
use crate::model::{Chain, ParamId, Quantity};
use crate::util::Rng;

/// The IRB 120 model file shipped with calibd (copied from `../shared/data/robots`).
pub const IRB120_JSON: &str = include_str!("../../tests/data/robots/irb120.json");

/// Why a twin cannot be built around a lab's nominal.
#[derive(Debug, thiserror::Error)]
pub enum TwinError {
    /// The model file does not build a chain.
    #[error("model: {0}")]
    Model(#[from] crate::model::ModelError),
    /// The ballbar distances do not make a plate.
    #[error("ballbar: {0}")]
    Plate(#[from] crate::measure::MeasureError),
}

/// The cell: nominal and true models, ball plate, sensor noise.
#[derive(Debug, Clone)]
pub struct SerialTwin {
    /// The model file the identification starts from.
    pub file: DhFile,
    /// Nominal chain.
    pub nominal: Chain,
    /// True chain (what the robot really is).
    pub truth: Chain,
    /// Ballbar distances d12, d13, d23 (mm).
    pub ballbar: [f64; 3],
    /// The plate they define.
    pub plate: BallPlate,
    /// Centring loop tolerance: the TCP stops within this distance of the ball centre (mm).
    pub centring_epsilon_mm: f64,
    /// Laser tracker noise, standard deviation per coordinate (mm).
    pub tracker_noise_mm: f64,
}

/// Deterministic true errors: lengths ~0.3 mm, angles ~0.05 deg, base ~1 mm / 0.1 deg, and
/// compliances of a small arm (deg/(N*m)).
fn perturb(nominal: &Chain, names: &[String], seed: u64) -> Chain {
    let mut rng = Rng::new(seed);
    let mut t = nominal.clone();
    for name in names {
        let Ok(id) = t.param_by_name(name) else {
            continue;
        };
        let v = t.param(id);
        let dv = match (id, id.quantity()) {
            (ParamId::Base(_), Quantity::Length) => 1.0 * rng.normal(),
            (ParamId::Base(_), _) => 0.1f64.to_radians() * rng.normal(),
            (_, Quantity::Length) => 0.3 * rng.normal(),
            (_, Quantity::Angle) => 0.05f64.to_radians() * rng.normal(),
            (_, Quantity::Compliance) => (0.002 + 0.002 * rng.uniform()).to_radians(),
            _ => 0.0,
        };
        t.set_param(id, v + dv);
    }
    t
}

impl SerialTwin {
    /// The IRB 120 cell with true errors drawn from `seed`.
    pub fn irb120(seed: u64) -> Self {
        let file = DhFile::parse(IRB120_JSON).expect("the embedded IRB 120 file is valid");
        Self::around(file, [200.012, 199.987, 200.003], seed)
            .expect("the embedded IRB 120 file and ballbar build")
    }

    /// A cell whose nominal is `file` (a lab's model file) and whose plate has the ballbar
    /// distances `ballbar` (mm): the true robot is drawn around the nominal from `seed`
    /// (every parameter the file identifies), as `calibd mock lab` serves a lab file.
    pub fn around(file: DhFile, ballbar: [f64; 3], seed: u64) -> Result<Self, TwinError> {
        let nominal = file.to_chain()?;
        let truth = perturb(&nominal, &file.identify, seed);
        let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])?;
        Ok(Self {
            file,
            nominal,
            truth,
            ballbar,
            plate,
            centring_epsilon_mm: 0.010,
            tracker_noise_mm: 0.010,
        })
    }

    /// Where the true TCP is at joint values `q` (rad), with the true static deflection.
    pub fn true_tcp(&self, q: &[f64]) -> Vector3<f64> {
        let tau = self.truth.static_torques(q);
        self.truth.tcp(q, Some(&tau)).p
    }

    /// Joint values near `q0` that put the true TCP at `target` (position-only damped least
    /// squares), or `None` if it does not converge within the limits away from the wrist
    /// singularity.
    pub fn reach(&self, q0: &[f64], target: &Vector3<f64>) -> Option<Vec<f64>> {
        let q = crate::model::ik::reach_point(q0, target, |q| self.true_tcp(q))?;
        let lim = self.truth.limit_violation(&q).is_none();
        (lim && q[4].abs() > 10f64.to_radians()).then_some(q)
    }

    /// A random joint vector in the central part of the workspace (rad).
    pub fn random_q(&self, rng: &mut Rng) -> Vec<f64> {
        let deg = |lo: f64, hi: f64, rng: &mut Rng| rng.range(lo, hi).to_radians();
        vec![
            deg(-60.0, 100.0, rng),
            deg(-30.0, 60.0, rng),
            deg(-60.0, 40.0, rng),
            deg(-150.0, 150.0, rng),
            deg(-110.0, 110.0, rng),
            deg(-300.0, 300.0, rng),
        ]
    }

    /// `per_ball` centring measurements on each ball: a random start, the robot driven onto
    /// the ball (true model) and stopped within epsilon of its centre, joints recorded.
    pub fn centring(&self, per_ball: usize, seed: u64) -> Vec<PointMeasurement> {
        let mut rng = Rng::new(seed);
        let mut out = Vec::new();
        for b in 0..self.plate.len() {
            let centre = self.plate.centres[b].unwrap_or_else(Vector3::zeros);
            let mut got = 0;
            while got < per_ball {
                let q0 = self.random_q(&mut rng);
                let e = Vector3::from(rng.in_ball(self.centring_epsilon_mm));
                if let Some(q) = self.reach(&q0, &(centre + e)) {
                    out.push(PointMeasurement {
                        q,
                        target: Target::Ball(b),
                    });
                    got += 1;
                }
            }
        }
        out
    }

    /// `n` laser-tracker validation measurements at random configurations: the true TCP plus
    /// Gaussian noise of `tracker_noise_mm` per coordinate.
    pub fn tracker(&self, n: usize, seed: u64) -> Vec<PointMeasurement> {
        let mut rng = Rng::new(seed);
        (0..n)
            .map(|_| {
                let q = self.random_q(&mut rng);
                let noise =
                    Vector3::new(rng.normal(), rng.normal(), rng.normal()) * self.tracker_noise_mm;
                PointMeasurement {
                    target: Target::Point(self.true_tcp(&q) + noise),
                    q,
                }
            })
            .collect()
    }
}
