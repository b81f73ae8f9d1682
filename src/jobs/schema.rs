//! JSON Schemas of the job documents, generated from the serde types each kind's `prepare`
//! parses, so that `openapi.yaml`'s `JobDocument` says what the server accepts.
//!
//! A kind's spec derives `schemars::JsonSchema` (next to `Deserialize`, so
//! `deny_unknown_fields`, defaults and doc comments carry over); its inputs typed
//! `serde_json::Value` (models, tables) take one of the hand schemas below through
//! `#[schemars(schema_with = "crate::jobs::schema::table")]`. The registry
//! ([`super::KINDS`]) holds each kind's schema; [`openapi_schemas`] turns them into
//! the `components.schemas` entries of `openapi.yaml` and [`splice_openapi`] writes those
//! into the file's generated region (`tests/openapi_jobs.rs` checks the file).

use schemars::generate::SchemaSettings;
use schemars::{Schema, SchemaGenerator, json_schema};
use serde_json::{Map, Value, json};

use super::KINDS;

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

/// Why the job documents' schemas could not be generated or written.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    /// A kind's spec does not declare `kind` (every job document has one).
    #[error("the spec of `{0}` has no `kind` property")]
    NoKindProperty(String),
    /// A type needed a `$ref` (recursive): the generated section has none.
    #[error("the job document schemas need definitions (a recursive type?): {0:?}")]
    Definitions(Vec<String>),
    /// `openapi.yaml` has no (or a broken) generated region.
    #[error(
        "openapi.yaml has no region between `{BEGIN}` and `{END}` (indented under components.schemas)"
    )]
    NoRegion,
}

/// First line of `openapi.yaml`'s generated region.
pub const BEGIN: &str = "# BEGIN generated job documents";
/// Last line of `openapi.yaml`'s generated region.
pub const END: &str = "# END generated job documents";

/// Where the per-kind schemas live in `openapi.yaml`.
const PREFIX: &str = "#/components/schemas/";

/// Name of a kind's schema under `components.schemas` (e.g. `job.serial.fk`).
pub fn schema_name(kind: &str) -> String {
    format!("job.{kind}")
}

/// The schema of one kind's document as the registry generates it: its spec's schema with
/// `kind` fixed to the kind's name and the kind's description.
fn kind_schema(
    g: &mut SchemaGenerator,
    name: &str,
    description: &str,
    schema: fn(&mut SchemaGenerator) -> Schema,
) -> Result<Value, SchemaError> {
    let mut s = schema(g).to_value();
    let obj = s
        .as_object_mut()
        .expect("a derived struct's schema is an object");
    let props = obj
        .get_mut("properties")
        .and_then(Value::as_object_mut)
        .filter(|p| p.contains_key("kind"))
        .ok_or_else(|| SchemaError::NoKindProperty(name.into()))?;
    props.insert("kind".into(), json!({"type": "string", "const": name}));
    obj.remove("title");
    obj.insert("description".into(), json!(description));
    let required = obj.entry("required").or_insert_with(|| json!([]));
    if let Some(r) = required.as_array_mut()
        && !r.contains(&json!("kind"))
    {
        r.insert(0, json!("kind"));
    }
    Ok(s)
}

/// The generated `components.schemas` entries of `openapi.yaml`: `JobDocument`, a `oneOf`
/// over the kinds discriminated by `kind`; one `job.KIND` schema per registered kind; and
/// `TimeZone`, the IANA names a schedule's `timezone` may take (those of `chrono-tz`).
pub fn openapi_schemas() -> Result<Map<String, Value>, SchemaError> {
    let mut g = SchemaSettings::draft2020_12()
        .with(|s| {
            s.inline_subschemas = true;
            s.meta_schema = None;
        })
        .into_generator();
    let mut out = Map::new();
    let mut one_of = Vec::new();
    let mut mapping = Map::new();
    let mut kinds = Map::new();
    for k in KINDS {
        let name = schema_name(k.name);
        let reference = format!("{PREFIX}{name}");
        kinds.insert(name, kind_schema(&mut g, k.name, k.description, k.schema)?);
        one_of.push(json!({"$ref": reference}));
        mapping.insert(k.name.into(), json!(reference));
    }
    let defs = g.take_definitions(true);
    if !defs.is_empty() {
        return Err(SchemaError::Definitions(defs.keys().cloned().collect()));
    }
    out.insert(
        "JobDocument".into(),
        json!({
            "description": "A job document (jobs.md): `kind` (GET /v1/kinds) selects the schema. Over HTTP, inputs are inline (a model as its JSON object or URDF text, a table as an array of row objects) or the id of an uploaded dataset. Generated from the kinds' specs (src/jobs/schema.rs).",
            "oneOf": one_of,
            "discriminator": {"propertyName": "kind", "mapping": mapping},
        }),
    );
    out.extend(kinds);
    let zones: Vec<&str> = chrono_tz::TZ_VARIANTS.iter().map(|z| z.name()).collect();
    out.insert(
        "TimeZone".into(),
        json!({"type": "string", "default": "UTC", "description": "an IANA time zone name, e.g. Europe/Berlin", "enum": zones}),
    );
    Ok(out)
}

