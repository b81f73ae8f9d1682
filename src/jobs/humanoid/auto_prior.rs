//! `options.prior.scale: "auto"` for `humanoid.identify`: the joint parameters' length and
//! angle stds chosen by K-fold over a self-extending grid on the training samples (base
//! frame and markers carry over within the session), so the user need not guess them.

use super::identify::IdentifyJob;
use crate::identify::IdentifyError;
use crate::identify::duplicates::duplicate_configurations;
use crate::identify::prior::CV_FOLDS;
use crate::identify::prior_grid::{AutoPrior, auto_axes, choose_grid};
use crate::measure::marker_fit::FitOptions;
use crate::measure::markers::{MarkerSample, marker_rmse};
use crate::run::JobError;
use crate::util::{Monitor, SubMonitor};

impl IdentifyJob {
    /// Choose the length and angle stds (weight 1) with the smallest held-out marker RMS
    /// over [`CV_FOLDS`] seeded folds (copies of a configuration in one fold); the fit
    /// options with that prior and the report of the grid.
    pub(super) fn auto_prior(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<(FitOptions, AutoPrior), JobError> {
        let samples = &self.set.samples;
        let group = duplicate_configurations(samples.iter().map(|s| s.state.q.as_slice())).group;
        let with = |a: f64, b: f64| {
            let mut o = self.fit.clone();
            if let Some(map) = &mut o.prior {
                map.spec = map.spec.with_scale(a, b);
                map.weight = 1.0;
            }
            o
        };
        let mut done = 0usize;
        // Progress: the grid's size is not known ahead (it may extend); 25 cells is half.
        let share = |n: usize| n as f64 / (n as f64 + 25.0 * CV_FOLDS as f64);
        let choice = choose_grid(
            &auto_axes(),
            &group,
            CV_FOLDS,
            self.options.seed,
            |a, b, train, test| {
                if monitor.is_cancelled() {
                    return Err(IdentifyError::Cancelled);
                }
                let sub = SubMonitor::new(monitor, share(done), share(done + 1));
                done += 1;
                let tr: Vec<MarkerSample> = train.iter().map(|&i| samples[i].clone()).collect();
                let te: Vec<MarkerSample> = test.iter().map(|&i| samples[i].clone()).collect();
                let cal = super::identify::calibrate(
                    &self.loaded.model,
                    &tr,
                    self.groups,
                    &with(a, b),
                    &sub,
                )
                .map_err(|e| IdentifyError::Model(e.to_string()))?;
                let (rmse_m, _) = marker_rmse(&cal.full.model, &te);
                let m: usize = te.iter().map(|s| s.points.iter().flatten().count()).sum();
                let rmse_mm = rmse_m * 1e3;
                Ok((rmse_mm * rmse_mm * m as f64, m))
            },
        )
        .map_err(|e| match e {
            IdentifyError::Cancelled => JobError::Cancelled,
            e => JobError::from(e),
        })?;
        Ok((with(choice.a, choice.b), AutoPrior::of(&choice)))
    }
}
