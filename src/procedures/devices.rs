//! Device capabilities as small object-safe async traits (`Arc<dyn Robot>`), and the error
//! every device reports through them.

use std::future::Future;
use std::pin::Pin;

/// The future a device call returns.
pub type DeviceFuture<'a, T> = Pin<Box<dyn Future<Output = Result<T, DeviceError>> + Send + 'a>>;

/// A device call that failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DeviceError {
    /// No reply within the allowed time.
    #[error("{device}: no reply within {timeout_ms} ms")]
    Timeout {
        /// Device name.
        device: String,
        /// The limit.
        timeout_ms: u64,
    },
    /// The connection is down (the driver is reconnecting).
    #[error("{device}: disconnected")]
    Disconnected {
        /// Device name.
        device: String,
    },
    /// The device answered with an error of its own.
    #[error("{device} reported: {message}")]
    Fault {
        /// Device name.
        device: String,
        /// The device's message.
        message: String,
    },
    /// A request refused before it reached the device (limits, envelope, state).
    #[error("{device}: refused: {reason}")]
    Refused {
        /// Device name.
        device: String,
        /// Why.
        reason: String,
    },
    /// The reply could not be understood.
    #[error("{device}: protocol error: {message}")]
    Protocol {
        /// Device name.
        device: String,
        /// What was wrong.
        message: String,
    },
}

/// A robot arm driven in joint space and by small tool-frame offsets.
pub trait Robot: Send + Sync {
    /// Current joint values (rad).
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>>;
    /// Move to joint values (rad) and return once the motion has finished.
    fn move_joints<'a>(&'a self, q: &'a [f64]) -> DeviceFuture<'a, ()>;
    /// Move the TCP by an offset along the tool axes (mm), orientation unchanged.
    fn move_tool(&self, offset_mm: [f64; 3]) -> DeviceFuture<'_, ()>;
}

/// A robot controller that takes program modules (an IRC5 over RWS).
pub trait ModuleLoader: Send + Sync {
    /// Upload `text` as the file `file` in the controller's home directory and load it into
    /// the robot task, replacing a module of the same name; with `stop`, stop the program
    /// first. The file's path on the controller; a refusal carries the controller's message.
    fn load_module<'a>(
        &'a self,
        file: &'a str,
        text: &'a str,
        stop: bool,
    ) -> DeviceFuture<'a, String>;
}

/// Three indicators reading the offset of the ball centre from the TCP along the tool axes.
pub trait Indicators: Send + Sync {
    /// A fresh reading (mm), with per-indicator sign and zero already applied.
    fn read(&self) -> DeviceFuture<'_, [f64; 3]>;
}

/// A robot driven joint by joint to whole postures (a humanoid's joint interface).
pub trait JointRobot: Send + Sync {
    /// Names of the joints this interface drives, in the order of [`JointRobot::joints`].
    fn joint_names(&self) -> Vec<String>;
    /// Current joint values (rad), in the order of [`JointRobot::joint_names`].
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>>;
    /// Move to a posture of named joint values (rad); joints not named keep their values.
    /// Returns once the posture is reached.
    fn move_to<'a>(&'a self, posture: &'a [(String, f64)]) -> DeviceFuture<'a, ()>;
}

/// A stretch of a motion-capture stream: labelled 3-D markers with time stamps.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MarkerFrames {
    /// Marker labels, in the order of each frame's positions.
    pub labels: Vec<String>,
    /// Time stamp of each frame (s, the capture system's clock).
    pub t_s: Vec<f64>,
    /// Positions per frame and label (m, capture frame); `None` where occluded.
    pub frames: Vec<Vec<Option<[f64; 3]>>>,
}

/// A motion-capture system streaming labelled markers.
pub trait MarkerStream: Send + Sync {
    /// Record the stream for `duration` from the next frame on.
    fn record(&self, duration: std::time::Duration) -> DeviceFuture<'_, MarkerFrames>;
}

/// A pose source over a planar platform (the microscope of the 3-PF cell).
pub trait PoseSensor: Send + Sync {
    /// The pose in a fresh image: x (m), y (m), theta (rad) of the pattern in the sensor
    /// frame.
    fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]>;
}

/// Three linear stages driving the joints of a parallel robot (the 3-PF's clamps).
pub trait LinearStages: Send + Sync {
    /// Move every stage to `q` (m) and return once all have settled, with the positions
    /// they settled at (m; closed-loop stages stop a few nm from the target).
    fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]>;
    /// Current positions (m).
    fn positions(&self) -> DeviceFuture<'_, [f64; 3]>;
}
