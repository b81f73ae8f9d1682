use super::*;

/// Render the cosine or dot pattern, period 10 px (10 um at 1 um/px).
fn image(kind: PatternKind, size: usize, pose: PatternPose, noise: f64, seed: u64) -> GrayImage {
    render(&RenderSpec {
        kind,
        pose,
        period_um: 10.0,
        pixel_um: 1.0,
        width: size,
        height: size,
        bit_depth: 16,
        noise_frac: noise,
        seed,
    })
    .expect("valid render spec")
}

fn pose(x: f64, y: f64, theta_rad: f64) -> PatternPose {
    PatternPose { x, y, theta_rad }
}

/// The error of `est` against `truth` modulo the lattice (in the pattern's axes).
fn lattice_error(est: PatternPose, truth: PatternPose, period: f64) -> [f64; 2] {
    let (s, c) = truth.theta_rad.sin_cos();
    let (dx, dy) = (est.x - truth.x, est.y - truth.y);
    [
        wrap_half(c * dx + s * dy, period / 2.0),
        wrap_half(-s * dx + c * dy, period / 2.0),
    ]
}

#[test]
fn the_code_is_a_maximum_length_sequence_with_unique_windows() {
    let s = code::sequence();
    assert_eq!(s.len(), code::LEN);
    let idx = code::window_index(&s);
    let found = idx.iter().filter(|&&i| i != u16::MAX).count();
    assert_eq!(
        found,
        code::LEN,
        "every non-zero 12-bit window occurs exactly once"
    );
    assert_eq!(idx[0], u16::MAX);
    assert_eq!(s.iter().filter(|&&b| b).count(), 2048);
}

#[test]
fn a_noiseless_pose_is_recovered_with_theta_in_the_quarter_turn_and_the_nearest_origin() {
    let mut est = PhaseEstimator::new(256, 256, 10.0).unwrap();
    // theta = 100 deg is theta = 10 deg for a square grid; the origin at (13, -4) um has
    // the lattice point (13, -4) - R(theta)(10, 0) nearer the centre.
    for (truth, theta_expect) in [
        (pose(1.3, -2.2, 0.2), 0.2),
        (pose(3.0, 4.0, 100f64.to_radians()), 10f64.to_radians()),
        (pose(-2.0, 1.0, -0.7), -0.7),
    ] {
        let img = image(PatternKind::Periodic, 256, truth, 0.0, 1);
        let fit = est.fit(&img).unwrap();
        let p = fit.pose(10.0);
        assert!(
            (p.theta_rad - theta_expect).abs() < 1e-5,
            "{p:?} vs {truth:?}"
        );
        let e = lattice_error(p, truth, 10.0);
        assert!(e[0].abs() < 1e-3 && e[1].abs() < 1e-3, "{e:?}");
        assert!(
            p.x.hypot(p.y) <= 10.0 / 2f64.sqrt() + 1e-9,
            "nearest origin: {p:?}"
        );
        assert!((fit.period_px() - 10.0).abs() < 1e-4);
        assert!((fit.contrast() - 0.5).abs() < 0.02, "{}", fit.contrast());
    }
}

#[test]
fn images_without_a_square_grid_are_refused_with_a_clear_error() {
    let mut est = PhaseEstimator::new(256, 256, 10.0).unwrap();
    let noise = GrayImage {
        width: 256,
        height: 256,
        full_scale: u16::MAX,
        pixels: {
            let mut r = crate::util::Rng::new(3);
            (0..256 * 256)
                .map(|_| (30000.0 + 3000.0 * r.normal()) as u16)
                .collect()
        },
    };
    let e = est.fit(&noise).unwrap_err();
    assert!(matches!(e, PatternError::NoPattern(_)), "{e}");
    assert!(e.to_string().contains("no periodic pattern"), "{e}");
    // Lines (one grating) only.
    let mut lines = noise.clone();
    for (k, p) in lines.pixels.iter_mut().enumerate() {
        let c = (k % 256) as f64;
        *p = (30000.0 + 20000.0 * (std::f64::consts::TAU * c / 10.0).cos()) as u16;
    }
    let e = est.fit(&lines).unwrap_err();
    assert!(e.to_string().contains("not a square grid"), "{e}");
    // Wrong size.
    let small = image(PatternKind::Periodic, 128, pose(0.0, 0.0, 0.0), 0.0, 1);
    assert!(matches!(est.fit(&small), Err(PatternError::Setup(_))));
}

