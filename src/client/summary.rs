//! The summary a person reads when a job ends (`calibd submit --watch`, `watch`, `run`):
//! the headline figures, the verdict with its reasons, what "before" was, warnings.

use serde_json::Value;

fn stats_line(name: &str, v: &Value) -> Option<String> {
    let b = v.get("before")?;
    let a = v.get("after")?;
    let unit = a.get("unit").and_then(Value::as_str).unwrap_or("");
    let f = |x: &Value, k: &str| {
        x.get(k)
            .and_then(Value::as_f64)
            .map_or("-".into(), |v| format!("{v:.4}"))
    };
    Some(format!(
        "{name:<11} mean {} -> {} {unit}, max {} -> {} {unit}",
        f(b, "mean"),
        f(a, "mean"),
        f(b, "max"),
        f(a, "max")
    ))
}

/// Print the headline figures of a result.
pub fn print_summary(r: &Value) {
    for l in summary_lines(r) {
        println!("{l}");
    }
}

/// The headline figures of a result, as lines: kind and time, the verdict with its
/// reasons, what "before" is, parameters identified, before/after errors, warnings.
pub fn summary_lines(r: &Value) -> Vec<String> {
    let mut out = vec![format!(
        "{} finished in {:.2} s",
        r["kind"].as_str().unwrap_or("?"),
        r["duration_s"].as_f64().unwrap_or(0.0)
    )];
    if let Some(v) = r["verdict"].as_str() {
        out.push(format!("verdict: {v}"));
        for x in r["reasons"].as_array().into_iter().flatten() {
            out.push(format!(
                "  {} ({}): {}",
                x["code"].as_str().unwrap_or_default(),
                x["severity"].as_str().unwrap_or_default(),
                x["message"].as_str().unwrap_or_default()
            ));
        }
    }
    if let Some(s) = r["started_from"].as_str().filter(|s| !s.is_empty()) {
        out.push(format!("before = {s}"));
    }
    if let Some(p) = r["parameters"]
        .as_array()
        .filter(|p| p.iter().all(Value::is_object))
    {
        let identified = p
            .iter()
            .filter(|x| x["identifiable"].as_bool().unwrap_or(true))
            .count();
        out.push(format!(
            "{identified} of {} parameters identified ({} held)",
            p.len(),
            p.len() - identified
        ));
    }
    let mm = |k: &str| r[k].as_f64().map(|v| format!("{v:.4}"));
    if let (Some(b), Some(a)) = (mm("rmse_before_mm"), mm("rmse_after_mm")) {
        out.push(format!("marker RMSE {b} -> {a} mm"));
    }
    let cv = &r["cross_validation"];
    if let (Some(b), Some(a)) = (
        cv["rmse_nominal_mm"].as_f64(),
        cv["rmse_calibrated_mm"].as_f64(),
    ) {
        out.push(format!(
            "held-out marker RMSE (cross-validation) {b:.4} -> {a:.4} mm"
        ));
    }
    for set in ["calibration", "validation"] {
        let e = &r["model_error"][set]["e_P"];
        if let (Some(b), Some(a)) = (
            e["nominal"]["mean"].as_f64(),
            e["identified"]["mean"].as_f64(),
        ) {
            out.push(format!(
                "{set} e_P mean {b:.2} -> {a:.2} {}",
                e["unit"].as_str().unwrap_or("um")
            ));
        }
    }
    if let Some(u) = r["unidentifiable"].as_array().filter(|u| !u.is_empty()) {
        out.push(format!(
            "unidentifiable: {}",
            u.iter()
                .filter_map(Value::as_str)
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    for key in ["residuals", "validation"] {
        if let Some(l) = stats_line(key, &r[key]) {
            out.push(l);
        }
    }
    if let (Some(sel), Some(o)) = (
        r["selected"].as_array(),
        r["observability"]["selection"]["o1"].as_f64(),
    ) {
        out.push(format!(
            "{} configurations selected; O1 {o:.4} (pool {:.4})",
            sel.len(),
            r["observability"]["pool"]["o1"]
                .as_f64()
                .unwrap_or(f64::NAN)
        ));
    }
    if let Some(rows) = r["poses"].as_array() {
        out.push(format!("{} poses", rows.len()));
    }
    for w in r["warnings"].as_array().into_iter().flatten() {
        out.push(format!("warning: {}", w.as_str().unwrap_or_default()));
    }
    out
}
