//! Guarded moves through the calibd RAPID module: local safety checks, then write target,
//! `calib_cmd`, bump `calib_seq`, poll `calib_ack`, check `calib_err`.

use tokio::time::Instant;

use super::{Actor, DEVICE, device, field, parse_num};
use crate::error::DriverError;
use crate::link::Connect;
use crate::rws::rapid::{format_jointtarget, format_pos};

impl<C: Connect> Actor<C> {
    fn safety(&self, reason: String) -> DriverError {
        DriverError::Safety {
            device: DEVICE,
            reason,
        }
    }

    pub(super) async fn move_abs_j(&mut self, q: [f64; 6]) -> Result<[f64; 6], DriverError> {
        for (i, (v, (lo, hi))) in q.iter().zip(self.cfg.limits_deg).enumerate() {
            if !v.is_finite() || *v < lo || *v > hi {
                return Err(self.safety(format!(
                    "joint {} target {v} deg outside [{lo}, {hi}]",
                    i + 1
                )));
            }
        }
        let now = self.joints().await?;
        for i in 0..6 {
            let step = (q[i] - now[i]).abs();
            if step > self.cfg.max_joint_step_deg {
                return Err(self.safety(format!(
                    "joint {} step {step:.3} deg exceeds the maximum {} deg",
                    i + 1,
                    self.cfg.max_joint_step_deg
                )));
            }
        }
        self.write("calib_q", &format_jointtarget(&q)).await?;
        self.command(1).await
    }

    pub(super) async fn move_rel_tool(&mut self, dp: [f64; 3]) -> Result<[f64; 6], DriverError> {
        let len = dp.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !len.is_finite() || len > self.cfg.max_tool_step_mm {
            return Err(self.safety(format!(
                "tool step {len:.4} mm exceeds the maximum {} mm",
                self.cfg.max_tool_step_mm
            )));
        }
        self.write("calib_dp", &format_pos(&dp)).await?;
        self.command(2).await
    }

    /// Runs one calib-server command: check the controller, write `calib_cmd`, bump
    /// `calib_seq`, poll `calib_ack`, check `calib_err`, read the joints reached.
    async fn command(&mut self, cmd: i64) -> Result<[f64; 6], DriverError> {
        let st = self.ctrl_state().await?;
        if st.ctrlstate != "motoron" {
            return Err(device(
                -1,
                format!("controller state is {}, a move needs motoron", st.ctrlstate),
            ));
        }
        if st.opmode != "AUTO" {
            return Err(device(
                -1,
                format!(
                    "operating mode is {}, calibration moves run in AUTO",
                    st.opmode
                ),
            ));
        }
        if st.execstate != "running" {
            return Err(device(
                -1,
                format!(
                    "RAPID execution is {}, the calib server must run",
                    st.execstate
                ),
            ));
        }
        let seq = match self.seq {
            Some(s) => s,
            None => parse_num(&self.read("calib_seq").await?)?,
        } + 1;
        self.write("calib_cmd", &cmd.to_string()).await?;
        // A write whose reply is lost may still have reached the controller: forget the
        // cached number until this one is confirmed, so the next command re-reads it
        // instead of writing the same number again (which the calib server would not see
        // as a new command, and whose old ack would pass for this move's).
        self.seq = None;
        self.write("calib_seq", &seq.to_string()).await?;
        self.seq = Some(seq);
        let deadline = Instant::now() + self.cfg.move_timeout;
        loop {
            if parse_num(&self.read("calib_ack").await?)? == seq {
                break;
            }
            let e = self.get_state("/rw/rapid/execution").await?;
            if field(&e, "ctrlexecstate")? != "running" {
                return Err(device(
                    -1,
                    "RAPID execution stopped while a move was pending".into(),
                ));
            }
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: DEVICE,
                    what: format!("calib_ack = {seq}"),
                    after_ms: self.cfg.move_timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(self.cfg.poll).await;
        }
        let err = parse_num(&self.read("calib_err").await?)?;
        if err != 0 {
            let what = if err == 2 {
                "target unreachable or outside the robot's limits"
            } else {
                "unknown command"
            };
            return Err(device(err, format!("calib server: {what}")));
        }
        self.joints().await
    }
}
