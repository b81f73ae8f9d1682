//! The simulated lab: digital twins behind mock device servers on loopback, reached over
//! the real protocols. It produces the same cell descriptions as a real lab's configuration
//! ([`crate::lab::CellLink`]) and builds the [`Lab`] from them exactly as the daemon
//! would for the real instruments; the mock servers stay attached to the lab.

pub mod bench;
pub mod lab;
pub mod mocap;
pub mod pcr;
pub mod trical;

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use calibd_drivers::mock::RunningMock;

pub use mocap::SimMocapOptions;
pub use pcr::SimPcrOptions;
pub use trical::{INDICATOR_ZERO_MM, SimTricalOptions};

use crate::lab::{Attached, Lab, LabError};

/// A twin shared by the simulated devices of one cell; each locks it for one exchange.
type Shared<T> = Arc<Mutex<T>>;

/// Run `f` on a shared twin (a panic in one device does not poison it for the others).
fn with<T, R>(twin: &Shared<T>, f: impl FnOnce(&mut T) -> R) -> R {
    f(&mut twin.lock().unwrap_or_else(|p| p.into_inner()))
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

/// The mock servers of the simulation, stopped with the lab.
struct Mocks(Vec<RunningMock>);

impl Attached for Mocks {
    fn addresses(&self) -> Vec<String> {
        self.0.iter().map(|m| m.addr.clone()).collect()
    }
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = ()> + Send>> {
        Box::pin(async move {
            for m in self.0 {
                m.stop().await;
            }
        })
    }
}

impl Lab {
    /// Start the simulated lab on loopback: the three cells' twins and mock servers, and
    /// the lab connected to them. Must be called inside a tokio runtime.
    pub async fn simulated(opts: &SimOptions) -> Result<Lab, LabError> {
        let (trical, mut mocks) = trical::start(opts.seed, &opts.trical).await?;
        let (mocap, more) = mocap::start(opts.seed, &opts.mocap).await?;
        mocks.extend(more);
        let (pcr, more) = pcr::start(opts.seed, &opts.pcr).await?;
        mocks.extend(more);
        let mut lab = Lab::connect(vec![trical, mocap, pcr])?;
        lab.attach(Box::new(Mocks(mocks)));
        Ok(lab)
    }
}
