use super::*;
use crate::util::NoMonitor;

/// The data see x0 + x1 and x2 only: x0 - x1 is free. Scales 1 and 3.
struct Sum;
impl Problem for Sum {
    fn residual_count(&self) -> usize {
        3
    }
    fn unknown_count(&self) -> usize {
        3
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        r[0] = x[0] + x[1] - 4.0;
        r[1] = 2.0 * (x[0] + x[1]) - 8.0;
        r[2] = x[2] - 1.0;
        Ok(())
    }
}

fn unknown(name: &str, range: f64) -> Unknown {
    Unknown {
        name: name.into(),
        unit: "mm".into(),
        to_report: 1.0,
        nominal: 0.0,
        plausible_range: range,
        lower: None,
        upper: None,
    }
}

/// The free fit ends somewhere on the line x0 + x1 = 4; held, it ends at the point closest
/// to the start in scaled units: minimise x0^2 + (x1 / 3)^2 on it, x0 = 0.4, x1 = 3.6.
#[test]
fn the_held_orbit_point_is_the_closest_to_the_start_and_costs_nothing() {
    let unknowns = [unknown("a", 1.0), unknown("b", 3.0), unknown("c", 1.0)];
    let x0 = [0.0, 0.0, 0.0];
    let mut free =
        solve(&Sum, &unknowns, &x0, &SolveOptions::default(), &NoMonitor).expect("free fit");
    // Somewhere else on the solution line, as a wandering fit would leave it.
    free.x = vec![7.0, -3.0, 1.0];
    let map = |x: &[f64], t: f64| vec![x[0] + t, x[1] - t, x[2]];
    let orbit = Orbit {
        freedom: "a - b".into(),
        map: &map,
        half_range: 20.0,
        unit: ("mm", 1.0),
    };
    let (sol, held) = hold_orbit(
        &Sum,
        &unknowns,
        &x0,
        &free,
        &orbit,
        &SolveOptions::default(),
        &NoMonitor,
    )
    .expect("held fit");
    assert!(
        (sol.x[0] - 0.4).abs() < 1e-6 && (sol.x[1] - 3.6).abs() < 1e-6,
        "{:?}",
        sol.x
    );
    assert!((held.moved + 6.6).abs() < 1e-6, "{}", held.moved);
    assert!(held.cost_change.abs() < 1e-12);
    assert_eq!(sol.residuals.len(), 3);
    // Both unknowns are identified, with finite std.
    assert_eq!(sol.free.len(), 3);
    assert!(sol.params.iter().all(|p| p.std.is_some_and(f64::is_finite)));
}