/// The accuracy target of issue 33 at full size: 1024 x 1024, 16-bit, noise 1 % of full
/// scale, period 10 px; steps between images within 0.001 px RMS, theta within 2 urad.
#[test]
fn steps_and_angle_meet_the_accuracy_target_on_noisy_1024_images() {
    let mut est = PhaseEstimator::new(1024, 1024, 10.0).unwrap();
    let mut track = Track::new();
    let truths: Vec<PatternPose> = (0..8)
        .map(|k| {
            let k = k as f64;
            pose(0.37 + 1.713 * k, -0.21 + 0.931 * k, 0.05 + 1e-4 * k)
        })
        .collect();
    let mut est_poses = Vec::new();
    let (mut max_theta, mut sq, mut n) = (0.0f64, 0.0, 0);
    for (k, t) in truths.iter().enumerate() {
        let img = image(PatternKind::Periodic, 1024, *t, 0.01, 100 + k as u64);
        let fit = est.fit(&img).unwrap();
        let p = track.push(fit.pose(10.0), 10.0);
        max_theta = max_theta.max((p.theta_rad - t.theta_rad).abs());
        if let Some(prev) = est_poses.last().copied() {
            let prev: PatternPose = prev;
            let ex = (p.x - prev.x) - (t.x - truths[k - 1].x);
            let ey = (p.y - prev.y) - (t.y - truths[k - 1].y);
            sq += ex * ex + ey * ey;
            n += 2;
        }
        est_poses.push(p);
    }
    let rms = (sq / n as f64).sqrt();
    eprintln!(
        "1024 px, 1 % noise: step RMS {rms:.2e} px, max |theta error| {:.3} urad",
        max_theta * 1e6
    );
    assert!(rms < 1e-3, "step RMS {rms} px");
    assert!(max_theta < 2e-6, "theta error {max_theta} rad");
}

/// Bias against sub-pixel shift and rotation, noiseless: the largest position and angle
/// errors over shifts of 0..1 px along both axes and angles across the quarter turn.
#[test]
fn bias_against_subpixel_shift_and_rotation_is_small() {
    let mut est = PhaseEstimator::new(512, 512, 10.0).unwrap();
    let (mut max_pos, mut max_theta) = (0.0f64, 0.0f64);
    for a in [-0.7f64, -0.3, 0.0, 0.01, 0.2, 0.5, 0.78] {
        for k in 0..10 {
            let s = k as f64 / 10.0;
            let truth = pose(s, 0.7 * s, a);
            let fit = est
                .fit(&image(PatternKind::Periodic, 512, truth, 0.0, 1))
                .unwrap();
            let p = fit.pose(10.0);
            let e = lattice_error(p, truth, 10.0);
            max_pos = max_pos.max(e[0].hypot(e[1]));
            max_theta = max_theta
                .max(wrap_half(p.theta_rad - truth.theta_rad, std::f64::consts::FRAC_PI_4).abs());
        }
    }
    eprintln!(
        "bias (512 px, noiseless): position {max_pos:.2e} px, theta {:.3} urad",
        max_theta * 1e6
    );
    assert!(max_pos < 2e-4, "{max_pos}");
    assert!(max_theta < 1e-6, "{max_theta}");
}

