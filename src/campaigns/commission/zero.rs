//! `cell.zero_check`: with the device mated on its kinematic coupling platform (the
//! operator mates it and presses each indicator's set button, then continues), read the
//! three indicators several times, journal each reading and confirm each reads 0.000 mm
//! within the tolerance. In the simulated cell, a device centred on a ball stands in for
//! the coupling (the stems are then at their zero).

use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::plan::campaign_kind;
use super::results::{IndicatorOff, ZeroCheck};
use super::zero_plan::ZeroCheckJob;
use crate::campaigns::engine::{self, Step, StepError};
use crate::campaigns::operator;
use crate::procedures::{Indicators, Journal};
use crate::run::{Cx, JobError, Output, Produced, Table};
use crate::util::Monitor;

/// The operator's prompt before the readings.
pub const PROMPT: &str = "mate the centring device on its coupling platform and press each indicator's set button, then continue";

/// One journalled reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZeroReading {
    /// Journal index.
    pub index: usize,
    /// The three indicators (mm).
    pub reading_mm: [f64; 3],
}

struct ReadZero<'a> {
    indicators: &'a dyn Indicators,
    journal: &'a dyn Journal,
    settle: Duration,
    timeout: Duration,
}

impl Step for ReadZero<'_> {
    type Plan = ();
    type Sample = ZeroReading;
    const STAGE: &'static str = "zero check";

    fn describe(&self, k: usize, n: usize, _: &()) -> String {
        format!("reading {k}/{n}")
    }

    async fn measure(
        &self,
        index: usize,
        _: &(),
        _: &dyn Monitor,
    ) -> Result<ZeroReading, StepError> {
        // One prompt for the whole check: its marker is step 0's.
        operator::confirm(self.journal, 0, PROMPT)?;
        tokio::time::sleep(self.settle).await;
        match tokio::time::timeout(self.timeout, self.indicators.read()).await {
            Ok(Ok(r)) => Ok(ZeroReading {
                index,
                reading_mm: r,
            }),
            Ok(Err(e)) => Err(StepError::Fault(e.to_string())),
            Err(_) => Err(StepError::Fault(format!(
                "no indicator reading within {} ms",
                self.timeout.as_millis()
            ))),
        }
    }
}

/// The verdict on the journalled readings.
pub fn verdict(cell: &str, tolerance_mm: f64, readings: &[ZeroReading]) -> ZeroCheck {
    let n = readings.len().max(1) as f64;
    let mut mean_mm = [0.0; 3];
    let mut worst = [0.0f64; 3];
    for r in readings {
        for k in 0..3 {
            mean_mm[k] += r.reading_mm[k] / n;
            if r.reading_mm[k].abs() > worst[k].abs() {
                worst[k] = r.reading_mm[k];
            }
        }
    }
    let out_of_tolerance: Vec<IndicatorOff> = (0..3)
        .filter(|&k| worst[k].abs() > tolerance_mm)
        .map(|k| IndicatorOff {
            indicator: k + 1,
            worst_reading_mm: worst[k],
            excess_mm: worst[k].abs() - tolerance_mm,
        })
        .collect();
    let message = if out_of_tolerance.is_empty() {
        format!("all three indicators read 0.000 mm within {tolerance_mm} mm")
    } else {
        out_of_tolerance
            .iter()
            .map(|o| {
                format!(
                    "indicator {} reads {:.4} mm, {:.4} mm beyond the {tolerance_mm} mm tolerance: re-mate the device and press its set button",
                    o.indicator, o.worst_reading_mm, o.excess_mm
                )
            })
            .collect::<Vec<_>>()
            .join("; ")
    };
    ZeroCheck {
        cell: cell.to_string(),
        passed: out_of_tolerance.is_empty(),
        tolerance_mm,
        readings: readings.len(),
        mean_mm,
        max_abs_mm: worst.map(f64::abs),
        out_of_tolerance,
        message,
    }
}

/// Run a `cell.zero_check`.
pub async fn campaign(job: Arc<ZeroCheckJob>, cx: Cx) -> Result<Produced, JobError> {
    let cell = cx.lab().trical(&job.cell)?;
    let journal = cx.journal();
    let step = ReadZero {
        indicators: &*cell.indicators,
        journal,
        settle: Duration::from_millis(job.options.settle_ms),
        timeout: Duration::from_millis(job.options.reading_timeout_ms),
    };
    let plan = vec![(); job.readings];
    engine::run(&step, &plan, 0, journal, &job.options.retry.retry(), &cx).await?;
    let readings: Vec<ZeroReading> = engine::recorded(journal, 0, plan.len())?;
    let result = verdict(&job.cell, job.options.tolerance_mm, &readings);
    let mut t = Table::new(&["reading", "indicator1_mm", "indicator2_mm", "indicator3_mm"]);
    for r in &readings {
        t.push(vec![
            (r.index + 1) as f64,
            r.reading_mm[0],
            r.reading_mm[1],
            r.reading_mm[2],
        ]);
    }
    let mut out = Output::typed(&result)?;
    out.main_table = Some(t);
    Ok(out.into())
}

campaign_kind!(ZeroCheckJob, campaign);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_verdict_names_the_indicator_out_of_tolerance_and_by_how_much() {
        let r = |index, reading_mm| ZeroReading { index, reading_mm };
        let v = verdict(
            "c",
            0.005,
            &[r(0, [0.001, -0.002, 0.0]), r(1, [0.0, -0.009, 0.004])],
        );
        assert!(!v.passed);
        assert_eq!(v.out_of_tolerance.len(), 1);
        assert_eq!(v.out_of_tolerance[0].indicator, 2);
        assert!((v.out_of_tolerance[0].excess_mm - 0.004).abs() < 1e-12);
        assert!(
            v.message.contains("indicator 2 reads -0.0090 mm"),
            "{}",
            v.message
        );
        assert!(verdict("c", 0.005, &[r(0, [0.001, 0.0, -0.001])]).passed);
    }
}
