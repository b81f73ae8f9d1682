//! The folder source: a camera's acquisition software writes numbered frames
//! (`<anything><number>.png|.tif|.tiff`, e.g. `frame_000123.png`) into a folder; each grab
//! returns the first frame written after it was asked for (numbered above every frame then
//! present), waiting for it (one look per frame period) up to a timeout. Writers should create a file under another name
//! and rename it into place, so a half-written frame is never read.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use tokio::sync::Mutex;

use super::{FrameSource, RawFrame};
use crate::error::DriverError;
use crate::link::BoxFuture;

const DEVICE: &str = "camera";

/// Frames from a folder.
#[derive(Debug)]
pub struct FolderCamera {
    dir: PathBuf,
    period: Duration,
    timeout: Duration,
    last: Mutex<Option<u64>>,
}

impl FolderCamera {
    /// Frames from `dir`, looked for at `frame_rate_hz`, a grab failing after `timeout`.
    pub fn new(dir: impl Into<PathBuf>, frame_rate_hz: f64, timeout: Duration) -> Self {
        let hz = if frame_rate_hz > 0.0 && frame_rate_hz.is_finite() {
            frame_rate_hz
        } else {
            25.0
        };
        Self {
            dir: dir.into(),
            period: Duration::from_secs_f64(1.0 / hz),
            timeout,
            last: Mutex::new(None),
        }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The numbered frames in the folder, lowest number first.
    pub fn frames(&self) -> Result<Vec<(u64, PathBuf)>, DriverError> {
        let io = |source| DriverError::Transport {
            device: DEVICE,
            source,
        };
        let mut out = Vec::new();
        for e in std::fs::read_dir(&self.dir).map_err(io)? {
            let p = e.map_err(io)?.path();
            if let Some(n) = frame_number(&p) {
                out.push((n, p));
            }
        }
        out.sort();
        Ok(out)
    }

    /// The highest frame number present (None for an empty folder).
    fn highest(&self) -> Result<Option<u64>, DriverError> {
        Ok(self.frames()?.last().map(|(n, _)| *n))
    }

    async fn next(&self, floor: Result<Option<u64>, DriverError>) -> Result<RawFrame, DriverError> {
        let floor = floor?;
        let mut last = self.last.lock().await;
        let above = floor.max(*last);
        let t0 = Instant::now();
        loop {
            let newer = self
                .frames()?
                .into_iter()
                .find(|(n, _)| above.is_none_or(|l| *n > l));
            if let Some((seq, path)) = newer {
                let bytes =
                    tokio::fs::read(&path)
                        .await
                        .map_err(|source| DriverError::Transport {
                            device: DEVICE,
                            source,
                        })?;
                *last = Some(seq);
                let name = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                return Ok(RawFrame::File { seq, name, bytes });
            }
            if t0.elapsed() >= self.timeout {
                return Err(DriverError::Timeout {
                    device: DEVICE,
                    what: format!(
                        "a frame newer than {} in {}",
                        above.map_or("none".into(), |l| l.to_string()),
                        self.dir.display()
                    ),
                    after_ms: self.timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(self.period).await;
        }
    }
}

impl FrameSource for FolderCamera {
    /// The frames present when `grab` is called are the past: the one returned comes after.
    fn grab(&self) -> BoxFuture<'_, Result<RawFrame, DriverError>> {
        let floor = self.highest();
        Box::pin(self.next(floor))
    }
}

/// The number at the end of a PNG/TIFF file's stem (`frame_0042.png` -> 42).
pub fn frame_number(p: &Path) -> Option<u64> {
    let ext = p.extension()?.to_str()?.to_ascii_lowercase();
    if !matches!(ext.as_str(), "png" | "tif" | "tiff") {
        return None;
    }
    let stem = p.file_stem()?.to_str()?;
    let digits = stem.len() - stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    if digits == 0 {
        return None;
    }
    stem[stem.len() - digits..].parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_numbers_come_from_the_end_of_the_stem() {
        assert_eq!(frame_number(Path::new("a/frame_0042.png")), Some(42));
        assert_eq!(frame_number(Path::new("x7_13.TIFF")), Some(13));
        assert_eq!(frame_number(Path::new("frame_0042.png.part")), None);
        assert_eq!(frame_number(Path::new("notes.txt")), None);
        assert_eq!(frame_number(Path::new("frame.png")), None);
    }

    #[tokio::test]
    async fn a_grab_returns_the_first_frame_written_after_it_was_asked_for() {
        let dir = tempfile::tempdir().expect("dir");
        let write = |n: u64| {
            let path = dir.path().join(format!("f_{n:04}.png"));
            let tmp = path.with_extension("part");
            std::fs::write(&tmp, [n as u8]).expect("write");
            std::fs::rename(&tmp, &path).expect("rename");
        };
        for n in [3, 1, 2] {
            write(n);
        }
        std::fs::write(dir.path().join("readme.txt"), b"x").expect("write");
        let cam = FolderCamera::new(dir.path(), 200.0, Duration::from_secs(5));
        // Frames 1..3 were there before the request: the grab returns the next ones, in order.
        let pending = cam.grab();
        write(5);
        write(4);
        match pending.await.expect("frame") {
            RawFrame::File { seq, name, bytes } => {
                assert_eq!(seq, 4);
                assert_eq!(name, "f_0004.png");
                assert_eq!(bytes, vec![4]);
            }
            other => panic!("{other:?}"),
        }
        // Frame 5 is present when the next grab is asked for: it is the past too.
        let quick = FolderCamera::new(dir.path(), 200.0, Duration::from_millis(20));
        let e = quick.grab().await.expect_err("no sixth frame").to_string();
        assert!(e.contains("newer than 5") && e.contains("timed out"), "{e}");
        let pending = cam.grab();
        write(6);
        assert_eq!(pending.await.expect("frame 6").seq(), 6);
    }
}
