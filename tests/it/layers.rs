//! The layering of `src/` (ARCHITECTURE.md), checked from the source: every `crate::…` and
//! `super::…` path in a file's non-test code is an import; it may only reach the file's own
//! layer or one below, except the named exceptions; and no import circle spans more than
//! two files. Test code (`tests.rs`, `tests/`, `*_tests.rs`, `#[cfg(test)] mod …` at a file's end)
//! may reach anywhere.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layers, lowest first: a module path prefix (folder or file under `src/`) per entry.
/// `jobs` is two layers: its kinds below the campaigns, its registry above them.
const LAYERS: &[(&str, &[&str])] = &[
    ("foundations", &["util"]),
    ("geometry", &["geometry", "signal"]),
    ("models", &["model", "identify"]),
    ("methods", &["measure", "design", "twin"]),
    ("devices", &["procedures"]),
    ("lab", &["lab", "sim"]),
    ("job core", &["run"]),
    ("reports", &["report"]),
    (
        "kinds",
        &[
            "jobs/serial",
            "jobs/pcr",
            "jobs/humanoid",
            "jobs/tree",
            "jobs/map_options",
        ],
    ),
    ("campaigns", &["campaigns"]),
    ("registry", &["jobs"]),
    ("storage", &["store"]),
    ("service", &["service", "schedule"]),
    ("http", &["api", "config"]),
    (
        "entry",
        &["server", "client", "bench", "lib", "main", "cli"],
    ),
];

