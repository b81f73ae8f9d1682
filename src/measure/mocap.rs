//! Motion-capture pre-processing (`../shared/spec/humanoid.md`): each marker's visible runs
//! are low-pass filtered with a zero-phase Butterworth (5th order, 5 Hz at 100 Hz by
//! default), velocities come from the filtered signal, stable samples are those where every
//! visible marker moves slower than a threshold, postures are long enough runs of stable
//! samples, and the same number of samples is kept per posture and marker (the ones nearest
//! the middle of the posture). Gaps are never interpolated: a marker that is occluded (or
//! whose visible run is too short to filter) has no measurement there, and the samples within
//! `rate / (2 cutoff)` of either end of a visible run (where the filter has not settled) are
//! neither measurements nor evidence of motion.

use nalgebra::Vector3;
use serde::Serialize;

use crate::signal::{SignalError, butterworth_lowpass, filtfilt};

/// Settings of the pre-processing.
#[derive(Debug, Clone, PartialEq)]
pub struct MocapOptions {
    /// Butterworth order.
    pub order: usize,
    /// Cutoff frequency (Hz).
    pub cutoff_hz: f64,
    /// Sampling rate (Hz); `None`: from the time stamps.
    pub rate_hz: Option<f64>,
    /// A sample is stable when every visible marker is slower than this (m/s).
    pub velocity_threshold: f64,
    /// ... and, when joint values are given, every joint slower than this (rad/s). Joints
    /// also bridge samples where no marker is visible: a posture is not cut in two by an
    /// occlusion while the robot stands still.
    pub joint_velocity_threshold: f64,
    /// Shortest run of stable samples that counts as a posture.
    pub min_stable: usize,
    /// Samples kept per posture and marker.
    pub samples_per_posture: usize,
}

impl Default for MocapOptions {
    fn default() -> Self {
        Self {
            order: 5,
            cutoff_hz: 5.0,
            rate_hz: None,
            velocity_threshold: 0.02,
            joint_velocity_threshold: 0.02,
            min_stable: 20,
            samples_per_posture: 10,
        }
    }
}

/// The result: which samples to keep for which marker, and the filtered positions.
#[derive(Debug, Clone)]
pub struct Stable {
    /// Sample indices of each posture's kept samples (sorted).
    pub postures: Vec<Vec<usize>>,
    /// `keep[marker][sample]`: this marker's position at this sample is a measurement.
    pub keep: Vec<Vec<bool>>,
    /// Filtered positions `[marker][sample]` (None where occluded or unfilterable).
    pub filtered: Vec<Vec<Option<Vector3<f64>>>>,
    /// Summary for reports.
    pub report: MocapReport,
}

/// Numbers of a pre-processing run.
#[derive(Debug, Clone, Serialize)]
pub struct MocapReport {
    /// Sampling rate used (Hz).
    pub rate_hz: f64,
    /// Raw samples.
    pub samples: usize,
    /// Stable samples.
    pub stable_samples: usize,
    /// Postures found.
    pub postures: usize,
    /// (posture, marker) pairs dropped for lack of visible stable samples.
    pub dropped_marker_postures: usize,
    /// Visible marker samples discarded because their run was too short to filter.
    pub unfilterable_samples: usize,
}

