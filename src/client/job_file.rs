//! The files a job file names, found at any depth of its document (`model`, `twin.model`,
//! `images[3]`, `constraints.srdf`), to upload as datasets before submitting it.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::looks_like_file;

/// A string of the job document that names a file in the job file's folder.
#[derive(Debug, Clone, PartialEq)]
pub struct FileRef {
    /// The field, as job errors name it (`twin.model`, `images[0]`).
    pub field: String,
    /// JSON pointer of the string in the document, to replace it by the dataset id.
    pub pointer: String,
    /// The file.
    pub path: PathBuf,
}

/// The references of a job document whose paths (relative to `dir`) exist, and the
/// descriptions (`` `field`: name (path) ``) of those that name files that do not.
///
/// A top-level string (but `kind`) is a file when the file exists, and reported missing
/// when it looks like a file name (see [`looks_like_file`]). Deeper strings are taken only
/// when they look like file names, and reported missing only when they end in a file
/// extension, so that inline values such as the unit `deg/(N*m)` are left alone. Inline
/// XML (URDF text) is never a reference. References inside the referenced files are not
/// followed: the daemon cannot resolve them (give such inputs in the job document).
pub fn file_references(doc: &Value, dir: &Path) -> (Vec<FileRef>, Vec<String>) {
    let mut found = Vec::new();
    let mut missing = Vec::new();
    if let Value::Object(m) = doc {
        for (k, v) in m {
            if k != "kind" {
                walk(
                    v,
                    k,
                    &format!("/{}", escape(k)),
                    true,
                    dir,
                    &mut found,
                    &mut missing,
                );
            }
        }
    }
    (found, missing)
}

fn walk(
    v: &Value,
    field: &str,
    pointer: &str,
    top: bool,
    dir: &Path,
    found: &mut Vec<FileRef>,
    missing: &mut Vec<String>,
) {
    match v {
        Value::String(s) => {
            if s.trim_start().starts_with('<') || !(top || looks_like_file(s)) {
                return;
            }
            let path = dir.join(s);
            if path.is_file() {
                found.push(FileRef {
                    field: field.to_string(),
                    pointer: pointer.to_string(),
                    path,
                });
            } else if looks_like_file(s) && (top || has_file_extension(s)) {
                missing.push(format!("`{field}`: {s} ({})", path.display()));
            }
        }
        Value::Object(m) => {
            for (k, x) in m {
                let f = format!("{field}.{k}");
                let p = format!("{pointer}/{}", escape(k));
                walk(x, &f, &p, false, dir, found, missing);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                let f = format!("{field}[{i}]");
                let p = format!("{pointer}/{i}");
                walk(x, &f, &p, false, dir, found, missing);
            }
        }
        _ => {}
    }
}

/// A JSON pointer token (RFC 6901: `~` as `~0`, `/` as `~1`).
fn escape(k: &str) -> String {
    k.replace('~', "~0").replace('/', "~1")
}

/// Whether `s` ends in an extension of the files jobs read.
fn has_file_extension(s: &str) -> bool {
    Path::new(s.trim())
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| FILE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Extensions of the files jobs read: tables, models, settings, images.
pub(crate) const FILE_EXTENSIONS: &[&str] = &[
    "csv", "json", "urdf", "xml", "srdf", "toml", "txt", "tsv", "png", "tif", "tiff",
];

/// The media type a file is uploaded with, from its extension.
pub fn media_type(path: &Path) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("csv") => "text/csv",
        Some("json") => "application/json",
        Some("urdf" | "xml" | "srdf") => "application/xml",
        Some("png") => "image/png",
        Some("tif" | "tiff") => "image/tiff",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn references_are_found_at_any_depth_and_inline_values_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        for f in ["robot.urdf", "twin.json", "a.png", "b.png", "rows.csv"] {
            std::fs::write(dir.path().join(f), "x").unwrap();
        }
        let doc = json!({
            "kind": "serial.fk",
            "model": "robot.urdf",
            "joints": "rows.csv",
            "twin": {"model": "twin.json", "seed": 1},
            "images": ["a.png", "b.png"],
            "units": {"compliance": "deg/(N*m)"},
            "chain": {"root": "base", "tip": "tool"},
            "inline": "<robot name=\"r\"/>",
            "nested": [{"file": "gone.csv"}],
            "absent": "gone.json"
        });
        let (found, missing) = file_references(&doc, dir.path());
        let mut got: Vec<(&str, &str)> = found
            .iter()
            .map(|r| (r.field.as_str(), r.pointer.as_str()))
            .collect();
        got.sort();
        assert_eq!(
            got,
            vec![
                ("images[0]", "/images/0"),
                ("images[1]", "/images/1"),
                ("joints", "/joints"),
                ("model", "/model"),
                ("twin.model", "/twin/model"),
            ]
        );
        for r in &found {
            assert_eq!(
                doc.pointer(&r.pointer),
                Some(&json!(r.path.file_name().unwrap().to_str().unwrap()))
            );
        }
        let mut missing = missing;
        missing.sort();
        assert_eq!(missing.len(), 2, "{missing:?}");
        assert!(missing[0].starts_with("`absent`: gone.json"), "{missing:?}");
        assert!(
            missing[1].starts_with("`nested[0].file`: gone.csv"),
            "{missing:?}"
        );
    }

    #[test]
    fn pointer_tokens_are_escaped() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.json"), "{}").unwrap();
        let doc = json!({"a/b": {"c~d": "m.json"}});
        let (found, _) = file_references(&doc, dir.path());
        assert_eq!(found[0].pointer, "/a~1b/c~0d");
        assert_eq!(doc.pointer(&found[0].pointer), Some(&json!("m.json")));
    }
}
