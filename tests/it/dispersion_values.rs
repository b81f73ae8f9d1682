//! The values-only identification of a dispersion study (issue 17, item 2) equals the full
//! one: DETMAX sets of the IRB 120 twin (seeded), identified by
//! `IdentifyInputs::identify_values` (no standard deviations, no near-dependent reports,
//! spectra skipped where a certificate shows nothing is held, the nuisance-only fit through
//! its cheap form) and by `IdentifyInputs::identify` (the straightforward pipeline, every
//! spectrum computed): the same values to 1e-9 relative, the same free set and status.

use calibd::design::{DetmaxOptions, detmax};
use calibd::jobs::serial::design::DesignPool;
use calibd::util::NoMonitor;

#[test]
fn values_only_identification_equals_the_full_one() {
    let inputs = calibd::bench::serial::dispersion_inputs().expect("twin inputs are valid");
    let pool = DesignPool::new(&inputs).expect("pool builds");
    let mut worst = 0.0_f64;
    for (n, seed) in [(20, 3), (45, 4), (100, 5)] {
        let set = detmax(
            &pool.pool,
            &DetmaxOptions {
                n,
                seed,
                max_excursion: 4,
                path: false,
            },
            &NoMonitor,
        )
        .expect("not cancelled")
        .selected;
        let (_, fast) = inputs
            .identify_values(Some(&set), &NoMonitor)
            .expect("values only");
        let (_, full) = inputs.identify(Some(&set), &NoMonitor).expect("full");
        assert_eq!(fast.status(), full.status(), "n = {n}");
        assert!(full.converged(), "n = {n}");
        assert_eq!(fast.free, full.free, "n = {n}");
        assert_eq!(fast.iterations, full.iterations, "n = {n}");
        for (a, b) in fast.params.iter().zip(&full.params) {
            let rel = (a.value - b.value).abs() / a.value.abs().max(b.value.abs()).max(1e-300);
            worst = worst.max(rel);
            assert!(
                rel <= 1e-9,
                "n = {n} {}: {} vs {}",
                a.name,
                a.value,
                b.value
            );
            assert!(a.std.is_none() && b.std.is_some(), "{}", a.name);
        }
        // The nuisance-only fit (frames alone) went through the cheap form: the same cost.
        let (a, b) = (
            fast.nuisance_cost.expect("fitted"),
            full.nuisance_cost.expect("fitted"),
        );
        assert!((a - b).abs() <= 1e-9 * b, "n = {n}: {a} vs {b}");
        assert!(a > fast.cost_after, "n = {n}: the frames alone fit worse");
        // The full pipeline reports the three least-determined combinations; the values
        // only path skipped those spectra (nothing was near the floor).
        assert_eq!(full.near_dependent.len(), 3, "n = {n}");
        assert!(fast.near_dependent.is_empty(), "n = {n}");
    }
    eprintln!("largest relative difference: {worst:.1e}");
}