/// Pre-process a recording: time stamps `t` (s), `markers[marker][sample]` and, optionally,
/// the joint values of every sample (`joints[sample][joint]`, rad).
pub fn preprocess(
    t: &[f64],
    markers: &[Vec<Option<Vector3<f64>>>],
    joints: Option<&[Vec<f64>]>,
    opts: &MocapOptions,
) -> Result<Stable, SignalError> {
    let n = t.len();
    if markers.iter().any(|m| m.len() != n) || joints.is_some_and(|j| j.len() != n) {
        return Err(SignalError::Design(
            "every marker and joint needs one entry per time stamp".into(),
        ));
    }
    if n < 2 {
        return Err(SignalError::TooShort { len: n, needed: 2 });
    }
    if t.windows(2).any(|w| !(w[1] > w[0])) {
        return Err(SignalError::Design(
            "time stamps must increase strictly".into(),
        ));
    }
    let rate = match opts.rate_hz {
        Some(r) => r,
        None => {
            let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
            d.sort_by(f64::total_cmp);
            1.0 / d[d.len() / 2]
        }
    };
    let filter = butterworth_lowpass(opts.order, opts.cutoff_hz, rate)?;
    let edge = (0.5 * rate / opts.cutoff_hz).ceil() as usize;
    let mut unfilterable = 0;
    let mut filtered = Vec::with_capacity(markers.len());
    let mut speed = vec![vec![f64::NAN; n]; markers.len()];
    for (m, track) in markers.iter().enumerate() {
        let mut out: Vec<Option<Vector3<f64>>> = vec![None; n];
        let mut k = 0;
        while k < n {
            if track[k].is_none() {
                k += 1;
                continue;
            }
            let start = k;
            while k < n && track[k].is_some() {
                k += 1;
            }
            let run: Vec<Vector3<f64>> = track[start..k].iter().flatten().copied().collect();
            let coords: Result<Vec<Vec<f64>>, SignalError> = (0..3)
                .map(|a| filtfilt(&filter, &run.iter().map(|p| p[a]).collect::<Vec<_>>()))
                .collect();
            let Ok(c) = coords else {
                unfilterable += run.len();
                continue;
            };
            let len = run.len();
            for i in 0..len {
                out[start + i] = Some(Vector3::new(c[0][i], c[1][i], c[2][i]));
                // The filter settles over about rate / (2 cutoff) samples: near the ends of a
                // visible run the filtered signal is neither a measurement nor a velocity.
                if i < edge || i + edge >= len {
                    continue;
                }
                let (a, b) = (i.saturating_sub(1), (i + 1).min(len - 1));
                let dt = t[start + b] - t[start + a];
                let d = Vector3::new(c[0][b] - c[0][a], c[1][b] - c[1][a], c[2][b] - c[2][a]);
                speed[m][start + i] = d.norm() / dt;
            }
        }
        filtered.push(out);
    }
    let joint_still = |s: usize| -> Option<bool> {
        let q = joints?;
        let (a, b) = (s.saturating_sub(1), (s + 1).min(n - 1));
        let dt = t[b] - t[a];
        Some(
            q[a].iter()
                .zip(&q[b])
                .all(|(x, y)| ((y - x) / dt).abs() < opts.joint_velocity_threshold),
        )
    };
    let stable: Vec<bool> = (0..n)
        .map(|s| {
            let seen: Vec<f64> = speed
                .iter()
                .map(|v| v[s])
                .filter(|v| v.is_finite())
                .collect();
            let markers_still = seen.iter().all(|v| *v < opts.velocity_threshold);
            match joint_still(s) {
                Some(j) => j && markers_still,
                None => !seen.is_empty() && markers_still,
            }
        })
        .collect();
    let mut runs = Vec::new();
    let mut k = 0;
    while k < n {
        if !stable[k] {
            k += 1;
            continue;
        }
        let s = k;
        while k < n && stable[k] {
            k += 1;
        }
        if k - s >= opts.min_stable.max(1) {
            runs.push((s, k));
        }
    }
    let want = opts.samples_per_posture.max(1);
    let mut keep = vec![vec![false; n]; markers.len()];
    let mut postures = Vec::new();
    let mut dropped = 0;
    for &(s, e) in &runs {
        let mid = 0.5 * (s + e - 1) as f64;
        let mut used = Vec::new();
        for m in 0..markers.len() {
            let mut seen: Vec<usize> = (s..e).filter(|&i| speed[m][i].is_finite()).collect();
            if seen.len() < want {
                dropped += 1;
                continue;
            }
            seen.sort_by(|a, b| (*a as f64 - mid).abs().total_cmp(&(*b as f64 - mid).abs()));
            for &i in &seen[..want] {
                keep[m][i] = true;
                used.push(i);
            }
        }
        used.sort_unstable();
        used.dedup();
        if !used.is_empty() {
            postures.push(used);
        }
    }
    let report = MocapReport {
        rate_hz: rate,
        samples: n,
        stable_samples: stable.iter().filter(|v| **v).count(),
        postures: postures.len(),
        dropped_marker_postures: dropped,
        unfilterable_samples: unfilterable,
    };
    Ok(Stable {
        postures,
        keep,
        filtered,
        report,
    })
}

