//! Candidate configurations for ball-centring: random starts driven by the nominal model onto
//! each ball centre (position IK), kept when inside the limits and accepted by a filter.

use nalgebra::Vector3;

use crate::model::Chain;
use crate::model::ik::reach_point;
use crate::util::Rng;

/// `per_ball` configurations per ball centre (in {W}) for which the nominal TCP (compliance
/// off) is on the centre, as (joint values in rad, 0-based ball). `sample` draws a random
/// start; `accept` vets a solution (e.g. away from the wrist singularity). Gives up on a ball
/// after `20 * per_ball` failed starts.
pub fn ball_pool(
    chain: &Chain,
    centres: &[Vector3<f64>],
    per_ball: usize,
    seed: u64,
    sample: impl Fn(&mut Rng) -> Vec<f64>,
    accept: impl Fn(&[f64]) -> bool,
) -> Vec<(Vec<f64>, usize)> {
    let mut rng = Rng::new(seed);
    let mut out = Vec::new();
    for (b, c) in centres.iter().enumerate() {
        let (mut got, mut tries) = (0, 0);
        while got < per_ball && tries < 20 * per_ball.max(1) {
            tries += 1;
            let q0 = sample(&mut rng);
            let Some(q) = reach_point(&q0, c, |q| chain.tcp(q, None).p) else {
                continue;
            };
            if chain.limit_violation(&q).is_none() && accept(&q) {
                out.push((q, b));
                got += 1;
            }
        }
    }
    out
}
