//! The lab: the cells calibd drives, each a set of device handles (driver actors) behind
//! the procedure traits. [`Lab::simulated`] builds the simulated lab: the digital twins
//! behind the mock device servers' simulate mode on loopback, reached over the real
//! protocols exactly as the daemon would reach the real instruments.

pub mod adapters;
pub mod mocap;
pub mod pcr;
pub mod pcr_adapters;
pub mod qtm_stream;
pub mod trical;

use calibd_drivers::mock::RunningMock;

pub use mocap::{MocapCell, SimMocapOptions};
pub use pcr::{PcrCell, SimPcrOptions};
pub use trical::{SimTricalOptions, TricalCell};

/// Why a lab could not be started.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LabError {
    /// A mock device server did not start.
    #[error("simulated {device}: {message}")]
    Mock {
        /// Which device.
        device: String,
        /// What went wrong.
        message: String,
    },
}

/// Settings of the simulated lab.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Seed of the twins' true parameters and sensor noise.
    pub seed: u64,
    /// The TriCal cell.
    pub trical: SimTricalOptions,
    /// The humanoid motion-capture cell.
    pub mocap: SimMocapOptions,
    /// The 3-PF cell.
    pub pcr: SimPcrOptions,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            seed: 7,
            trical: SimTricalOptions::default(),
            mocap: SimMocapOptions::default(),
            pcr: SimPcrOptions::default(),
        }
    }
}

/// The lab's cells and the simulated devices behind them (if any).
pub struct Lab {
    /// The ball-centring cell of the serial arm.
    pub trical: Option<TricalCell>,
    /// The humanoid motion-capture cell.
    pub mocap: Option<MocapCell>,
    /// The 3-PF robot under its microscope.
    pub pcr: Option<PcrCell>,
    mocks: Vec<RunningMock>,
}

impl std::fmt::Debug for Lab {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lab")
            .field("trical", &self.trical.as_ref().map(|c| &c.name))
            .field("mocap", &self.mocap.as_ref().map(|c| &c.name))
            .field("pcr", &self.pcr.as_ref().map(|c| &c.name))
            .field("mocks", &self.mocks.len())
            .finish()
    }
}

impl Lab {
    /// A lab without cells (numerical jobs only).
    pub fn empty() -> Self {
        Self {
            trical: None,
            mocap: None,
            pcr: None,
            mocks: Vec::new(),
        }
    }

    /// Start the simulated lab on loopback. Must be called inside a tokio runtime: the mock
    /// servers and the driver actors are tasks on it.
    pub async fn simulated(opts: &SimOptions) -> Result<Self, LabError> {
        let (cell, mut mocks) = trical::simulated(opts.seed, &opts.trical).await?;
        let (mocap, qtm) = mocap::simulated(opts.seed, &opts.mocap).await?;
        mocks.push(qtm);
        let (pcr, more) = pcr::simulated(opts.seed, &opts.pcr).await?;
        mocks.extend(more);
        Ok(Self {
            trical: Some(cell),
            mocap: Some(mocap),
            pcr: Some(pcr),
            mocks,
        })
    }

    /// Names of every device of every cell (for the device panel and the queue's locks).
    pub fn device_names(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(c) = &self.trical {
            v.extend(c.devices.iter().cloned());
        }
        if let Some(c) = &self.mocap {
            v.extend(c.devices.iter().cloned());
        }
        if let Some(c) = &self.pcr {
            v.extend(c.devices.iter().cloned());
        }
        v
    }

    /// Addresses of the simulated devices (`device -> address`), for operators and tests.
    pub fn mock_addresses(&self) -> Vec<String> {
        self.mocks.iter().map(|m| m.addr.clone()).collect()
    }

    /// Stop the simulated devices.
    pub async fn stop(self) {
        for m in self.mocks {
            m.stop().await;
        }
    }
}
