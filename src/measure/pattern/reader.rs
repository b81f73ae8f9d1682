//! Poses from a stream of camera frames of one pattern (what a microscope device computes):
//! the phase fit, then a continuous [`Track`] for the periodic pattern or the absolute
//! decode for the encoded one. The encoded pattern's missing dots bias the phase planes by
//! a deterministic 0.03-0.13 period; the reader removes it by simulation: it renders the
//! pattern (noiseless) at its estimate, measures that image the same way, and subtracts the
//! difference, iterating to a fixed point (the bias is a smooth function of the pose).

use super::{
    GrayImage, PatternError, PatternKind, PatternPose, PhaseEstimator, RenderSpec, Track,
    decode_absolute, render,
};

/// Largest number of bias-correction passes.
const PASSES: usize = 4;
/// The passes stop once the correction moves the pose by less than this (periods).
const SETTLED_PERIODS: f64 = 1e-5;

/// The pattern a microscope camera looks at and the camera's scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatternSetup {
    /// Periodic or encoded.
    pub kind: PatternKind,
    /// Period of the pattern (um).
    pub period_um: f64,
    /// Pixel size in the object plane (um).
    pub pixel_um: f64,
}

/// Reads poses (um, rad) from successive frames; the estimator is planned for the first
/// frame's size and re-planned when the size changes.
#[derive(Debug)]
pub struct PoseReader {
    setup: PatternSetup,
    /// The estimator and the frame size it is planned for.
    est: Option<((usize, usize), PhaseEstimator)>,
    track: Track,
}

impl PoseReader {
    /// A reader for `setup`.
    pub fn new(setup: PatternSetup) -> Result<Self, PatternError> {
        if !(setup.period_um > 0.0 && setup.pixel_um > 0.0)
            || !(setup.period_um.is_finite() && setup.pixel_um.is_finite())
        {
            return Err(PatternError::Setup(format!(
                "period_um = {} and pixel_um = {} must be positive",
                setup.period_um, setup.pixel_um
            )));
        }
        Ok(Self {
            setup,
            est: None,
            track: Track::new(),
        })
    }

    /// The pose of the pattern in `img` (x, y in um in the camera frame, theta in rad).
    pub fn read(&mut self, img: &GrayImage) -> Result<PatternPose, PatternError> {
        let s = self.setup;
        let period_px = s.period_um / s.pixel_um;
        let size = (img.width, img.height);
        let est = match &mut self.est {
            Some((at, e)) if *at == size => e,
            slot => {
                let e = PhaseEstimator::new(img.width, img.height, period_px)?;
                &mut slot.insert((size, e)).1
            }
        };
        let fit = est.fit(img)?;
        match s.kind {
            PatternKind::Periodic => Ok(self.track.push(fit.pose(s.period_um), s.period_um)),
            PatternKind::Encoded => {
                let first = decode_absolute(img, &fit, s.period_um)?;
                unbias(est, img, s, first)
            }
        }
    }
}