/// Imports allowed to run upward, each with its reason (also in ARCHITECTURE.md).
const UPWARD: &[(&str, &str)] = &[];

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `src/jobs/serial/fk.rs` -> ["jobs", "serial", "fk"]; `mod.rs` names its folder.
fn module_of(rel: &str) -> Vec<String> {
    let mut parts: Vec<String> = rel
        .trim_end_matches(".rs")
        .split('/')
        .map(String::from)
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

fn is_test_file(rel: &str) -> bool {
    let name = rel.rsplit('/').next().unwrap_or(rel);
    rel.split('/').any(|dir| dir == "tests")
        || name == "tests.rs"
        || name.ends_with("_tests.rs")
        || name == "testpg.rs"
}

/// The file's code without comments and without a trailing `#[cfg(test)] mod`.
fn code(text: &str) -> String {
    let cut = text.find("#[cfg(test)]\nmod ").unwrap_or(text.len());
    text[..cut]
        .lines()
        .map(|l| match l.find("//") {
            Some(i) if !l[..i].contains('"') => &l[..i],
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every path the code names from `crate::` or `super::`, as absolute module paths.
/// Grouped `use a::{b, c::d}` lists count each member.
fn paths(code: &str, module: &[String], is_mod_rs: bool) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut i = 0;
    while i < bytes.len() {
        if !code.is_char_boundary(i) {
            i += 1;
            continue;
        }
        let rest = &code[i..];
        let start = if rest.starts_with("crate::") {
            Some(Vec::new())
        } else if rest.starts_with("super::") {
            // `super` of a file module is its parent; of a mod.rs, its parent's parent.
            let mut m = module.to_vec();
            if !is_mod_rs || !m.is_empty() {
                m.pop();
            }
            Some(m)
        } else {
            None
        };
        let boundary = i == 0 || !ident(bytes[i - 1]) && bytes[i - 1] != b':';
        let (Some(mut path), true) = (start, boundary) else {
            i += 1;
            continue;
        };
        // Both `crate` and `super` are five bytes long.
        let mut j = i + 5;
        loop {
            // at "::"
            if !code[j..].starts_with("::") {
                break;
            }
            j += 2;
            if code[j..].starts_with('{') {
                let close = code[j..].find('}').map_or(code.len(), |k| j + k);
                for member in code[j + 1..close].split(',') {
                    let mut p = path.clone();
                    let first = member.trim().split(' ').next().unwrap_or("");
                    for seg in first.split("::").map(|s| s.trim_matches(['{', '}'])) {
                        match seg {
                            "" | "self" => {}
                            "super" => {
                                p.pop();
                            }
                            s => p.push(s.to_string()),
                        }
                    }
                    out.push(p);
                }
                j = close;
                break;
            }
            let k = code[j..].bytes().take_while(|&c| ident(c)).count();
            let seg = &code[j..j + k];
            if seg == "super" {
                path.pop();
            } else if !seg.is_empty() {
                path.push(seg.to_string());
            }
            j += k;
        }
        out.push(path);
        i = j.max(i + 1);
    }
    out
}

struct Tree {
    /// Module path -> file (relative to src/).
    files: BTreeMap<Vec<String>, String>,
}

impl Tree {
    /// The file holding the longest prefix of `path`.
    fn resolve(&self, path: &[String]) -> Option<&String> {
        (1..=path.len())
            .rev()
            .find_map(|n| self.files.get(&path[..n]))
    }
}

fn layer_of(rel: &str) -> usize {
    let m = rel.trim_end_matches(".rs").trim_end_matches("/mod");
    LAYERS
        .iter()
        .enumerate()
        .filter_map(|(i, (_, prefixes))| {
            prefixes
                .iter()
                .filter(|p| {
                    m == **p || m.starts_with(&format!("{p}/")) || m.starts_with(&format!("{p}_"))
                })
                .map(|p| (p.len(), i))
                .max()
        })
        .max()
        .map(|(_, i)| i)
        .unwrap_or_else(|| {
            panic!("src/{rel} is in no layer: add its folder to LAYERS and ARCHITECTURE.md")
        })
}

/// (file, imported file) for every import of non-test code.
fn edges() -> Vec<(String, String)> {
    let root = src();
    let mut all = Vec::new();
    files(&root, &mut all);
    let rel = |p: &Path| {
        p.strip_prefix(&root)
            .unwrap_or(p)
            .to_string_lossy()
            .replace('\\', "/")
    };
    let tree = Tree {
        files: all.iter().map(|p| (module_of(&rel(p)), rel(p))).collect(),
    };
    let mut out = BTreeSet::new();
    for p in &all {
        let r = rel(p);
        if is_test_file(&r) || r == "main.rs" || r.starts_with("cli/") {
            continue;
        }
        let text = std::fs::read_to_string(p).unwrap_or_default();
        let m = module_of(&r);
        let is_mod_rs = r.ends_with("mod.rs");
        for path in paths(&code(&text), &m, is_mod_rs) {
            if let Some(f) = tree.resolve(&path)
                && *f != r
            {
                out.insert((r.clone(), f.clone()));
            }
        }
    }
    out.into_iter().collect()
}

#[test]
fn imports_only_run_down_the_layers() {
    let mut up = Vec::new();
    for (a, b) in edges() {
        let (la, lb) = (layer_of(&a), layer_of(&b));
        if lb > la && !UPWARD.iter().any(|(x, y)| *x == a && *y == b) {
            up.push(format!(
                "src/{a} ({}) imports src/{b} ({})",
                LAYERS[la].0, LAYERS[lb].0
            ));
        }
    }
    assert!(
        up.is_empty(),
        "imports running up the layers:\n  {}",
        up.join("\n  ")
    );
}

#[test]
fn no_import_circle_spans_more_than_two_files() {
    let e = edges();
    let mut next: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (a, b) in &e {
        next.entry(a).or_default().push(b);
    }
    let nodes: BTreeSet<&str> = e
        .iter()
        .flat_map(|(a, b)| [a.as_str(), b.as_str()])
        .collect();
    // Tarjan's strongly connected components, iteratively.
    let mut index: BTreeMap<&str, usize> = BTreeMap::new();
    let mut low: BTreeMap<&str, usize> = BTreeMap::new();
    let mut on: BTreeSet<&str> = BTreeSet::new();
    let mut stack: Vec<&str> = Vec::new();
    let mut circles: Vec<Vec<&str>> = Vec::new();
    for &root in &nodes {
        if index.contains_key(root) {
            continue;
        }
        let mut work: Vec<(&str, usize)> = vec![(root, 0)];
        while let Some((v, k)) = work.pop() {
            if k == 0 {
                let n = index.len();
                index.insert(v, n);
                low.insert(v, n);
                stack.push(v);
                on.insert(v);
            }
            let succ = next.get(v).map(Vec::as_slice).unwrap_or(&[]);
            if let Some(&w) = succ.get(k) {
                work.push((v, k + 1));
                if !index.contains_key(w) {
                    work.push((w, 0));
                } else if on.contains(w) {
                    let l = low[v].min(index[w]);
                    low.insert(v, l);
                }
                continue;
            }
            if low[v] == index[v] {
                let mut c = Vec::new();
                while let Some(w) = stack.pop() {
                    on.remove(w);
                    c.push(w);
                    if w == v {
                        break;
                    }
                }
                if c.len() > 2 {
                    circles.push(c);
                }
            }
            if let Some(&(parent, _)) = work.last() {
                let l = low[parent].min(low[v]);
                low.insert(parent, l);
            }
        }
    }
    assert!(
        circles.is_empty(),
        "import circles of more than two files:\n  {}",
        circles
            .iter()
            .map(|c| c.join(" <-> "))
            .collect::<Vec<_>>()
            .join("\n  ")
    );
}

/// The checker itself: it sees a known upward import and a known circle in made-up code.
#[test]
fn the_checker_finds_imports_through_groups_and_super() {
    let m = vec!["jobs".to_string(), "serial".to_string(), "fk".to_string()];
    let got = paths(
        "use crate::run::{Cx, table::Table};\nuse super::{load_model, super::KINDS};\nfn f() { crate::lab::Lab::empty() }",
        &m,
        false,
    );
    let s: Vec<String> = got.iter().map(|p| p.join("::")).collect();
    assert!(s.contains(&"run::Cx".to_string()), "{s:?}");
    assert!(s.contains(&"run::table::Table".to_string()), "{s:?}");
    assert!(s.contains(&"jobs::serial::load_model".to_string()), "{s:?}");
    assert!(s.contains(&"lab::Lab::empty".to_string()), "{s:?}");
    assert_eq!(layer_of("jobs/serial/fk.rs"), layer_of("jobs/pcr/mod.rs"));
    assert!(layer_of("jobs/mod.rs") > layer_of("campaigns/trical/plan.rs"));
    assert!(layer_of("campaigns/trical/plan.rs") > layer_of("jobs/serial/fk.rs"));
    assert!(layer_of("run/context.rs") > layer_of("lab/mod.rs"));
}
