//! Posture design on a planar 3R arm whose tip is measured: O1 against the independent
//! SVD-based indices, worstIndex against brute force, and the optimisers improving O1 over
//! random postures while staying feasible.

use nalgebra::DMatrix;

use super::*;
use crate::design::ocp::*;
use crate::design::{DetmaxOptions, Pool, detmax};
use crate::util::{NoMonitor, Rng};

/// Planar 3R arm (lengths 0.5, 0.4, 0.3 m); parameters: three lengths and three joint
/// offsets; measurement: tip (x, y). Feasible: tip above y = -0.3.
struct Planar;

impl Planar {
    fn tip(q: &[f64], l: [f64; 3]) -> [f64; 2] {
        let (mut x, mut y, mut a) = (0.0, 0.0, 0.0);
        for k in 0..3 {
            a += q[k];
            x += l[k] * a.cos();
            y += l[k] * a.sin();
        }
        [x, y]
    }
}

impl PostureModel for Planar {
    fn dof(&self) -> usize {
        3
    }
    fn limits(&self) -> Vec<[f64; 2]> {
        vec![[-2.5, 2.5]; 3]
    }
    fn block(&self, q: &[f64]) -> DMatrix<f64> {
        let l = [0.5, 0.4, 0.3];
        let mut b = DMatrix::zeros(2, 6);
        let mut a = 0.0;
        let mut angles = [0.0; 3];
        for k in 0..3 {
            a += q[k];
            angles[k] = a;
            b[(0, k)] = a.cos();
            b[(1, k)] = a.sin();
        }
        // Offset k turns every link from k on.
        for k in 0..3 {
            for j in k..3 {
                b[(0, 3 + k)] -= l[j] * angles[j].sin();
                b[(1, 3 + k)] += l[j] * angles[j].cos();
            }
        }
        b
    }
    fn feasible(&self, q: &[f64]) -> bool {
        q.iter().all(|v| v.abs() <= 2.5) && Planar::tip(q, [0.5, 0.4, 0.3])[1] > -0.3
    }
}

fn random_set(n: usize, seed: u64) -> PostureSet {
    let mut rng = Rng::new(seed);
    let qs = (0..n)
        .map(|_| random_feasible(&Planar, &mut rng, 1000).unwrap())
        .collect();
    PostureSet::from_postures(&Planar, qs)
}

#[test]
fn block_is_the_derivative_of_the_tip() {
    let q = [0.3, -0.7, 1.1];
    let b = Planar.block(&q);
    let h = 1e-7;
    for k in 0..3 {
        let mut l = [0.5, 0.4, 0.3];
        l[k] += h;
        let a = Planar::tip(&q, l);
        let c = Planar::tip(&q, [0.5, 0.4, 0.3]);
        assert!(((a[0] - c[0]) / h - b[(0, k)]).abs() < 1e-6);
        let mut qq = q;
        qq[k] += h;
        let a = Planar::tip(&qq, [0.5, 0.4, 0.3]);
        assert!(((a[1] - c[1]) / h - b[(1, 3 + k)]).abs() < 1e-6);
    }
}

#[test]
fn o1_and_worst_index_match_the_svd_indices() {
    let set = random_set(8, 1);
    // Independent: the singular values of the stacked Jacobian.
    let sv = set.stacked().singular_values();
    let direct = (sv.iter().map(|v| v.ln()).sum::<f64>() / 6.0).exp() / 8f64.sqrt();
    assert!(
        (set.o1() - direct).abs() < 1e-10 * direct,
        "{} vs {direct}",
        set.o1()
    );
    let w = worst_index(&set).unwrap();
    let o1_without = |i: usize| {
        let rest: Vec<Vec<f64>> = (0..set.len())
            .filter(|&k| k != i)
            .map(|k| set.postures[k].clone())
            .collect();
        let sv = PostureSet::from_postures(&Planar, rest)
            .stacked()
            .singular_values();
        (sv.iter().map(|v| v.ln()).sum::<f64>() / 6.0).exp() / 7f64.sqrt()
    };
    let best = (0..set.len())
        .map(o1_without)
        .fold(f64::NEG_INFINITY, f64::max);
    assert!((o1_without(w) - best).abs() < 1e-12);
    // Fewer postures than needed: O1 is zero (not all parameters observable).
    assert_eq!(random_set(2, 1).o1(), 0.0);
}

#[test]
fn partial_optim_and_cocp_raise_o1_and_stay_feasible() {
    let mut set = random_set(6, 3);
    let start = set.o1();
    let gain = partial_optim(&Planar, &mut set, &[0, 1], &OptimOptions::default());
    assert!(gain > 0.0 && (set.o1() - start - gain).abs() < 1e-12);
    let before = set.o1();
    let rep = cocp(&Planar, &mut set, &OptimOptions::default(), 50, &NoMonitor).unwrap();
    assert!(rep.o1 >= before && rep.iterations >= 1, "{rep:?}");
    // The history: the start, one O1 per re-optimised posture, never falling, ending at o1.
    assert_eq!(rep.history.len(), rep.iterations + 1);
    assert_eq!(
        (rep.history[0], rep.history[rep.iterations]),
        (before, rep.o1)
    );
    assert!(
        rep.history.windows(2).all(|w| w[1] >= w[0] * (1.0 - 1e-12)),
        "{rep:?}"
    );
    assert!(set.postures.iter().all(|q| Planar.feasible(q)));
    // The information matrix kept by updates equals a fresh one.
    let fresh = PostureSet::from_postures(&Planar, set.postures.clone());
    assert!((fresh.o1() - set.o1()).abs() < 1e-9);
}

#[test]
fn nocp_stops_on_the_plateau_and_beats_random_and_detmax() {
    let opts = NocpOptions {
        block: 2,
        epsilon: 0.02,
        max_postures: 40,
        seed: 5,
        ..Default::default()
    };
    let r = nocp(&Planar, &opts, &NoMonitor).unwrap();
    assert!(r.plateau, "{:?}", r.history);
    let n = r.set.len();
    assert!((4..40).contains(&n), "{n}");
    let last = r.history.last().unwrap().o1;
    assert!((last - r.set.o1()).abs() < opts.epsilon * r.set.o1());
    assert!(r.set.postures.iter().all(|q| Planar.feasible(q)));
    // Optimised postures beat random ones of the same number, and DETMAX over a random
    // feasible pool of 300.
    let random: f64 = (0..10).map(|s| random_set(n, 100 + s).o1()).sum::<f64>() / 10.0;
    assert!(
        r.set.o1() > 1.1 * random,
        "{} vs random {random}",
        r.set.o1()
    );
    let pool = random_set(300, 9);
    let blocks: Vec<DMatrix<f64>> = pool.postures.iter().map(|q| Planar.block(q)).collect();
    let sel = detmax(
        &Pool::from_blocks(&blocks),
        &DetmaxOptions {
            n,
            seed: 1,
            max_excursion: 4,
            path: true,
        },
        &NoMonitor,
    )
    .unwrap();
    let chosen: Vec<Vec<f64>> = sel
        .selected
        .iter()
        .map(|&i| pool.postures[i].clone())
        .collect();
    let d = o1_of_postures(&Planar, &chosen);
    assert!(r.set.o1() > d, "nocp {} vs detmax {d}", r.set.o1());
}
