//! The mock's file service (`PUT`/`GET /fileservice/$HOME/<file>`) and `loadmod`: a module
//! file loads into T_ROB1 only under RAPID mastership, with the program stopped, when it
//! holds one `MODULE <name>` ... `ENDMODULE` with balanced brackets and its name is not
//! loaded yet (or `replace=true`); otherwise the controller's refusal with its message.

use super::{Robot, error, no_content};
use crate::rws::http::{Response, url_decode};

/// `/fileservice/$HOME/x.mod` -> `$HOME/x.mod`, or `None` outside the home directory.
fn home_path(p: &str) -> Option<String> {
    let rest = url_decode(p.strip_prefix("/fileservice/")?);
    let file = rest
        .strip_prefix("$HOME/")
        .or_else(|| rest.strip_prefix("$home/"))?;
    (!file.is_empty() && !file.contains('/') && !file.contains(".."))
        .then(|| format!("$HOME/{file}"))
}

pub(super) fn put(r: &mut Robot, p: &str, body: &[u8]) -> Response {
    let Some(path) = home_path(p) else {
        return error(404, -1073479661, &format!("Directory not found: {p}"));
    };
    let existed = r.files.insert(path, body.to_vec()).is_some();
    let mut resp = no_content();
    resp.status = if existed { 200 } else { 201 };
    resp.reason = if existed { "OK" } else { "Created" }.into();
    resp
}

pub(super) fn get(r: &Robot, p: &str) -> Response {
    match home_path(p).and_then(|k| r.files.get(&k)) {
        Some(b) => Response {
            status: 200,
            reason: "OK".into(),
            headers: vec![("Content-Type".into(), "text/plain".into())],
            body: b.clone(),
        },
        None => error(404, -1073479661, &format!("File not found: {p}")),
    }
}

pub(super) fn loadmod(r: &mut Robot, form: &[(String, String)]) -> Response {
    let field = |k: &str| form.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
    let Some(path) = field("modulepath") else {
        return error(400, -1073445879, "Missing parameter: modulepath");
    };
    let replace = field("replace").is_some_and(|v| v.eq_ignore_ascii_case("true"));
    if !r.mastership {
        return error(
            403,
            -1073445820,
            "Mastership is not held: request RAPID mastership before loading a module",
        );
    }
    if r.running {
        return error(
            400,
            -1073442813,
            "Operation not allowed while the RAPID program is executing: stop it before loading a module",
        );
    }
    let Some(bytes) = r.files.get(path) else {
        return error(400, -1073445859, &format!("File not found: {path}"));
    };
    let text = match std::str::from_utf8(bytes) {
        Ok(t) => t.to_string(),
        Err(_) => return error(400, -1073442787, &format!("Load error: {path} is not text")),
    };
    let name = match check_module(&text) {
        Ok(n) => n,
        Err(m) => return error(400, -1073442787, &format!("Load error in {path}: {m}")),
    };
    let present = r
        .info
        .program_modules
        .iter()
        .any(|m| m.eq_ignore_ascii_case(&name));
    if present && !replace {
        return error(
            400,
            -1073442790,
            &format!("Module {name} is already loaded in T_ROB1"),
        );
    }
    if !present {
        r.info.program_modules.push(name);
    }
    no_content()
}

/// The module name, or a syntax error with its line: `MODULE <name>` first, `ENDMODULE`
/// last, brackets balanced outside strings and comments.
fn check_module(text: &str) -> Result<String, String> {
    let mut name = None;
    let mut depth: Vec<(char, usize)> = Vec::new();
    let mut ended = false;
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        let code = strip(raw);
        let t = code.trim();
        if t.is_empty() || t.starts_with("%%%") {
            continue;
        }
        if name.is_none() {
            let mut w = t.split_whitespace();
            match (w.next(), w.next()) {
                (Some(m), Some(id)) if m.eq_ignore_ascii_case("MODULE") => {
                    name = Some(id.split('(').next().unwrap_or(id).to_string());
                    continue;
                }
                _ if t.contains(':') => continue, // header lines VERSION:1 ...
                _ => return Err(format!("line {line}: expected MODULE")),
            }
        }
        if ended {
            return Err(format!("line {line}: text after ENDMODULE"));
        }
        for c in code.chars() {
            match c {
                '[' | '(' | '{' => depth.push((c, line)),
                ']' | ')' | '}' => {
                    let want = match c {
                        ']' => '[',
                        ')' => '(',
                        _ => '{',
                    };
                    match depth.pop() {
                        Some((o, _)) if o == want => {}
                        _ => return Err(format!("line {line}: unbalanced '{c}'")),
                    }
                }
                _ => {}
            }
        }
        if t.eq_ignore_ascii_case("ENDMODULE") {
            ended = true;
        }
    }
    if let Some((c, line)) = depth.first() {
        return Err(format!("line {line}: '{c}' is not closed"));
    }
    match (name, ended) {
        (Some(n), true) => Ok(n),
        (Some(_), false) => Err("ENDMODULE missing".into()),
        (None, _) => Err("no MODULE".into()),
    }
}

/// A line without its comment and string contents.
fn strip(line: &str) -> String {
    let mut out = String::new();
    let mut in_str = false;
    for c in line.chars() {
        match c {
            '"' => in_str = !in_str,
            '!' if !in_str => break,
            _ if !in_str => out.push(c),
            _ => {}
        }
    }
    out
}
