//! Datasets: uploaded inputs (CSV tables, model files), named by the SHA-256 of their
//! content so an upload is idempotent and a job's input hash names the dataset.

use serde::Serialize;

use super::{Store, StoreError};

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
        let id = crate::run::input::sha256_hex(content);
        self.backend
            .insert_dataset(&id, name, media_type, content)?;
        self.dataset_info(&id)?
            .ok_or_else(|| StoreError::Conflict(format!("dataset {id} vanished")))
    }

    /// A dataset's description.
    pub fn dataset_info(&self, id: &str) -> Result<Option<DatasetInfo>, StoreError> {
        self.backend.dataset_info(id)
    }

    /// A dataset's content.
    pub fn dataset(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError> {
        self.backend.dataset(id)
    }

    /// Every dataset, newest first.
    pub fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError> {
        self.backend.datasets()
    }
}
