//! Filtering a whole module: every literal robtarget declaration (arrays too) corrected with
//! the tool and work object of the move instructions that use it, the numbers rewritten in
//! place (a number whose change is below its printed resolution keeps its bytes), optional
//! `jointtarget` declarations for `MoveAbsJ`, and a report row per target.

use std::collections::BTreeMap;

use super::correct::{Failure, Filter, difference};
use super::data::{Held, RobTarget, matrix_to_quat, quat_to_matrix, tooldata, wobjdata};
use super::parse::{Decl, Module, Value};
use super::rewrite::{Edit, apply, number};
use super::{RapidError, parse};
use crate::geometry::Frame;
use crate::model::compensate::{Scratch, rotation_vector};

/// Decimals written for positions (mm) and quaternion components.
const POS_DECIMALS: usize = 5;
const QUAT_DECIMALS: usize = 9;
/// Decimals of jointtarget joints (deg).
const JOINT_DECIMALS: usize = 6;
/// A rotation below this (rad) keeps the quaternion's bytes.
const QUAT_KEEP_RAD: f64 = 1e-9;

/// How to filter a module.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// `tooldata` literals by name, besides (and over) the module's.
    pub tooldata: BTreeMap<String, String>,
    /// `wobjdata` literals by name, besides (and over) the module's.
    pub wobjdata: BTreeMap<String, String>,
    /// Tool of targets no move instruction uses (`tool0` if empty).
    pub default_tool: String,
    /// Work object of targets no move instruction uses (`wobj0` if empty).
    pub default_wobj: String,
    /// Also declare `<name>_jt` jointtargets with the calibrated joints.
    pub jointtargets: bool,
}

/// What happened to one target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Rewritten.
    Corrected,
    /// Its correction is below the printed resolution: bytes kept.
    Unchanged,
    /// The calibrated model does not reach it (or only beyond a limit, or singular).
    NotReached,
    /// The nominal controller has no solution with its configuration.
    Configuration,
    /// Used with different tools or work objects.
    Ambiguous,
    /// Its tool or work object is not declared, or not supported.
    Data,
    /// Not a literal robtarget.
    NotLiteral,
}

/// The report of one target (lengths in mm, angles in deg).
#[derive(Debug, Clone, serde::Serialize)]
pub struct TargetReport {
    /// `p10`, or `path{3}` for an array element.
    pub target: String,
    /// Line of its declaration.
    pub line: usize,
    /// Tool and work object used.
    pub tool: String,
    /// Work object.
    pub wobj: String,
    /// What happened.
    pub outcome: Outcome,
    /// Position change in the work object (mm).
    pub dx_mm: f64,
    /// ...
    pub dy_mm: f64,
    /// ...
    pub dz_mm: f64,
    /// Length of the position change (mm).
    pub correction_mm: f64,
    /// Rotation of the orientation (deg).
    pub correction_deg: f64,
    /// Configuration data before.
    pub conf_before: Option<[i64; 4]>,
    /// Configuration data after.
    pub conf_after: Option<[i64; 4]>,
    /// Joints on the real robot (deg), per the calibrated model.
    pub q_deg: Option<[f64; 6]>,
    /// Whether a move reaches it through `Offs` or `RelTool` (corrected to first order).
    pub through_offset: bool,
    /// Why it was not corrected, or a warning.
    pub reason: String,
}

/// The filtered module text and the report per target.
#[derive(Debug, Clone)]
pub struct Filtered {
    /// Module name.
    pub module: String,
    /// The new text.
    pub text: String,
    /// One row per robtarget (array elements each).
    pub targets: Vec<TargetReport>,
}

/// A frame per tool and work object name (lower case), or why it cannot be used.
type Frames = BTreeMap<String, Result<Frame, String>>;

