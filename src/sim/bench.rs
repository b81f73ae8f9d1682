//! The operator's hands on the simulated centring device: its kinematic coupling platform
//! and the indicators' set buttons, for rehearsing `cell.zero_check` against the twins.
//!
//! Each indicator shows `zero_mm + p - p_set`: `p` is its plunger's position from
//! mid-travel (the device's tool centre on a ball centre puts every plunger there), `p_set`
//! the position at which its set button was last pressed (pressing it presets the display
//! to the lab file's `zero_mm`). The indicators start set at mid-travel. Mated on its
//! coupling, the device's stems rest on the coupling's master ball, whose centre is off
//! the tool centre by a manufacturing offset (tens of micrometres, drawn from the seed) plus
//! a sub-micrometre repeatability per mating: so until the set buttons are pressed on the
//! coupling, the zero check sees the offset; after, the coupling defines the zero.

use std::sync::{Arc, Mutex};

use crate::util::Rng;

/// Standard deviation of the coupling master's offset from the tool centre (mm, per axis).
pub const COUPLING_OFFSET_STD_MM: f64 = 0.03;
/// Standard deviation of the coupling's repeatability between matings (mm, per axis).
pub const COUPLING_REPEATABILITY_MM: f64 = 0.0003;

/// The master ball's centre from the tool centre along the tool axes (mm) for `seed`.
pub fn coupling_offset_mm(seed: u64) -> [f64; 3] {
    let mut rng = Rng::new(seed ^ 0xc0_0b1e);
    std::array::from_fn(|_| COUPLING_OFFSET_STD_MM * rng.normal())
}

/// State of the device on the bench.
#[derive(Debug, Clone, PartialEq)]
pub struct Bench {
    seed: u64,
    /// Where the master ball sits on the coupling (tool axes, mm).
    coupling_mm: [f64; 3],
    /// The ball centre from the tool centre while mated (None: on the robot's flange).
    mated_mm: Option<[f64; 3]>,
    matings: u64,
    /// Plunger positions (mm from mid-travel) at the last press of each set button.
    set_at_mm: [f64; 3],
}

/// A bench shared by the indicators' mock and the mock lab's operator commands.
pub type BenchHandle = Arc<Mutex<Bench>>;

impl Bench {
    /// The device on the flange, indicators set at mid-travel, coupling drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            coupling_mm: coupling_offset_mm(seed),
            mated_mm: None,
            matings: 0,
            set_at_mm: [0.0; 3],
        }
    }

    /// Mate the device on its coupling platform (its stems on the master ball).
    pub fn mate(&mut self) {
        self.matings += 1;
        let mut rng = Rng::new(self.seed ^ self.matings.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let c = self.coupling_mm;
        self.mated_mm = Some(std::array::from_fn(|k| {
            c[k] + COUPLING_REPEATABILITY_MM * rng.normal()
        }));
    }

    /// Take the device off the coupling, back on the robot's flange.
    pub fn unmate(&mut self) {
        self.mated_mm = None;
    }

    /// The ball centre from the tool centre along the tool axes while mated.
    pub fn mated(&self) -> Option<[f64; 3]> {
        self.mated_mm
    }

    /// Press the set button of every indicator, whose plungers stand at `plunger_mm`.
    pub fn set(&mut self, plunger_mm: [f64; 3]) {
        self.set_at_mm = plunger_mm;
    }

    /// What indicator `k` displays with its plunger at `plunger_mm`, preset `zero_mm`
    /// (0.001 mm resolution).
    pub fn display_mm(&self, k: usize, plunger_mm: f64, zero_mm: f64) -> f64 {
        let v = zero_mm + plunger_mm - self.set_at_mm[k];
        (v * 1000.0).round() / 1000.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_set_button_on_the_coupling_moves_the_zero_to_the_master_ball() {
        let mut b = Bench::new(11);
        let c = coupling_offset_mm(11);
        // On the flange, a plunger at mid-travel shows the preset.
        assert_eq!(b.display_mm(0, 0.0, 6.35), 6.35);
        b.mate();
        let m = b.mated().expect("mated");
        for k in 0..3 {
            assert!((m[k] - c[k]).abs() < 5.0 * COUPLING_REPEATABILITY_MM);
            // Before the set: the master's offset shows.
            let shown = b.display_mm(k, m[k], 6.35) - 6.35;
            assert!((shown - c[k]).abs() < 0.002, "{shown} vs {}", c[k]);
        }
        b.set(m);
        for k in 0..3 {
            assert_eq!(b.display_mm(k, m[k], 6.35), 6.35);
        }
        // Mated again: the same zero within the repeatability.
        b.unmate();
        assert!(b.mated().is_none());
        b.mate();
        let m2 = b.mated().expect("mated");
        for k in 0..3 {
            assert!((b.display_mm(k, m2[k], 6.35) - 6.35).abs() <= 0.002);
        }
    }
}
