//! Large inputs and outputs copied between the database and files in chunks: a dataset
//! spooled to a file that a job reads row by row, and a main table written row by row to a
//! file and copied into the result. Neither is ever held whole in memory (SQLite's
//! incremental BLOB I/O; PostgreSQL reads the value whole).

use std::path::Path;

use super::{Store, StoreError};

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Datasets at least this large are read by jobs from a spooled file, row by row (bytes).
pub(crate) const SPOOL_DATASET_BYTES: i64 = 4 << 20;

impl Store {
    /// The folder of spooled files: `spool/` beside the SQLite file, or under the system's
    /// temporary folder for PostgreSQL. A cache: emptied when the daemon starts.
    pub fn spool_dir(&self) -> std::path::PathBuf {
        match self.backend.file().and_then(Path::parent) {
            Some(dir) => dir.join("spool"),
            None => std::env::temp_dir().join(format!("calibd-spool-{}", std::process::id())),
        }
    }

    /// A file holding dataset `id` for a job to read row by row, when the dataset is at
    /// least [`SPOOL_DATASET_BYTES`]; `None` for smaller (read whole) or unknown datasets.
    pub fn spooled_dataset(&self, id: &str) -> Result<Option<std::path::PathBuf>, StoreError> {
        // Ids are hex SHA-256: anything else names no dataset (and no path).
        if id.len() != 64 || !id.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Ok(None);
        }
        match self.dataset_size(id)? {
            Some(n) if n >= SPOOL_DATASET_BYTES => {}
            _ => return Ok(None),
        }
        let dir = self.spool_dir();
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
        let dest = dir.join(format!("{id}.dataset"));
        if dest.exists() || self.dataset_to_file(id, &dest)? {
            Ok(Some(dest))
        } else {
            Ok(None)
        }
    }

    /// Size in bytes of dataset `id`, if it exists.
    pub fn dataset_size(&self, id: &str) -> Result<Option<i64>, StoreError> {
        Ok(self.dataset_info(id)?.map(|d| d.size))
    }

    /// Copy dataset `id` to the file `dest` (through `dest.partial`, renamed when complete);
    /// false if there is no such dataset.
    pub fn dataset_to_file(&self, id: &str, dest: &Path) -> Result<bool, StoreError> {
        // A name of this call's own: two jobs may spool the same dataset at once.
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut partial = dest.as_os_str().to_owned();
        partial.push(format!(".{}-{k}.partial", std::process::id()));
        let partial = std::path::PathBuf::from(partial);
        let mut out = std::fs::File::create(&partial).map_err(io_err(&partial))?;
        let copied = self.backend.dataset_to_writer(id, &mut out, &partial)?;
        drop(out);
        if copied {
            std::fs::rename(&partial, dest).map_err(io_err(dest))?;
        } else {
            let _ = std::fs::remove_file(&partial);
        }
        Ok(copied)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dataset_spools_to_a_file_byte_for_byte() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        // Larger than one chunk (64 KiB) and not a multiple of it.
        let content: Vec<u8> = (0..(3 * (1 << 16) + 17)).map(|i| (i % 251) as u8).collect();
        let info = s.put_dataset("big.csv", "text/csv", &content).unwrap();
        let dest = dir.path().join("spooled");
        assert!(s.dataset_to_file(&info.id, &dest).unwrap());
        assert_eq!(std::fs::read(&dest).unwrap(), content);
        assert!(!s.dataset_to_file("0000", &dir.path().join("none")).unwrap());
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with("none"))
            .collect();
        assert!(
            left.is_empty(),
            "nothing left of a missing dataset: {left:?}"
        );
        assert_eq!(
            s.dataset_size(&info.id).unwrap(),
            Some(content.len() as i64)
        );
    }
}
