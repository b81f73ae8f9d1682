//! Joint columns read row by row: where `q1..qN` sit in a table's columns, the factors from
//! the model's file units to its internal ones, and the limit check, shared by whole tables
//! ([`SerialModel::joints`]) and streamed ones (`serial.fk` over a CSV file).

use super::SerialModel;
use crate::run::JobError;

/// The joint columns of one table for one model.
#[derive(Debug, Clone)]
pub struct JointColumns {
    field: String,
    /// Index of `q1..qN` in the table's columns.
    index: Vec<usize>,
    /// Per joint: internal value per file unit (1/deg -> rad, 1 for SI).
    to_internal: Vec<f64>,
}

impl JointColumns {
    /// Locate the model's joint columns among `columns` of input `field`; an error names
    /// the first missing one.
    pub fn new(model: &SerialModel, field: &str, columns: &[String]) -> Result<Self, JobError> {
        let index = model
            .joint_columns()
            .iter()
            .map(|name| {
                columns.iter().position(|c| c == name).ok_or_else(|| {
                    JobError::invalid(
                        field,
                        format!("missing column `{name}` (columns are {columns:?})"),
                    )
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let to_internal = (0..index.len())
            .map(|k| 1.0 / model.chain.units.to_file(model.chain.variable_quantity(k)))
            .collect();
        Ok(Self {
            field: field.to_string(),
            index,
            to_internal,
        })
    }

    /// The joint values of table row `values` (row number `row`, from 1) into `q`, in the
    /// chain's internal units, checked against the model's limits.
    pub fn read(
        &self,
        model: &SerialModel,
        row: usize,
        values: &[f64],
        q: &mut Vec<f64>,
    ) -> Result<(), JobError> {
        q.clear();
        q.extend(
            self.index
                .iter()
                .zip(&self.to_internal)
                .map(|(&c, k)| values[c] * k),
        );
        if let Some((j, v, l)) = model.chain.limit_violation(q) {
            let u = 1.0 / self.to_internal[j];
            return Err(JobError::row(
                &self.field,
                row,
                format!(
                    "q{} = {} {} is outside the joint limits [{}, {}]",
                    j + 1,
                    v * u,
                    model.joint_unit(j),
                    l[0] * u,
                    l[1] * u
                ),
            ));
        }
        Ok(())
    }
}