/// Filter module `src` through `filter`.
pub fn filter_module(src: &str, filter: &Filter, o: &Options) -> Result<Filtered, RapidError> {
    let m = parse(src)?;
    let tools = frames(&m, "tooldata", &o.tooldata, "tool0", tooldata)?;
    let wobjs = frames(&m, "wobjdata", &o.wobjdata, "wobj0", wobjdata)?;
    // Tool and work object of every use, by target name.
    let mut uses: BTreeMap<String, Vec<(String, String, usize, bool)>> = BTreeMap::new();
    for mv in &m.moves {
        for (name, via) in &mv.targets {
            uses.entry(name.to_ascii_lowercase()).or_default().push((
                mv.tool.clone().unwrap_or_else(|| "?".into()),
                mv.wobj.clone().unwrap_or_else(|| "wobj0".into()),
                mv.line,
                *via,
            ));
        }
    }
    let or = |s: &str, d: &str| {
        if s.is_empty() {
            d.to_string()
        } else {
            s.to_string()
        }
    };
    let defaults = (or(&o.default_tool, "tool0"), or(&o.default_wobj, "wobj0"));
    let names: Vec<String> = m
        .decls
        .iter()
        .map(|d| d.name.to_ascii_lowercase())
        .collect();
    let mut edits = Vec::new();
    let mut reports = Vec::new();
    let mut scratch = Scratch::default();
    for d in m.decls.iter().filter(|d| d.ty == "robtarget") {
        let Some(value) = &d.value else { continue };
        let u = uses.get(&d.name.to_ascii_lowercase());
        let through = u.is_some_and(|u| u.iter().any(|x| x.3));
        let mut pairs: Vec<(String, String)> = u
            .map(|u| u.iter().map(|x| (x.0.clone(), x.1.clone())).collect())
            .unwrap_or_else(|| vec![defaults.clone()]);
        pairs.sort_by_key(|p| (p.0.to_ascii_lowercase(), p.1.to_ascii_lowercase()));
        pairs.dedup_by(|a, b| a.0.eq_ignore_ascii_case(&b.0) && a.1.eq_ignore_ascii_case(&b.1));
        let (tool, wobj) = pairs[0].clone();
        let mut blocked: Option<(Outcome, String)> = None;
        if pairs.len() > 1 {
            let lines: Vec<String> = u
                .into_iter()
                .flatten()
                .map(|x| format!("{} with {} (line {})", x.0, x.1, x.2))
                .collect();
            blocked = Some((
                Outcome::Ambiguous,
                format!(
                    "used with different tools or work objects: {}",
                    lines.join(", ")
                ),
            ));
        }
        let lookup = |set: &Frames, name: &str, what: &str| -> Result<Frame, String> {
            match set.get(&name.to_ascii_lowercase()) {
                Some(r) => r.clone(),
                None => Err(format!(
                    "{what} `{name}` is not declared in the module: give it in options.{what}"
                )),
            }
        };
        let frames = lookup(&tools, &tool, "tooldata")
            .and_then(|t| lookup(&wobjs, &wobj, "wobjdata").map(|w| (t, w)));
        if blocked.is_none()
            && let Err(e) = &frames
        {
            blocked = Some((Outcome::Data, e.clone()));
        }
        let mut elements = Vec::new();
        flatten(value, d.dims.len(), &mut Vec::new(), &mut elements);
        let mut joints: Vec<Option<([f64; 6], (usize, usize))>> = Vec::new();
        for (index, v) in elements {
            let label = if index.is_empty() {
                d.name.clone()
            } else {
                let i: Vec<String> = index.iter().map(|k| (k + 1).to_string()).collect();
                format!("{}{{{}}}", d.name, i.join(","))
            };
            let mut r = TargetReport {
                target: label,
                line: d.line,
                tool: tool.clone(),
                wobj: wobj.clone(),
                outcome: Outcome::NotLiteral,
                dx_mm: 0.0,
                dy_mm: 0.0,
                dz_mm: 0.0,
                correction_mm: 0.0,
                correction_deg: 0.0,
                conf_before: None,
                conf_after: None,
                q_deg: None,
                through_offset: through,
                reason: String::new(),
            };
            let lit = RobTarget::of(v).and_then(|rt| Some((rt.frame()?, rt.confdata()?, rt)));
            let Some((t, cf, rt)) = lit else {
                r.reason = "not a literal robtarget (numbers, a non-zero quaternion and integer configuration data)".into();
                reports.push(r);
                joints.push(None);
                continue;
            };
            r.conf_before = Some(cf);
            if let Some((oc, why)) = &blocked {
                r.outcome = *oc;
                r.reason = why.clone();
                reports.push(r);
                joints.push(None);
                continue;
            }
            let Ok((tf, wf)) = &frames else { continue };
            match filter.correct(&t, cf, tf, wf, &mut scratch) {
                Err(Failure::Configuration(why)) => {
                    r.outcome = Outcome::Configuration;
                    r.reason = why;
                    joints.push(None);
                }
                Err(Failure::Solver(_, why)) => {
                    r.outcome = Outcome::NotReached;
                    r.reason = why;
                    joints.push(None);
                }
                Ok(c) => {
                    let n = edits.len();
                    rewrite_target(&rt, &c.target, c.conf, &mut edits);
                    r.outcome = if edits.len() > n {
                        Outcome::Corrected
                    } else {
                        Outcome::Unchanged
                    };
                    let dp = c.target.p - t.p;
                    (r.dx_mm, r.dy_mm, r.dz_mm) = (dp.x, dp.y, dp.z);
                    let (dl, da) = difference(&t, &c.target);
                    r.correction_mm = dl;
                    r.correction_deg = da.to_degrees();
                    r.conf_after = Some(c.conf);
                    r.q_deg = Some(c.q.map(f64::to_degrees));
                    if c.quadrants_missed > 0 {
                        r.reason = format!(
                            "the original cf1, cf4, cf6 were {} quadrant(s) off the nominal \
                             solution; the nearest was used",
                            c.quadrants_missed
                        );
                    }
                    if through {
                        if !r.reason.is_empty() {
                            r.reason.push_str("; ");
                        }
                        r.reason.push_str(
                            "reached through Offs/RelTool too: displaced poses get this \
                             target's correction (first order)",
                        );
                    }
                    joints.push(Some((c.q.map(f64::to_degrees), rt.extax)));
                }
            }
            reports.push(r);
        }
        if o.jointtargets {
            edits.push(jointtarget(src, d, &joints, &names)?);
        }
    }
    Ok(Filtered {
        module: m.name,
        text: apply(src, &edits),
        targets: reports,
    })
}

