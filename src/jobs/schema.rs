//! JSON Schemas of the job documents, generated from the serde types each kind's `prepare`
//! parses, so that `openapi.yaml`'s `JobDocument` says what the server accepts.
//!
//! A kind's spec derives `schemars::JsonSchema` (next to `Deserialize`, so
//! `deny_unknown_fields`, defaults and doc comments carry over); its inputs typed
//! `serde_json::Value` (models, tables) take one of the hand schemas of [`crate::run::schema`] through
//! `#[schemars(schema_with = "crate::run::schema::table")]`. The registry
//! ([`super::KINDS`]) holds each kind's schema; [`openapi_schemas`] turns them into
//! the `components.schemas` entries of `openapi.yaml` and [`splice_openapi`] writes those
//! into the file's generated region (`tests/it/openapi_jobs.rs` checks the file).

use schemars::generate::SchemaSettings;
use schemars::{Schema, SchemaGenerator};
use serde_json::{Map, Value, json};

use super::KINDS;

/// Why the job documents' schemas could not be generated or written.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    /// A kind's spec is not an object schema declaring `kind` (every job document has one).
    #[error("the spec of `{0}` is not an object with a `kind` property")]
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
    drop_number_formats(&mut s);
    let obj = s
        .as_object_mut()
        .ok_or_else(|| SchemaError::NoKindProperty(name.into()))?;
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

/// The generator of the kinds' schemas: JSON Schema 2020-12 (OpenAPI 3.1 and 3.2), every
/// subschema inline.
fn generator() -> SchemaGenerator {
    SchemaSettings::draft2020_12()
        .with(|s| {
            s.inline_subschemas = true;
            s.meta_schema = None;
        })
        .into_generator()
}

/// Remove schemars' `format` of numbers (`double`, `uint`, `uint64`, ...): no OpenAPI tool
/// checks Rust's integer widths, and `minimum: 0` already says unsigned. The widths below
/// 64 bits become a `maximum`.
fn drop_number_formats(v: &mut Value) {
    match v {
        Value::Object(m) => {
            let max = match m.get("format").and_then(Value::as_str) {
                Some("uint8") => Some(json!(u8::MAX)),
                Some("uint16") => Some(json!(u16::MAX)),
                Some("uint32") => Some(json!(u32::MAX)),
                _ => None,
            };
            let numeric = m
                .get("format")
                .and_then(Value::as_str)
                .is_some_and(|f| matches!(f, "double" | "float") || f.starts_with("uint"));
            if numeric {
                m.remove("format");
            }
            if let Some(max) = max {
                m.entry("maximum").or_insert(max);
            }
            m.values_mut().for_each(drop_number_formats);
        }
        Value::Array(a) => a.iter_mut().for_each(drop_number_formats),
        _ => {}
    }
}

/// The generated `components.schemas` entries of `openapi.yaml`: `JobDocument`, a `oneOf`
/// over the kinds discriminated by `kind`; one `job.KIND` schema per registered kind; and
/// `TimeZone`, the IANA names a schedule's `timezone` may take (those of `chrono-tz`).
pub fn openapi_schemas() -> Result<Map<String, Value>, SchemaError> {
    let mut g = generator();
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

/// Each registered kind's document schema, generated once per process.
fn kind_schemas() -> &'static Map<String, Value> {
    static SCHEMAS: std::sync::OnceLock<Map<String, Value>> = std::sync::OnceLock::new();
    SCHEMAS.get_or_init(|| {
        let mut g = generator();
        KINDS
            .iter()
            .filter_map(|k| {
                let s = kind_schema(&mut g, k.name, k.description, k.schema).ok()?;
                Some((k.name.to_string(), s))
            })
            .collect()
    })
}

/// Whether `schema` admits a JSON value of type `t` (`object`, `array`, ...).
fn admits(schema: &Value, t: &str) -> bool {
    let Some(m) = schema.as_object() else {
        return schema != &Value::Bool(false);
    };
    let alternatives = ["anyOf", "oneOf"]
        .iter()
        .filter_map(|k| m.get(*k).and_then(Value::as_array))
        .flatten()
        .collect::<Vec<_>>();
    match m.get("type") {
        Some(Value::String(s)) => s == t,
        Some(Value::Array(ts)) => ts.iter().any(|x| x == t),
        _ if !alternatives.is_empty() => alternatives.iter().any(|a| admits(a, t)),
        _ => true,
    }
}

