//! Datasets: uploaded inputs (CSV tables, model files), named by the SHA-256 of their
//! content so an upload is idempotent and a job's input hash names the dataset.

use rusqlite::{OptionalExtension, params};
use serde::Serialize;

use super::{Store, StoreError, now};

/// A dataset's description.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetInfo {
    /// Id: the hex SHA-256 of the content.
    pub id: String,
    /// Name given at upload (e.g. the file name).
    pub name: String,
    /// Media type given at upload.
    pub media_type: String,
    /// Size in bytes.
    pub size: i64,
    /// When it was first uploaded.
    pub created_at: String,
}

impl Store {
    /// Store a dataset (no-op if the same content exists); returns its description.
    pub fn put_dataset(
        &self,
        name: &str,
        media_type: &str,
        content: &[u8],
    ) -> Result<DatasetInfo, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.put_dataset(name, media_type, content);
        }
        let id = crate::run::input::sha256_hex(content);
        self.write(|c| {
            c.execute(
                "INSERT OR IGNORE INTO datasets (id, name, media_type, size, created_at, content) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![id, name, media_type, content.len() as i64, now(), content],
            )?;
            Ok(())
        })?;
        self.dataset_info(&id)?
            .ok_or_else(|| StoreError::Conflict(format!("dataset {id} vanished")))
    }

    /// A dataset's description.
    pub fn dataset_info(&self, id: &str) -> Result<Option<DatasetInfo>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.dataset_info(id);
        }
        self.read(|c| {
            Ok(c.query_row(
                "SELECT id, name, media_type, size, created_at FROM datasets WHERE id = ?1",
                [id],
                |r| {
                    Ok(DatasetInfo {
                        id: r.get(0)?,
                        name: r.get(1)?,
                        media_type: r.get(2)?,
                        size: r.get(3)?,
                        created_at: r.get(4)?,
                    })
                },
            )
            .optional()?)
        })
    }

    /// A dataset's content.
    pub fn dataset(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.dataset(id);
        }
        self.read(|c| {
            Ok(
                c.query_row("SELECT content FROM datasets WHERE id = ?1", [id], |r| {
                    r.get(0)
                })
                .optional()?,
            )
        })
    }

    /// Every dataset, newest first.
    pub fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.datasets();
        }
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT id, name, media_type, size, created_at FROM datasets ORDER BY created_at DESC, id",
            )?;
            let rows = st.query_map(params![], |r| {
                Ok(DatasetInfo {
                    id: r.get(0)?,
                    name: r.get(1)?,
                    media_type: r.get(2)?,
                    size: r.get(3)?,
                    created_at: r.get(4)?,
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }
}