/// The edits that write `new` (pose and configuration) over robtarget `rt`, number by
/// number, keeping the bytes of every number whose change is below its printed resolution.
fn rewrite_target(rt: &RobTarget, new: &Frame, conf: [i64; 4], edits: &mut Vec<Edit>) {
    let half = 0.5 * 10f64.powi(-(POS_DECIMALS as i32));
    for (k, (old, s, e)) in rt.pos.iter().enumerate() {
        if (new.p[k] - old).abs() >= half {
            edits.push(Edit {
                start: *s,
                end: *e,
                with: number(new.p[k], POS_DECIMALS),
            });
        }
    }
    let old_q = rt.rot.map(|r| r.0);
    let keep = quat_to_matrix(&old_q)
        .is_some_and(|r| rotation_vector(&(r.transpose() * new.r)).norm() < QUAT_KEEP_RAD);
    if !keep {
        let q = matrix_to_quat(&new.r, &old_q);
        for (k, (_, s, e)) in rt.rot.iter().enumerate() {
            edits.push(Edit {
                start: *s,
                end: *e,
                with: number(q[k], QUAT_DECIMALS),
            });
        }
    }
    for (k, (old, s, e)) in rt.conf.iter().enumerate() {
        if *old != conf[k] as f64 {
            edits.push(Edit {
                start: *s,
                end: *e,
                with: conf[k].to_string(),
            });
        }
    }
}

/// The elements of an array value `depth` levels deep, with their indices (from 0).
fn flatten<'v>(
    v: &'v Value,
    depth: usize,
    at: &mut Vec<usize>,
    out: &mut Vec<(Vec<usize>, &'v Value)>,
) {
    if depth == 0 {
        out.push((at.clone(), v));
        return;
    }
    if let Some(items) = v.items() {
        for (k, it) in items.iter().enumerate() {
            at.push(k);
            flatten(it, depth - 1, at, out);
            at.pop();
        }
    } else {
        out.push((at.clone(), v));
    }
}

