//! The report's campaign journal: every measured (or skipped) configuration as the
//! campaign stored it, one row per entry. Every number carries `data-journal` (its JSON
//! pointer into the journal's entries), as the result's numbers carry `data-pointer`.

use std::fmt::Write;

use serde_json::Value;

use super::{number, text};
use crate::report::svg::escape;

/// A journal number as the table shows it: an integer (a ball, a count) as written,
/// anything else with [`number`]'s 4 significant digits.
pub fn journal_number(n: &serde_json::Number) -> String {
    if n.is_i64() || n.is_u64() {
        return n.to_string();
    }
    n.as_f64().map_or_else(|| n.to_string(), number)
}

/// A journal value as a table cell: numbers formatted (with their pointer), arrays of
/// numbers joined, anything else as compact JSON. A `ball` is stored from 0 and shown from
/// 1, as the results and the page count balls (`data-from-one` marks the shifted cell).
fn cell(column: &str, v: &Value, pointer: &str) -> String {
    match v {
        Value::Number(n) if column == "ball" && n.is_u64() => format!(
            r#"<td class="num" data-journal="{}" data-from-one="">{}</td>"#,
            escape(pointer),
            n.as_u64().unwrap_or(0) + 1
        ),
        Value::Number(n) => match n.as_f64() {
            Some(_) => format!(
                r#"<td class="num" data-journal="{}">{}</td>"#,
                escape(pointer),
                journal_number(n)
            ),
            None => format!("<td>{}</td>", escape(&n.to_string())),
        },
        Value::Array(a) if a.iter().all(Value::is_number) => format!(
            "<td>{}</td>",
            a.iter()
                .filter_map(Value::as_number)
                .map(journal_number)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        other => format!("<td>{}</td>", text(Some(other))),
    }
}

/// The journal section (empty for a job that measured nothing): `entries` are the stored
/// journal entries (`index`, `status`, `data`) in index order.
pub(super) fn journal(entries: &[Value]) -> String {
    if entries.is_empty() {
        return String::new();
    }
    // Columns: the data fields in order of first appearance.
    let mut columns: Vec<String> = Vec::new();
    for e in entries {
        if let Some(o) = e.get("data").and_then(Value::as_object) {
            for k in o.keys() {
                if !columns.contains(k) {
                    columns.push(k.clone());
                }
            }
        }
    }
    let measured = entries
        .iter()
        .filter(|e| e.get("status").and_then(Value::as_str) == Some("measured"))
        .count();
    let mut h = format!(
        "<section><h2>Campaign measurement journal</h2><p class=\"meta\">{} entries as the campaign stored them, each before the next move: <span data-count=\"journal-measured\">{measured}</span> measured, {} skipped.</p><table class=\"journal\"><thead><tr><th>entry</th><th>status</th>",
        entries.len(),
        entries.len() - measured
    );
    let single = columns.is_empty();
    for c in &columns {
        let _ = write!(h, "<th>{}</th>", escape(c));
    }
    if single {
        h.push_str("<th>data</th>");
    }
    h.push_str("</tr></thead><tbody>");
    for (i, e) in entries.iter().enumerate() {
        let _ = write!(
            h,
            "<tr data-index=\"{}\"><td class=\"num\">{}</td><td>{}</td>",
            text(e.get("index")),
            text(e.get("index")),
            text(e.get("status"))
        );
        match e.get("data") {
            Some(Value::Object(o)) => {
                for c in &columns {
                    match o.get(c) {
                        Some(v) => h.push_str(&cell(c, v, &format!("/{i}/data/{c}"))),
                        None => h.push_str("<td></td>"),
                    }
                }
            }
            // A skip's reason (or any non-object data) spans the data columns.
            other => {
                let _ = write!(
                    h,
                    "<td colspan=\"{}\">{}</td>",
                    columns.len().max(1),
                    text(other)
                );
            }
        }
        h.push_str("</tr>");
    }
    h.push_str("</tbody></table></section>");
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn every_entry_is_a_row_and_numbers_point_into_the_journal() {
        let entries = [
            json!({"index": 0, "status": "measured", "data": {"q": [0.1, 0.2], "residual_mm": 0.0123}}),
            json!({"index": 1, "status": "skipped", "data": "ball <lost>"}),
            json!({"index": 2, "status": "measured", "data": {"residual_mm": 2.5, "ball": 3}}),
        ];
        let h = journal(&entries);
        assert_eq!(h.matches("<tr data-index=").count(), 3);
        assert!(
            h.contains(r#"data-journal="/0/data/residual_mm">0.01230<"#),
            "{h}"
        );
        assert!(h.contains(r#"data-journal="/2/data/residual_mm">2.500<"#));
        assert!(
            h.contains(r#"data-journal="/2/data/ball" data-from-one="">4<"#),
            "ball 3 as stored is ball 4 counted from 1: {h}"
        );
        assert!(h.contains("ball &lt;lost&gt;") && h.contains("<td>0.1000, 0.2000</td>"));
        assert!(h.contains(r#"data-count="journal-measured">2<"#));
        assert!(journal(&[]).is_empty());
    }
}
