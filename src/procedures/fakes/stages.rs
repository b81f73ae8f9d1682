//! In-memory 3-PF devices: stages that record their targets and a microscope that sees a
//! known linear map of the last target (tests of the engine and the 3-PF campaign).

use std::sync::{Arc, Mutex};

use crate::procedures::{DeviceError, DeviceFuture, LinearStages, PoseSensor};

/// Stages that settle 1 nm past the target; the first `faults` moves time out.
#[derive(Debug)]
pub struct FakeStages {
    /// Moves still to fail.
    pub faults: Mutex<usize>,
    /// Targets received.
    pub moves: Mutex<Vec<[f64; 3]>>,
}

impl FakeStages {
    /// Stages whose first `faults` moves time out.
    pub fn new(faults: usize) -> Arc<Self> {
        Arc::new(Self {
            faults: Mutex::new(faults),
            moves: Mutex::new(Vec::new()),
        })
    }
}

impl LinearStages for FakeStages {
    fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]> {
        Box::pin(async move {
            let mut f = self.faults.lock().expect("lock");
            if *f > 0 {
                *f -= 1;
                return Err(DeviceError::Timeout {
                    device: "stages".into(),
                    timeout_ms: 1,
                });
            }
            self.moves.lock().expect("lock").push(*q);
            Ok(q.map(|v| v + 1e-9))
        })
    }
    fn positions(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async { Ok([0.0; 3]) })
    }
}

/// A microscope that sees the last joint set scaled (a known linear map).
#[derive(Debug)]
pub struct FakeScope(pub Arc<FakeStages>);

impl PoseSensor for FakeScope {
    fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let q = self
                .0
                .moves
                .lock()
                .expect("lock")
                .last()
                .copied()
                .unwrap_or_default();
            Ok([2.0 * q[0], 3.0 * q[1], q[2]])
        })
    }
}