/// `tool0`/`wobj0` and every declaration of type `ty` (module's, then the job's over them):
/// its frame, or why it cannot be used.
fn frames(
    m: &Module,
    ty: &str,
    given: &BTreeMap<String, String>,
    zero: &str,
    read: fn(&Value) -> Option<Held>,
) -> Result<Frames, RapidError> {
    let mut out = Frames::new();
    out.insert(zero.into(), Ok(Frame::identity()));
    let held = |name: &str, v: Option<&Value>| match v.and_then(read) {
        Some(Held::Frame(f)) => Ok(f),
        Some(Held::Unsupported(why)) => Err(format!("{ty} `{name}`: {why}")),
        None => Err(format!(
            "{ty} `{name}` has no literal value calibd can read"
        )),
    };
    for d in m.decls.iter().filter(|d| d.ty == ty && d.dims.is_empty()) {
        out.entry(d.name.to_ascii_lowercase())
            .or_insert_with(|| held(&d.name, d.value.as_ref()));
    }
    for (name, lit) in given {
        let doc = format!("MODULE given\nCONST {ty} {name} := {lit};\nENDMODULE\n");
        let v = parse(&doc)
            .map_err(|e| RapidError::new(0, format!("options.{ty}.{name}: {}", e.message)))?
            .decls
            .pop()
            .and_then(|d| d.value);
        let f = held(name, v.as_ref());
        if let Err(e) = &f {
            return Err(RapidError::new(0, format!("options.{ty}.{name}: {e}")));
        }
        out.insert(name.to_ascii_lowercase(), f);
    }
    Ok(out)
}

/// The declaration `<storage> jointtarget <name>_jt[{dims}] := ...;` inserted after `d`,
/// with the calibrated joints of each element.
fn jointtarget(
    src: &str,
    d: &Decl,
    joints: &[Option<([f64; 6], (usize, usize))>],
    names: &[String],
) -> Result<Edit, RapidError> {
    let at = Edit {
        start: d.end,
        end: d.end,
        with: String::new(),
    };
    let Some(vs) = d.value_span else {
        return Ok(at);
    };
    if joints.is_empty() || joints.iter().any(Option::is_none) {
        return Ok(at);
    }
    let jt = format!("{}_jt", d.name);
    if names.contains(&jt.to_ascii_lowercase()) {
        return Err(RapidError::new(
            d.line,
            format!("cannot declare jointtarget {jt}: the name is taken"),
        ));
    }
    let elem = |(q, ext): &([f64; 6], (usize, usize))| {
        let j: Vec<String> = q.iter().map(|v| number(*v, JOINT_DECIMALS)).collect();
        format!("[[{}],{}]", j.join(","), &src[ext.0..ext.1])
    };
    let items: Vec<String> = joints.iter().flatten().map(elem).collect();
    let value = if d.dims.is_empty() {
        items.concat()
    } else {
        // Nested like the robtarget array (one level per dimension).
        nest(d, &items)
    };
    let line_start = src[..d.start].rfind('\n').map_or(0, |k| k + 1);
    let indent: String = src[line_start..d.start]
        .chars()
        .take_while(|c| c.is_whitespace())
        .collect();
    let head = format!(
        "{}jointtarget{}_jt{}",
        &src[d.start..d.ty_span.0],
        &src[d.ty_span.1..d.name_span.1],
        &src[d.name_span.1..vs.0]
    );
    Ok(Edit {
        with: format!("\n{indent}{head}{value};"),
        ..at
    })
}

/// Items of a multi-dimensional array nested by its dimensions (row-major).
fn nest(d: &Decl, items: &[String]) -> String {
    let dims: Vec<usize> = d.dims.iter().map(|n| n.unwrap_or(items.len())).collect();
    fn go(dims: &[usize], items: &[String]) -> String {
        if dims.len() <= 1 {
            return format!("[{}]", items.join(","));
        }
        let chunk = items.len() / dims[0].max(1);
        let parts: Vec<String> = items
            .chunks(chunk.max(1))
            .map(|c| go(&dims[1..], c))
            .collect();
        format!("[{}]", parts.join(","))
    }
    go(&dims, items)
}
