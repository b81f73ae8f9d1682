//! The OpenAPI contract: `openapi.yaml` parsed into JSON, and a checker for the subset of
//! JSON Schema it uses (type incl. nullable unions, required, properties,
//! additionalProperties, items, enum, const, anyOf, oneOf, minimum/maximum,
//! exclusiveMinimum, minLength, pattern, minItems/maxItems, $ref).

use serde_json::Value;

/// The contract as JSON.
pub fn contract() -> Value {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml")).unwrap();
    yaml_serde::from_str(&text).unwrap()
}

fn resolve<'a>(root: &'a Value, s: &'a Value) -> &'a Value {
    match s.get("$ref").and_then(Value::as_str) {
        Some(r) => {
            let p = r.trim_start_matches('#');
            resolve(
                root,
                root.pointer(p)
                    .unwrap_or_else(|| panic!("dangling $ref {r}")),
            )
        }
        None => s,
    }
}

fn type_ok(t: &str, v: &Value) -> bool {
    match t {
        "object" => v.is_object(),
        "array" => v.is_array(),
        "string" => v.is_string(),
        "integer" => v.is_i64() || v.is_u64(),
        "number" => v.is_number(),
        "boolean" => v.is_boolean(),
        "null" => v.is_null(),
        _ => true,
    }
}

/// Errors of `v` against schema `s` (empty: valid).
pub fn check(root: &Value, s: &Value, v: &Value, at: &str) -> Vec<String> {
    let s = resolve(root, s);
    let mut errs = Vec::new();
    match s.get("type") {
        Some(Value::String(t)) if !type_ok(t, v) => {
            errs.push(format!("{at}: expected {t}, got {v}"))
        }
        Some(Value::Array(ts)) if !ts.iter().any(|t| type_ok(t.as_str().unwrap_or(""), v)) => {
            errs.push(format!("{at}: expected one of {ts:?}, got {v}"))
        }
        _ => {}
    }
    if !errs.is_empty() {
        return errs;
    }
    if let Some(c) = s.get("const")
        && c != v
    {
        errs.push(format!("{at}: {v} is not {c}"));
    }
    if let Some(alts) = s.get("anyOf").and_then(Value::as_array)
        && !alts.iter().any(|a| check(root, a, v, at).is_empty())
    {
        errs.push(format!("{at}: {v} matches none of anyOf"));
    }
    if let Some(alts) = s.get("oneOf").and_then(Value::as_array) {
        let fails: Vec<Vec<String>> = alts.iter().map(|a| check(root, a, v, at)).collect();
        match fails.iter().filter(|f| f.is_empty()).count() {
            1 => {}
            0 => {
                // The alternative whose discriminator matches explains best why.
                let best = fails
                    .iter()
                    .min_by_key(|f| f.len())
                    .cloned()
                    .unwrap_or_default();
                errs.push(format!("{at}: matches none of oneOf ({})", best.join("; ")));
            }
            n => errs.push(format!("{at}: matches {n} alternatives of oneOf")),
        }
    }
    if let (Some(min), Some(x)) = (
        s.get("exclusiveMinimum").and_then(Value::as_f64),
        v.as_f64(),
    ) && x <= min
    {
        errs.push(format!("{at}: {x} <= exclusiveMinimum {min}"));
    }
    if let Some(x) = v.as_str() {
        if let Some(min) = s.get("minLength").and_then(Value::as_u64)
            && (x.chars().count() as u64) < min
        {
            errs.push(format!("{at}: {x:?} shorter than {min}"));
        }
        if let Some(p) = s.get("pattern").and_then(Value::as_str)
            && !regex::Regex::new(p)
                .unwrap_or_else(|e| panic!("pattern {p}: {e}"))
                .is_match(x)
        {
            errs.push(format!("{at}: {x:?} does not match {p}"));
        }
    }
    if let Some(a) = v.as_array() {
        if let Some(min) = s.get("minItems").and_then(Value::as_u64)
            && (a.len() as u64) < min
        {
            errs.push(format!("{at}: fewer than {min} items"));
        }
        if let Some(max) = s.get("maxItems").and_then(Value::as_u64)
            && (a.len() as u64) > max
        {
            errs.push(format!("{at}: more than {max} items"));
        }
    }
    if let Some(e) = s.get("enum").and_then(Value::as_array)
        && !e.contains(v)
    {
        errs.push(format!("{at}: {v} not in {e:?}"));
    }
    if let (Some(min), Some(x)) = (s.get("minimum").and_then(Value::as_f64), v.as_f64())
        && x < min
    {
        errs.push(format!("{at}: {x} < minimum {min}"));
    }
    if let (Some(max), Some(x)) = (s.get("maximum").and_then(Value::as_f64), v.as_f64())
        && x > max
    {
        errs.push(format!("{at}: {x} > maximum {max}"));
    }
    if let Some(o) = v.as_object() {
        let props = s.get("properties").and_then(Value::as_object);
        for r in s
            .get("required")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            let k = r.as_str().unwrap_or("");
            if !o.contains_key(k) {
                errs.push(format!("{at}: missing required `{k}`"));
            }
        }
        for (k, x) in o {
            match props.and_then(|p| p.get(k)) {
                Some(ps) => errs.extend(check(root, ps, x, &format!("{at}.{k}"))),
                None => match s.get("additionalProperties") {
                    Some(Value::Bool(false)) => {
                        errs.push(format!("{at}: undocumented property `{k}`"))
                    }
                    Some(ap @ Value::Object(_)) => {
                        errs.extend(check(root, ap, x, &format!("{at}.{k}")))
                    }
                    _ => {}
                },
            }
        }
    }
    if let (Some(items), Some(a)) = (s.get("items"), v.as_array()) {
        for (i, x) in a.iter().enumerate() {
            errs.extend(check(root, items, x, &format!("{at}[{i}]")));
        }
    }
    errs
}

/// The documented JSON schema for a response (`status`, else `default`), or why there is none.
pub fn response_schema<'a>(
    root: &'a Value,
    method: &str,
    path: &str,
    status: u16,
) -> Result<&'a Value, String> {
    let op = root
        .pointer(&format!(
            "/paths/{}/{}",
            path.replace('~', "~0").replace('/', "~1"),
            method
        ))
        .ok_or_else(|| format!("{method} {path} is not in openapi.yaml"))?;
    let resp = op["responses"]
        .get(status.to_string())
        .or_else(|| op["responses"].get("default"))
        .ok_or_else(|| format!("{method} {path}: status {status} is not documented"))?;
    let resp = resolve(root, resp);
    resp.pointer("/content/application~1json/schema")
        .ok_or_else(|| format!("{method} {path} {status}: no application/json schema"))
}

/// Assert that a JSON response matches the contract.
pub fn assert_response(root: &Value, method: &str, path: &str, status: u16, body: &Value) {
    let s = response_schema(root, method, path, status).unwrap_or_else(|e| panic!("{e}"));
    let errs = check(root, s, body, "$");
    assert!(
        errs.is_empty(),
        "{method} {path} {status} disagrees with openapi.yaml:\n{}\nbody: {body}",
        errs.join("\n")
    );
}