/// Average each marker over the longest stable stretch of one recording window (the
/// pre-processing of `humanoid.*` raw recordings): per label its mean position (`None`
/// when it had no stable sample), and the most samples averaged for one marker.
#[allow(clippy::type_complexity)]
pub fn average_stable(
    labels: &[String],
    t_s: &[f64],
    frames: &[Vec<Option<[f64; 3]>>],
    opts: &MocapOptions,
) -> Result<(std::collections::BTreeMap<String, Option<[f64; 3]>>, usize), String> {
    let tracks: Vec<Vec<Option<Vector3<f64>>>> = (0..labels.len())
        .map(|m| {
            frames
                .iter()
                .map(|f| f.get(m).copied().flatten().map(Vector3::from))
                .collect()
        })
        .collect();
    let stable = preprocess(t_s, &tracks, None, opts).map_err(|e| e.to_string())?;
    let Some(kept) = stable.postures.iter().max_by_key(|p| p.len()) else {
        return Err(format!(
            "{} frames, none stable for {} samples",
            t_s.len(),
            opts.min_stable
        ));
    };
    let mut out = std::collections::BTreeMap::new();
    let mut most = 0;
    for (m, label) in labels.iter().enumerate() {
        let pts: Vec<Vector3<f64>> = kept
            .iter()
            .filter(|&&s| stable.keep[m][s])
            .filter_map(|&s| stable.filtered[m][s])
            .collect();
        most = most.max(pts.len());
        let mean = (!pts.is_empty()).then(|| {
            let c = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
            [c.x, c.y, c.z]
        });
        out.insert(label.clone(), mean);
    }
    Ok((out, most))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::playback::quintic;
    use crate::util::Rng;

    /// Five held postures (2 s each) joined by 1.5 s quintic moves at 100 Hz, two markers
    /// with 0.5 mm noise; marker 1 is occluded during all of posture 3 and briefly in posture 2.
    #[test]
    fn finds_the_postures_and_keeps_equal_counts_without_interpolating() {
        let mut rng = Rng::new(3);
        let targets: Vec<[f64; 3]> = (0..5)
            .map(|k| [0.1 * k as f64, 0.3 - 0.05 * k as f64, 1.0 + 0.02 * k as f64])
            .collect();
        let (hold, travel, rate) = (2.0, 1.5, 100.0);
        let mut t = Vec::new();
        let mut truth: Vec<Vector3<f64>> = Vec::new();
        let mut time = 0.0;
        for k in 0..5 {
            for _ in 0..(hold * rate) as usize {
                t.push(time);
                truth.push(Vector3::from(targets[k]));
                time += 1.0 / rate;
            }
            if k + 1 < 5 {
                for i in 0..(travel * rate) as usize {
                    let (p, _, _) = quintic(&targets[k], &targets[k + 1], travel, i as f64 / rate);
                    t.push(time);
                    truth.push(Vector3::new(p[0], p[1], p[2]));
                    time += 1.0 / rate;
                }
            }
        }
        let n = t.len();
        let noisy = |rng: &mut Rng, p: &Vector3<f64>| -> Vector3<f64> {
            p + 0.5e-3 * Vector3::new(rng.normal(), rng.normal(), rng.normal())
        };
        let m0: Vec<Option<Vector3<f64>>> =
            truth.iter().map(|p| Some(noisy(&mut rng, p))).collect();
        let offset = Vector3::new(0.0, 0.1, 0.0);
        let mut m1: Vec<Option<Vector3<f64>>> = truth
            .iter()
            .map(|p| Some(noisy(&mut rng, &(p + offset))))
            .collect();
        // Posture k starts at k * 350 samples. Occlude marker 1 over all of posture 3 and a
        // short gap in the middle of posture 2.
        for i in 3 * 350 - 30..3 * 350 + 230 {
            m1[i] = None;
        }
        for i in 2 * 350 + 95..2 * 350 + 105 {
            m1[i] = None;
        }
        let opts = MocapOptions::default();
        let s = preprocess(&t, &[m0.clone(), m1.clone()], None, &opts).unwrap();
        assert!((s.report.rate_hz - 100.0).abs() < 1e-6);
        assert_eq!(s.postures.len(), 5, "{:?}", s.report);
        // Equal counts per posture and marker; marker 1 dropped in posture 3 only.
        for (k, p) in s.postures.iter().enumerate() {
            let c0 = p.iter().filter(|&&i| s.keep[0][i]).count();
            let c1 = p.iter().filter(|&&i| s.keep[1][i]).count();
            assert_eq!(c0, opts.samples_per_posture);
            assert_eq!(
                c1,
                if k == 3 { 0 } else { opts.samples_per_posture },
                "posture {k}"
            );
            // Kept samples sit inside the hold and near the target.
            for &i in p {
                assert_eq!(i / 350, k);
                let e = (s.filtered[0][i].unwrap() - truth[i]).norm();
                assert!(e < 1e-3, "{e}");
            }
        }
        assert_eq!(s.report.dropped_marker_postures, 1);
        // Nothing kept inside a gap, and filtering reduced the noise.
        for i in 0..n {
            if m1[i].is_none() {
                assert!(!s.keep[1][i] && s.filtered[1][i].is_none());
            }
        }
        let kept: Vec<usize> = (0..n).filter(|&i| s.keep[0][i]).collect();
        let raw: f64 = kept
            .iter()
            .map(|&i| (m0[i].unwrap() - truth[i]).norm_squared())
            .sum();
        let fil: f64 = kept
            .iter()
            .map(|&i| (s.filtered[0][i].unwrap() - truth[i]).norm_squared())
            .sum();
        assert!(fil < 0.3 * raw, "{fil} vs {raw}");
    }
}