/// The path of an array in `doc` where `schema` only admits an object, if any. serde reads
/// a struct from an array of its fields in order (`"options": [null, 2]`); the documents
/// and `openapi.yaml` do not have that form, so [`check_document`] refuses it.
fn array_for_object(schema: &Value, doc: &Value, path: &str) -> Option<String> {
    let here = || {
        if path.is_empty() {
            "job".to_string()
        } else {
            path.to_string()
        }
    };
    let m = schema.as_object()?;
    let alternatives: Vec<&Value> = ["anyOf", "oneOf"]
        .iter()
        .filter_map(|k| m.get(*k).and_then(Value::as_array))
        .flatten()
        .collect();
    match doc {
        Value::Array(items) => {
            if !admits(schema, "array") {
                return admits(schema, "object").then(here);
            }
            if m.get("type").is_none() && !alternatives.is_empty() {
                // The alternatives that take an array: the first under which all is well.
                let mut first = None;
                for a in alternatives.iter().filter(|a| admits(a, "array")) {
                    match array_for_object(a, doc, path) {
                        None => return None,
                        Some(p) => first = first.or(Some(p)),
                    }
                }
                return first;
            }
            let prefix = m.get("prefixItems").and_then(Value::as_array);
            items.iter().enumerate().find_map(|(i, x)| {
                let s = prefix.and_then(|p| p.get(i)).or_else(|| m.get("items"))?;
                array_for_object(s, x, &format!("{path}[{i}]"))
            })
        }
        Value::Object(fields) => {
            if m.get("type").is_none() && !alternatives.is_empty() {
                let mut first = None;
                for a in alternatives.iter().filter(|a| admits(a, "object")) {
                    match array_for_object(a, doc, path) {
                        None => return None,
                        Some(p) => first = first.or(Some(p)),
                    }
                }
                return first;
            }
            let props = m.get("properties").and_then(Value::as_object);
            fields.iter().find_map(|(k, x)| {
                let s = props
                    .and_then(|p| p.get(k))
                    .or_else(|| m.get("additionalProperties"))?;
                let at = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                array_for_object(s, x, &at)
            })
        }
        _ => None,
    }
}

/// Refuse a document of `kind` where an object is given as an array (see
/// [`array_for_object`]); serde's own errors cover the rest.
pub fn check_document(kind: &str, doc: &Value) -> Result<(), super::JobError> {
    let Some(schema) = kind_schemas().get(kind) else {
        return Ok(());
    };
    match array_for_object(schema, doc, "") {
        None => Ok(()),
        Some(at) => Err(super::JobError::invalid(
            at,
            "expected an object, not an array",
        )),
    }
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

/// Widest line the generated YAML writes on one line (flow style) before it breaks it up.
const WIDTH: usize = 100;

/// `v` in YAML flow style on one line (`{type: "number"}`, `["a", "b"]`).
fn yaml_flow(v: &Value) -> String {
    match v {
        Value::Object(m) if !m.is_empty() => {
            let items: Vec<String> = m
                .iter()
                .map(|(k, x)| format!("{}: {}", yaml_key(k), yaml_flow(x)))
                .collect();
            format!("{{{}}}", items.join(", "))
        }
        Value::Array(a) if !a.is_empty() => {
            let items: Vec<String> = a.iter().map(yaml_flow).collect();
            format!("[{}]", items.join(", "))
        }
        other => yaml_scalar(other).unwrap_or_default(),
    }
}

/// Block YAML of a mapping at `indent`; `inline_first`: the first key follows a `- `.
fn yaml_map(out: &mut String, m: &Map<String, Value>, indent: usize, inline_first: bool) {
    for (i, (k, v)) in m.iter().enumerate() {
        if !(inline_first && i == 0) {
            out.push_str(&" ".repeat(indent));
        }
        let key = yaml_key(k);
        out.push_str(&key);
        out.push(':');
        yaml_value(out, v, indent, indent + key.len() + 2);
    }
}

/// A value after `key:` at `indent` (the key's column); `column`: where the value starts.
fn yaml_value(out: &mut String, v: &Value, indent: usize, column: usize) {
    let flow = yaml_flow(v);
    if column + flow.len() <= WIDTH || yaml_scalar(v).is_some() {
        out.push(' ');
        out.push_str(&flow);
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
                let flow = yaml_flow(x);
                match x {
                    _ if indent + 4 + flow.len() <= WIDTH => {
                        out.push(' ');
                        out.push_str(&flow);
                        out.push('\n');
                    }
                    Value::Object(m) => {
                        out.push(' ');
                        yaml_map(out, m, indent + 4, true);
                    }
                    // A long sequence in a sequence: its items on the lines below.
                    _ => yaml_value(out, x, indent + 2, WIDTH),
                }
            }
        }
        _ => unreachable!("scalars are written in flow style above"),
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
