//! Datasets on SQLite; a dataset is copied out in chunks (incremental BLOB I/O).

use std::io::Read;
use std::path::Path;

use rusqlite::{MAIN_DB, OptionalExtension, params};

use super::Sqlite;
use super::results::{CHUNK, io_err};
use crate::store::backend::Datasets;
use crate::store::{DatasetInfo, StoreError, now};

fn info(r: &rusqlite::Row<'_>) -> rusqlite::Result<DatasetInfo> {
    Ok(DatasetInfo {
        id: r.get(0)?,
        name: r.get(1)?,
        media_type: r.get(2)?,
        size: r.get(3)?,
        created_at: r.get(4)?,
    })
}

impl Datasets for Sqlite {
    fn insert_dataset(
        &self,
        id: &str,
        name: &str,
        media_type: &str,
        content: &[u8],
    ) -> Result<(), StoreError> {
        self.write(|c| {
            c.prepare_cached(
                "INSERT OR IGNORE INTO datasets (id, name, media_type, size, created_at, content) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
            )?
            .execute(params![
                id,
                name,
                media_type,
                content.len() as i64,
                now(),
                content
            ])?;
            Ok(())
        })
    }

    fn dataset_info(&self, id: &str) -> Result<Option<DatasetInfo>, StoreError> {
        self.read(|c| {
            Ok(c.prepare_cached(
                "SELECT id, name, media_type, size, created_at FROM datasets WHERE id = ?1",
            )?
            .query_row([id], info)
            .optional()?)
        })
    }

    fn dataset(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError> {
        self.read(|c| {
            Ok(
                c.prepare_cached("SELECT content FROM datasets WHERE id = ?1")?
                    .query_row([id], |r| r.get(0))
                    .optional()?,
            )
        })
    }

    fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT id, name, media_type, size, created_at FROM datasets ORDER BY created_at DESC, id",
            )?;
            let rows = st.query_map([], info)?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    fn dataset_to_writer(
        &self,
        id: &str,
        out: &mut dyn std::io::Write,
        path: &Path,
    ) -> Result<bool, StoreError> {
        self.read(|c| {
            let row: Option<i64> = c
                .prepare_cached("SELECT rowid FROM datasets WHERE id = ?1")?
                .query_row([id], |r| r.get(0))
                .optional()?;
            let Some(rowid) = row else {
                return Ok(false);
            };
            let mut blob = c.blob_open(MAIN_DB, "datasets", "content", rowid, true)?;
            let mut buf = vec![0u8; CHUNK];
            loop {
                let n = blob.read(&mut buf).map_err(io_err(path))?;
                if n == 0 {
                    break;
                }
                out.write_all(&buf[..n]).map_err(io_err(path))?;
            }
            Ok(true)
        })
    }
}