/// The encoded pose with the code's bias removed: `p` such that measuring a noiseless
/// rendering at `p` gives what the image gave.
fn unbias(
    est: &mut PhaseEstimator,
    img: &GrayImage,
    s: PatternSetup,
    measured: PatternPose,
) -> Result<PatternPose, PatternError> {
    let mut p = measured;
    for _ in 0..PASSES {
        let synth = render(&RenderSpec {
            kind: PatternKind::Encoded,
            pose: p,
            period_um: s.period_um,
            pixel_um: s.pixel_um,
            width: img.width,
            height: img.height,
            bit_depth: 16,
            noise_frac: 0.0,
            seed: 0,
        })?;
        let fit = est.fit(&synth)?;
        let seen = decode_absolute(&synth, &fit, s.period_um)?;
        let next = PatternPose {
            x: measured.x - (seen.x - p.x),
            y: measured.y - (seen.y - p.y),
            theta_rad: measured.theta_rad - (seen.theta_rad - p.theta_rad),
        };
        let moved = (next.x - p.x).hypot(next.y - p.y) / s.period_um;
        p = next;
        if moved < SETTLED_PERIODS {
            break;
        }
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(kind: PatternKind, pose: PatternPose, seed: u64) -> GrayImage {
        render(&RenderSpec {
            kind,
            pose,
            period_um: 10.0,
            pixel_um: 1.25,
            width: 1024,
            height: 1024,
            bit_depth: 16,
            noise_frac: 0.01,
            seed,
        })
        .expect("render")
    }

    #[test]
    fn encoded_frames_give_the_absolute_pose_without_the_code_bias() {
        let setup = PatternSetup {
            kind: PatternKind::Encoded,
            period_um: 10.0,
            pixel_um: 1.25,
        };
        let mut r = PoseReader::new(setup).expect("reader");
        let mut worst = (0.0f64, 0.0f64, 0.0f64);
        for (k, truth) in [
            (1234.567, -876.543, 0.0123),
            (-2500.02, 1500.7, -0.0031),
            (0.3, 0.2, 0.0),
            (4321.0, 3210.9, 0.02),
        ]
        .into_iter()
        .enumerate()
        {
            let truth = PatternPose {
                x: truth.0,
                y: truth.1,
                theta_rad: truth.2,
            };
            let img = frame(PatternKind::Encoded, truth, 40 + k as u64);
            // Without the correction: the code's bias, a fraction of a period.
            let mut est = PhaseEstimator::new(1024, 1024, 8.0).expect("estimator");
            let raw = decode_absolute(&img, &est.fit(&img).expect("fit"), 10.0).expect("decode");
            let t0 = std::time::Instant::now();
            let p = r.read(&img).expect("pose");
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let e = (p.x - truth.x).hypot(p.y - truth.y);
            eprintln!(
                "{truth:?}: raw ({:.4}, {:.4}) um {:.2e} rad, corrected ({:.2e}, {:.2e}) um {:.2e} rad, {ms:.0} ms",
                raw.x - truth.x,
                raw.y - truth.y,
                raw.theta_rad - truth.theta_rad,
                p.x - truth.x,
                p.y - truth.y,
                p.theta_rad - truth.theta_rad
            );
            worst.0 = worst.0.max((raw.x - truth.x).hypot(raw.y - truth.y));
            worst.1 = worst.1.max(e);
            worst.2 = worst.2.max((p.theta_rad - truth.theta_rad).abs());
        }
        eprintln!(
            "encoded 1024 px, 1.25 um/px, period 10 um, 1 % noise: raw decode {:.3} um, corrected {:.2e} um, theta {:.2e} rad",
            worst.0, worst.1, worst.2
        );
        // Left: the angle's noise (about 1 urad at 1024 px) times the lever arm from the
        // image centre to the pattern's origin (up to 5 mm here).
        assert!(
            worst.0 > 0.01,
            "the code's bias is there to remove: {} um",
            worst.0
        );
        assert!(worst.1 < 0.01, "corrected position error {} um", worst.1);
        assert!(worst.2 < 3e-6, "theta error {} rad", worst.2);
    }

    #[test]
    fn periodic_frames_are_tracked_and_bad_setups_refused() {
        let setup = PatternSetup {
            kind: PatternKind::Periodic,
            period_um: 10.0,
            pixel_um: 1.25,
        };
        let mut r = PoseReader::new(setup).expect("reader");
        let truths = [(1.0, 2.0), (4.5, -1.0), (8.9, -4.2)];
        let first = r
            .read(&frame(
                PatternKind::Periodic,
                PatternPose {
                    x: 1.0,
                    y: 2.0,
                    theta_rad: 0.0,
                },
                1,
            ))
            .expect("first");
        for (k, &(x, y)) in truths.iter().enumerate().skip(1) {
            let p = r
                .read(&frame(
                    PatternKind::Periodic,
                    PatternPose {
                        x,
                        y,
                        theta_rad: 0.0,
                    },
                    2 + k as u64,
                ))
                .expect("pose");
            // Steps below half a period: the track follows the truth's steps.
            assert!((p.x - first.x - (x - 1.0)).abs() < 1e-3, "{p:?}");
            assert!((p.y - first.y - (y - 2.0)).abs() < 1e-3, "{p:?}");
        }
        let bad = PoseReader::new(PatternSetup {
            pixel_um: 0.0,
            ..setup
        })
        .unwrap_err();
        assert!(bad.to_string().contains("pixel_um"), "{bad}");
    }
}