/// `text` (an `openapi.yaml`) with its generated region holding `schemas` (as YAML,
/// indented as the region's markers are).
pub fn splice_openapi(text: &str, schemas: &Map<String, Value>) -> Result<String, SchemaError> {
    let begin = text.find(BEGIN).ok_or(SchemaError::NoRegion)?;
    let line_start = text[..begin].rfind('\n').map_or(0, |i| i + 1);
    let indent = &text[line_start..begin];
    if !indent.chars().all(|c| c == ' ') {
        return Err(SchemaError::NoRegion);
    }
    let body_start = text[begin..]
        .find('\n')
        .map(|i| begin + i + 1)
        .ok_or(SchemaError::NoRegion)?;
    let end = text[body_start..]
        .find(&format!("{indent}{END}"))
        .map(|i| body_start + i)
        .ok_or(SchemaError::NoRegion)?;
    let mut out = String::with_capacity(text.len());
    out.push_str(&text[..body_start]);
    yaml_map(&mut out, schemas, indent.len(), false);
    out.push_str(&text[end..]);
    Ok(out)
}

/// A mapping key as YAML: plain when that reads back as the same string.
fn yaml_key(k: &str) -> String {
    let plain = k
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_' || c == '$')
        && k.chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-' | '$'))
        && !matches!(
            k.to_ascii_lowercase().as_str(),
            "y" | "n" | "yes" | "no" | "on" | "off" | "true" | "false" | "null"
        );
    if plain {
        k.to_string()
    } else {
        Value::from(k).to_string()
    }
}

/// A scalar (or empty collection) as YAML flow; `None` for a non-empty collection.
fn yaml_scalar(v: &Value) -> Option<String> {
    match v {
        Value::Object(m) if m.is_empty() => Some("{}".into()),
        Value::Array(a) if a.is_empty() => Some("[]".into()),
        Value::Object(_) | Value::Array(_) => None,
        // JSON strings, numbers, booleans and null read the same in YAML.
        other => Some(other.to_string()),
    }
}

/// Block YAML of a mapping at `indent`; `inline_first`: the first key follows a `- `.
fn yaml_map(out: &mut String, m: &Map<String, Value>, indent: usize, inline_first: bool) {
    for (i, (k, v)) in m.iter().enumerate() {
        if !(inline_first && i == 0) {
            out.push_str(&" ".repeat(indent));
        }
        out.push_str(&yaml_key(k));
        out.push(':');
        yaml_value(out, v, indent);
    }
}

/// A value after `key:` at `indent` (the key's column).
fn yaml_value(out: &mut String, v: &Value, indent: usize) {
    if let Some(s) = yaml_scalar(v) {
        out.push(' ');
        out.push_str(&s);
        out.push('\n');
        return;
    }
    if let Value::Array(a) = v
        && a.iter().all(|x| yaml_scalar(x).is_some())
    {
        yaml_flow_seq(out, a, indent);
        return;
    }
    out.push('\n');
    match v {
        Value::Object(m) => yaml_map(out, m, indent + 2, false),
        Value::Array(a) => {
            for x in a {
                out.push_str(&" ".repeat(indent + 2));
                out.push('-');
                match x {
                    Value::Object(m) if !m.is_empty() => {
                        out.push(' ');
                        yaml_map(out, m, indent + 4, true);
                    }
                    Value::Array(a) if !a.is_empty() => {
                        // A sequence in a sequence: its items on the lines below.
                        let mut inner = String::new();
                        yaml_value(&mut inner, x, indent + 2);
                        out.push_str(&inner);
                    }
                    _ => {
                        out.push(' ');
                        out.push_str(&yaml_scalar(x).unwrap_or_default());
                        out.push('\n');
                    }
                }
            }
        }
        _ => unreachable!("scalars returned above"),
    }
}

/// A sequence of scalars in flow style (`[a, b]`), wrapped before 100 columns; continuation
/// lines are indented past the key at `indent`.
fn yaml_flow_seq(out: &mut String, a: &[Value], indent: usize) {
    let mut line = indent + 4;
    out.push_str(" [");
    for (i, x) in a.iter().enumerate() {
        let item = yaml_scalar(x).unwrap_or_default();
        if i > 0 {
            out.push(',');
            if line + item.len() + 2 > 100 {
                out.push('\n');
                out.push_str(&" ".repeat(indent + 4));
                line = indent + 4;
            } else {
                out.push(' ');
            }
        }
        out.push_str(&item);
        line += item.len() + 2;
    }
    out.push_str("]\n");
}
