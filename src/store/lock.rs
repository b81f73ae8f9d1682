//! One daemon per SQLite store: its queue lives in its memory and it answers job status
//! from the records it read since its last write, so a second daemon on the same data
//! folder would run jobs twice and serve stale states. The daemon holds an exclusive lock
//! on `calibd.lock` in the folder while it runs; the kernel drops it when the process ends,
//! however it ends, so there is no stale lock to clean up after a crash.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::StoreError;

/// The held lock on a data folder (released on drop).
#[derive(Debug)]
pub struct DataLock {
    _file: File,
}

/// The lock file's name in the data folder.
const NAME: &str = "calibd.lock";

impl DataLock {
    /// Take the lock on `dir` (created if missing), or say which process holds it.
    pub fn take(dir: &Path) -> Result<DataLock, StoreError> {
        let path = Self::path(dir);
        let io = |source| StoreError::Io {
            path: path.clone(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(|source| StoreError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let mut options = std::fs::OpenOptions::new();
        options.read(true).write(true).create(true).truncate(false);
        #[cfg(unix)]
        std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
        let mut file = options.open(&path).map_err(io)?;
        // flock(2) on Linux: held by this open file, dropped with it or the process.
        if let Err(e) = file.try_lock() {
            if let std::fs::TryLockError::Error(source) = e {
                return Err(io(source));
            }
            let holder = std::fs::read_to_string(&path).unwrap_or_default();
            return Err(StoreError::InUse {
                path,
                holder: holder.trim().chars().take(20).collect(),
            });
        }
        // The holder's process id, for the message a second daemon gives.
        file.set_len(0).map_err(io)?;
        writeln!(file, "{}", std::process::id()).map_err(io)?;
        Ok(DataLock { _file: file })
    }

    /// The lock file of data folder `dir`.
    pub fn path(dir: &Path) -> PathBuf {
        dir.join(NAME)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_until_the_first_lets_go() {
        let dir = tempfile::tempdir().unwrap();
        let first = DataLock::take(dir.path()).unwrap();
        match DataLock::take(dir.path()) {
            Err(StoreError::InUse { path, holder }) => {
                assert_eq!(path, DataLock::path(dir.path()));
                assert_eq!(holder, std::process::id().to_string());
            }
            other => panic!("a second lock on the folder: {other:?}"),
        }
        drop(first);
        assert!(
            DataLock::take(dir.path()).is_ok(),
            "free again once dropped"
        );
    }
}
