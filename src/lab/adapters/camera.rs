//! A microscope whose pose calibd computes: frames from a camera source (network or
//! folder) measured by the phase method ([`crate::measure::pattern::PoseReader`]) on the
//! blocking pool, as a [`PoseSensor`] in the campaign's units (m, rad).

use std::sync::{Arc, Mutex};

use calibd_drivers::camera::{FrameSource, RawFrame};

use super::serial::device_error;
use crate::measure::pattern::{GrayImage, PatternError, PatternSetup, PoseReader, codec};
use crate::procedures::{DeviceError, DeviceFuture, PoseSensor};

/// Micrometres per metre.
const UM_PER_M: f64 = 1e6;

/// A camera and the pattern it looks at.
pub struct CameraMicroscope {
    source: Arc<dyn FrameSource>,
    reader: Arc<Mutex<PoseReader>>,
    name: String,
}

impl std::fmt::Debug for CameraMicroscope {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CameraMicroscope")
            .field("name", &self.name)
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

impl CameraMicroscope {
    /// Frames from `source` of the pattern `setup`; `name` is the device name in errors.
    pub fn new(
        source: Arc<dyn FrameSource>,
        setup: PatternSetup,
        name: impl Into<String>,
    ) -> Result<Self, PatternError> {
        Ok(Self {
            source,
            reader: Arc::new(Mutex::new(PoseReader::new(setup)?)),
            name: name.into(),
        })
    }
}

/// A frame as a grayscale image (files decoded from PNG/TIFF).
pub fn to_image(frame: RawFrame) -> Result<GrayImage, PatternError> {
    match frame {
        RawFrame::Pixels(f) => Ok(GrayImage {
            width: f.width as usize,
            height: f.height as usize,
            full_scale: ((1u32 << f.bit_depth) - 1) as u16,
            pixels: f.pixels,
        }),
        RawFrame::File { name, bytes, .. } => codec::decode(&bytes)
            .map_err(|e| PatternError::Decode(format!("frame file {name}: {e}"))),
    }
}

impl PoseSensor for CameraMicroscope {
    fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let frame = self
                .source
                .grab()
                .await
                .map_err(|e| device_error(&self.name, e))?;
            let seq = frame.seq();
            let reader = self.reader.clone();
            let pose = tokio::task::spawn_blocking(move || {
                let img = to_image(frame)?;
                reader
                    .lock()
                    .map_err(|_| PatternError::Setup("pose reader poisoned".into()))?
                    .read(&img)
            })
            .await;
            let failed = |message: String| DeviceError::Fault {
                device: self.name.clone(),
                message,
            };
            let pose = pose
                .map_err(|e| failed(format!("pose computation of frame {seq} stopped: {e}")))?
                .map_err(|e| failed(format!("frame {seq}: {e}")))?;
            Ok([pose.x / UM_PER_M, pose.y / UM_PER_M, pose.theta_rad])
        })
    }
}