/// The scatter of the position over noise draws, against the Cramer-Rao bound of the
/// phase of a sinusoid of amplitude A in white noise sigma over N pixels:
/// var(phi) = 2 sigma^2 / (N A^2), i.e. sd(x) = p/(2 pi) sqrt(2/N) sigma/A.
#[test]
fn position_scatter_is_within_a_small_factor_of_the_cramer_rao_bound() {
    let size = 512;
    let mut est = PhaseEstimator::new(size, size, 10.0).unwrap();
    let truth = pose(0.3, 0.1, 0.02);
    let xs: Vec<f64> = (0..12)
        .map(|k| {
            let fit = est
                .fit(&image(PatternKind::Periodic, size, truth, 0.01, 500 + k))
                .unwrap();
            lattice_error(fit.pose(10.0), truth, 10.0)[0]
        })
        .collect();
    let mean = xs.iter().sum::<f64>() / xs.len() as f64;
    let sd = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (xs.len() - 1) as f64).sqrt();
    // Amplitude after pixel averaging (sinc at k/2 = pi/10).
    let z = std::f64::consts::PI / 10.0;
    let a = 0.25 * z.sin() / z;
    let crb = 10.0 / std::f64::consts::TAU * (2.0 / (size * size) as f64).sqrt() * 0.01 / a;
    eprintln!(
        "position sd {sd:.2e} px, Cramer-Rao {crb:.2e} px, ratio {:.2}",
        sd / crb
    );
    assert!(sd < 3.0 * crb, "sd {sd} vs bound {crb}");
}

#[test]
fn a_track_is_continuous_over_many_periods_and_across_45_degrees() {
    let mut est = PhaseEstimator::new(256, 256, 10.0).unwrap();
    let mut track = Track::new();
    for k in 0..12 {
        let k = k as f64;
        let truth = pose(-20.0 + 3.7 * k, 2.9 * k, 0.70 + 0.02 * k);
        let p = track.push(
            est.fit(&image(PatternKind::Periodic, 256, truth, 0.0, 1))
                .unwrap()
                .pose(10.0),
            10.0,
        );
        if k == 0.0 {
            continue;
        }
        // The track moves with the truth: same offset as at the start.
        let e = lattice_error(p, truth, 10.0);
        assert!(e[0].abs() < 1e-3 && e[1].abs() < 1e-3, "{k}: {e:?}");
        assert!(
            (p.theta_rad - truth.theta_rad).abs() < 1e-5,
            "{k}: {p:?} vs {truth:?}"
        );
    }
}

#[test]
fn the_encoded_pattern_gives_the_absolute_position() {
    let mut est = PhaseEstimator::new(512, 512, 10.0).unwrap();
    for (truth, seed) in [
        (pose(12345.6, -8765.4, 0.15), 1),
        (pose(-30000.0 + 3.3, 21000.7, -0.6), 2),
        (pose(0.4, 0.2, 0.0), 3),
    ] {
        let img = image(PatternKind::Encoded, 512, truth, 0.01, seed);
        let fit = est.fit(&img).unwrap();
        let p = decode_absolute(&img, &fit, 10.0).unwrap();
        let (ex, ey) = (p.x - truth.x, p.y - truth.y);
        eprintln!(
            "encoded at {truth:?}: error ({ex:.2e}, {ey:.2e}) um, theta {:.2e} rad",
            p.theta_rad - truth.theta_rad
        );
        // The missing dots perturb the phase planes (a fixed pattern, not noise): measured
        // 0.03 and 0.13 period at the first two poses; this checks the decoded index (a
        // wrong one is at least a period, 10 um, off), not sub-period accuracy.
        assert!(ex.hypot(ey) < 3.0, "{p:?} vs {truth:?}");
        assert!((p.theta_rad - truth.theta_rad).abs() < 1e-4);
    }
}

#[test]
fn a_periodic_image_does_not_decode_as_encoded() {
    let mut est = PhaseEstimator::new(512, 512, 10.0).unwrap();
    let img = image(PatternKind::Periodic, 512, pose(1.0, 2.0, 0.1), 0.01, 1);
    let fit = est.fit(&img).unwrap();
    let e = decode_absolute(&img, &fit, 10.0).unwrap_err();
    assert!(matches!(e, PatternError::Code(_)), "{e}");
}

