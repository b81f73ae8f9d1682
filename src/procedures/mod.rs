//! Procedures that drive devices: the centring loop, the motion envelope and the journal;
//! whole campaigns are in [`crate::campaigns`]. They see
//! devices only through the small traits of [`devices`], implemented by the driver actors and
//! by the in-memory fakes of [`fakes`].

pub mod centring;
pub mod devices;
pub mod envelope;
pub mod fakes;
pub mod journal;

pub use centring::{Centred, CentringError, CentringOptions, centre};
pub use devices::{
    DeviceError, DeviceFuture, Indicators, JointRobot, LinearStages, MarkerFrames, MarkerStream,
    ModuleLoader, PoseSensor, Robot,
};
pub use envelope::{Envelope, MotionLimiter, Workspace};
pub use journal::{EntryStatus, Journal, JournalEntry, JournalError, MemoryJournal};
