//! Hand-written JSON Schemas of the inputs a job spec types as `serde_json::Value` (models,
//! tables, files): a spec field takes one through
//! `#[schemars(schema_with = "crate::run::schema::table")]`. The registry's schema module
//! ([`crate::jobs::schema`]) assembles each kind's document schema from them.

use schemars::{Schema, SchemaGenerator, json_schema};
use serde_json::{Value, json};

/// The id of an uploaded dataset (`POST /v1/datasets`): the hex SHA-256 of its content.
fn dataset_id() -> Value {
    json!({
        "type": "string",
        "pattern": "^[0-9a-f]{64}$",
        "description": "the id of an uploaded dataset (POST /v1/datasets); `calibd run` takes a file name relative to the job file",
    })
}

/// `schema` or `null` (an `Option` field: `null` is the same as leaving it out).
fn nullable(schema: Value) -> Schema {
    json_schema!({"anyOf": [schema, {"type": "null"}]})
}

fn rows(cell: Value) -> Value {
    json!({
        "type": "array",
        "description": "rows: objects keyed by column name",
        "items": {"type": "object", "additionalProperties": cell},
    })
}

fn table_value() -> Value {
    json!({"anyOf": [rows(json!({"type": "number"})), dataset_id()]})
}

fn table_with_gaps_value() -> Value {
    json!({
        "anyOf": [rows(json!({"type": ["number", "null"]})), dataset_id()],
        "description": "marker columns may hold null (a marker not seen in that sample)",
    })
}

fn json_file_value() -> Value {
    json!({"anyOf": [{"type": "object", "description": "the file's JSON inline"}, dataset_id()]})
}

fn urdf_value() -> Value {
    json!({"anyOf": [
        {"type": "string", "pattern": "^\\s*<", "description": "URDF text inline"},
        dataset_id(),
    ]})
}

/// A table input: inline rows or a CSV dataset.
pub fn table(_: &mut SchemaGenerator) -> Schema {
    Schema::try_from(table_value()).expect("an object")
}

/// An optional table input.
pub fn table_opt(_: &mut SchemaGenerator) -> Schema {
    nullable(table_value())
}

/// A table whose marker columns admit `null` (humanoid samples).
pub fn table_with_gaps(_: &mut SchemaGenerator) -> Schema {
    Schema::try_from(table_with_gaps_value()).expect("an object")
}

/// A JSON file input (a 3-PF model, a calibrated result): inline object or a dataset.
pub fn json_file(_: &mut SchemaGenerator) -> Schema {
    Schema::try_from(json_file_value()).expect("an object")
}

/// An optional JSON file input.
pub fn json_file_opt(_: &mut SchemaGenerator) -> Schema {
    nullable(json_file_value())
}

/// A URDF input: text inline or a dataset.
pub fn urdf(_: &mut SchemaGenerator) -> Schema {
    Schema::try_from(urdf_value()).expect("an object")
}

/// An optional URDF input (an SRDF is given the same way).
pub fn urdf_opt(_: &mut SchemaGenerator) -> Schema {
    nullable(urdf_value())
}

/// A serial model: a DH model or DH tree file (inline JSON or dataset) or URDF text inline
/// (a URDF dataset is not recognised as one: its id has no `.urdf` to tell).
pub fn serial_model(_: &mut SchemaGenerator) -> Schema {
    json_schema!({"anyOf": [
        {"type": "object", "description": "a DH model file, or a DH tree file (`\"kind\": \"tree\"`, with `chain.name`)"},
        {"type": "string", "pattern": "^\\s*<", "description": "URDF text inline (with `chain.root` and `chain.tip`)"},
        dataset_id(),
    ]})
}
