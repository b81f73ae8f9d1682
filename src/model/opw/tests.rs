use super::*;
use crate::model::dh::DhFile;
use crate::util::Rng;

fn irb120() -> Chain {
    DhFile::parse(crate::twin::serial::IRB120_JSON)
        .expect("irb120 parses")
        .to_chain()
        .expect("irb120 builds")
}

fn random_q(rng: &mut Rng) -> [f64; 6] {
    let lim = [165.0, 110.0, 70.0, 160.0, 120.0, 400.0];
    let mut q = [0.0; 6];
    for k in 0..6 {
        q[k] = rng.range(-lim[k], lim[k]).to_radians();
    }
    q
}

fn angle_diff(a: f64, b: f64) -> f64 {
    wrap(a - b).abs()
}

#[test]
fn every_solution_reaches_the_target_and_one_is_the_generating_joints() {
    let c = irb120();
    let o = Opw::of(&c, 1e-9).expect("the IRB 120 is an OPW arm");
    let mut rng = Rng::new(3);
    for _ in 0..500 {
        let q = random_q(&mut rng);
        let t = c.tcp(&q, None);
        let sols = o.solve(&t, q[3]);
        assert!(!sols.is_empty(), "no solution for {q:?}");
        let mut found = false;
        for s in &sols {
            let f = c.tcp(s, None);
            assert!((f.p - t.p).norm() < 1e-8, "{s:?}: {:?} vs {:?}", f.p, t.p);
            assert!(
                crate::model::compensate::rotation_vector(&(f.r * t.r.transpose())).norm() < 1e-9
            );
            if (0..6).all(|k| angle_diff(s[k], q[k]) < 1e-7) {
                found = true;
            }
        }
        assert!(found, "the generating joints {q:?} are not among {sols:?}");
    }
}

#[test]
fn a_target_beyond_reach_has_no_solution() {
    let c = irb120();
    let o = Opw::of(&c, 1e-9).unwrap();
    let mut t = c.tcp(&[0.0; 6], None);
    t.p.x += 2000.0;
    assert!(o.solve(&t, 0.0).is_empty());
}

#[test]
fn an_arm_without_a_spherical_wrist_is_refused_naming_the_offset() {
    let mut f = DhFile::parse(crate::twin::serial::IRB120_JSON).unwrap();
    f.joints[4].a = 40.0;
    let e = Opw::of(&f.to_chain().unwrap(), 1.0).unwrap_err();
    assert!(e.to_string().contains("a4 = 40"), "{e}");
}

#[test]
fn nearest_turn_prefers_the_reference_within_limits() {
    let pi = PI;
    // q6 range of +-400 deg: 170 deg near a reference of -200 deg is -190 deg.
    let l = Some([-400f64.to_radians(), 400f64.to_radians()]);
    let v = nearest_turn(170f64.to_radians(), -200f64.to_radians(), l);
    assert!((v - (-190f64).to_radians()).abs() < 1e-12);
    // Nearest turn out of the limits: the one inside is taken.
    let l = Some([-pi / 2.0, pi / 2.0]);
    assert!((nearest_turn(0.3, 2.0 * pi, l) - 0.3).abs() < 1e-12);
}