#[test]
fn png_and_tiff_round_trip_8_and_16_bit_and_bad_files_are_named() {
    for depth in [8, 16] {
        let img = render(&RenderSpec {
            kind: PatternKind::Periodic,
            pose: pose(1.0, 2.0, 0.1),
            period_um: 10.0,
            pixel_um: 1.0,
            width: 40,
            height: 30,
            bit_depth: depth,
            noise_frac: 0.01,
            seed: 4,
        })
        .unwrap();
        let png = codec::encode_png(&img).unwrap();
        assert_eq!(codec::decode(&png).unwrap(), img);
        let mut tif = std::io::Cursor::new(Vec::new());
        {
            let mut enc = tiff::encoder::TiffEncoder::new(&mut tif).unwrap();
            if depth == 8 {
                let px: Vec<u8> = img.pixels.iter().map(|&p| p as u8).collect();
                enc.write_image::<tiff::encoder::colortype::Gray8>(40, 30, &px)
                    .unwrap();
            } else {
                enc.write_image::<tiff::encoder::colortype::Gray16>(40, 30, &img.pixels)
                    .unwrap();
            }
        }
        assert_eq!(codec::decode(tif.get_ref()).unwrap(), img);
    }
    let e = codec::decode(b"GIF89a....").unwrap_err();
    assert!(e.to_string().contains("neither a PNG nor a TIFF"), "{e}");
    let e = codec::decode(b"\x89PNG\r\n\x1a\n\0\0").unwrap_err();
    assert!(e.to_string().contains("invalid PNG"), "{e}");
}

#[test]
fn small_noisy_8_bit_images_are_measured_near_the_noise_limit() {
    for (size, bits) in [(256, 8u8), (256, 16), (512, 8)] {
        let mut est = PhaseEstimator::new(size, size, 10.0).unwrap();
        let mut worst = 0.0f64;
        for k in 0..4 {
            let truth = pose(0.3 + 1.1 * k as f64, -0.4, 0.2 - 0.1 * k as f64);
            let img = render(&RenderSpec {
                kind: PatternKind::Periodic,
                pose: truth,
                period_um: 10.0,
                pixel_um: 1.0,
                width: size,
                height: size,
                bit_depth: bits,
                noise_frac: 0.01,
                seed: 9 + k,
            })
            .unwrap();
            let e = lattice_error(est.fit(&img).unwrap().pose(10.0), truth, 10.0);
            worst = worst.max(e[0].hypot(e[1]));
        }
        eprintln!("{size} px {bits}-bit 1 % noise: worst position error {worst:.2e} px");
        assert!(worst < 0.01, "{size} {bits}: {worst}");
    }
}

/// Each plan against the direct sum of its definition on a seeded signal.
#[test]
fn fft_plans_match_the_direct_transform() {
    let n = 12;
    let x: Vec<f64> = (0..n).map(|i| ((i * 7 + 3) % 11) as f64 - 5.0).collect();
    let dft = |sign: f64| -> Vec<calibd_fft::Complex<f64>> {
        (0..n)
            .map(|k| {
                (0..n)
                    .map(|j| {
                        let a = sign * std::f64::consts::TAU * (j * k) as f64 / n as f64;
                        calibd_fft::Complex::new(x[j] * a.cos(), x[j] * a.sin())
                    })
                    .sum()
            })
            .collect()
    };
    let (fwd, inv) = (dft(-1.0), dft(1.0));

    let r2c = calibd_fft::real_forward_f32(n);
    let mut input: Vec<f32> = x.iter().map(|&v| v as f32).collect();
    let mut out = r2c.make_output_vec();
    r2c.process(&mut input, &mut out)
        .expect("lengths match the plan");
    assert_eq!(out.len(), n / 2 + 1);
    for (a, b) in out.iter().zip(&fwd) {
        assert!((a.re as f64 - b.re).abs() < 1e-4 && (a.im as f64 - b.im).abs() < 1e-4);
    }

    let mut c: Vec<calibd_fft::Complex<f32>> = x
        .iter()
        .map(|&v| calibd_fft::Complex::new(v as f32, 0.0))
        .collect();
    calibd_fft::forward_f32(n).process(&mut c);
    for (a, b) in c.iter().zip(&fwd) {
        assert!((a.re as f64 - b.re).abs() < 1e-4 && (a.im as f64 - b.im).abs() < 1e-4);
    }

    let mut d: Vec<calibd_fft::Complex<f64>> = x
        .iter()
        .map(|&v| calibd_fft::Complex::new(v, 0.0))
        .collect();
    calibd_fft::inverse_f64(n).process(&mut d);
    for (a, b) in d.iter().zip(&inv) {
        assert!((a - b).norm() < 1e-12);
    }
}
