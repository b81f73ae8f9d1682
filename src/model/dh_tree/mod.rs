//! DH tree model files (JSON, `"kind": "tree"`): DH rows that name their parent row (or the
//! root frame), a stated convention (`classic` or `modified`), and named chains from the root
//! to an end row. Each named chain loads into the serial [`Chain`] the identification uses,
//! so a serial identification runs on one chain of a torso + two arms robot.
//!
//! Conventions: `modified` (Craig, as the serial DH files) row = `Rx(alpha) Dx(a) Ry(beta)
//! Rz(theta) Dz(d)`; `classic` row = `Rz(theta) Dz(d) Dx(a) Rx(alpha) Ry(beta)`. A classic
//! row's `a, alpha, beta` therefore move to the next row of the chain (and, for the end row,
//! into the tool), which is exact because `Dx(a)` and `Rx(alpha)` commute.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::ModelError;
use super::chain::{Chain, Geometry, Units};
use super::dh::{DhFile, DhJoint, DhMimic, DhUnits, Gravity, RowType, Xyzabc};
use super::joint::link_mimics;
use super::{JointField, ParamId, Quantity};
use crate::geometry::Frame;

/// A DH tree file, field for field.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhTreeFile {
    /// Always `"tree"`.
    pub kind: String,
    /// Human-readable name.
    pub name: String,
    /// `classic` or `modified`: required, never guessed.
    pub convention: Convention,
    /// Units of every number in the file.
    pub units: DhUnits,
    /// Name of the root frame (the parent of the first rows).
    pub root: String,
    /// Rows in any order; each names its parent.
    pub rows: Vec<TreeRow>,
    /// Named chains: paths from the root to an end row.
    pub chains: Vec<NamedChain>,
    /// Root frame in the world frame {W} (shared by every chain).
    pub base: Xyzabc,
    /// Gravity magnitude (m/s^2) and direction in the root frame; default 9.80665 along -z.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<Gravity>,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
}

/// The DH convention of every row of a tree file.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Convention {
    /// Denavit-Hartenberg: `Rz(theta) Dz(d) Dx(a) Rx(alpha)` (plus `Ry(beta)`).
    Classic,
    /// Craig's modified DH: `Rx(alpha) Dx(a) Ry(beta) Rz(theta) Dz(d)`.
    Modified,
}

/// One row of a tree file.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TreeRow {
    /// Row (joint) name, unique in the file.
    pub name: String,
    /// Parent row name, or the root frame's name.
    pub parent: String,
    /// alpha (angle unit).
    pub alpha: f64,
    /// a (length unit).
    pub a: f64,
    /// Hayati beta (angle unit).
    #[serde(default)]
    pub beta: f64,
    /// d (length unit); the value at q = 0 for a prismatic row.
    pub d: f64,
    /// theta offset (angle unit); the constant theta of a prismatic or fixed row.
    pub theta_offset: f64,
    /// Compliance (revolute rows with their own variable only).
    #[serde(default)]
    pub compliance: f64,
    /// [lower, upper] of the variable; required for a row with its own variable.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits: Option<[f64; 2]>,
    /// `revolute` (default), `prismatic` or `fixed`.
    #[serde(default, rename = "type", skip_serializing_if = "RowType::is_revolute")]
    pub row_type: RowType,
    /// A coupling row: variable = multiplier * leader's variable + offset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mimic: Option<DhMimic>,
}

/// A named chain of a tree file.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NamedChain {
    /// Chain name (e.g. `left_arm`).
    pub name: String,
    /// The row whose output frame ends the chain.
    pub end: String,
    /// TCP in the end frame (identity when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<Xyzabc>,
}

impl DhTreeFile {
    /// Parse a tree file from JSON text; `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<Self, ModelError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let f: Self = serde_path_to_error::deserialize(de)
            .map_err(|e| ModelError::Parse(format!("{file}: {} (at `{}`)", e.inner(), e.path())))?;
        f.check(file)?;
        Ok(f)
    }

    /// Names of the chains, in file order.
    pub fn chain_names(&self) -> Vec<&str> {
        self.chains.iter().map(|c| c.name.as_str()).collect()
    }

    /// Structural checks: kind, unique names, known parents, no cycle, known chain ends.
    fn check(&self, file: &str) -> Result<(), ModelError> {
        let err = |f: String, r: String| ModelError::Field {
            field: format!("{file}: {f}"),
            reason: r,
        };
        if self.kind != "tree" {
            return Err(err("kind".into(), format!("`{}` is not `tree`", self.kind)));
        }
        for (i, r) in self.rows.iter().enumerate() {
            let at = format!("rows[{i}] (`{}`)", r.name);
            if r.name == self.root || self.rows[..i].iter().any(|o| o.name == r.name) {
                return Err(err(format!("{at}.name"), "is used twice".into()));
            }
            if r.parent != self.root && !self.rows.iter().any(|o| o.name == r.parent) {
                return Err(err(
                    format!("{at}.parent"),
                    format!(
                        "unknown parent `{}` (not a row, not the root `{}`)",
                        r.parent, self.root
                    ),
                ));
            }
            self.path(i).map_err(|cycle| {
                err(
                    format!("{at}.parent"),
                    format!("rows form a cycle: {}", cycle.join(" -> ")),
                )
            })?;
        }
        for (i, c) in self.chains.iter().enumerate() {
            if !self.rows.iter().any(|r| r.name == c.end) {
                return Err(err(
                    format!("chains[{i}] (`{}`).end", c.name),
                    format!("unknown end row `{}`", c.end),
                ));
            }
            if self.chains[..i].iter().any(|o| o.name == c.name) {
                return Err(err(
                    format!("chains[{i}].name"),
                    format!("`{}` is used twice", c.name),
                ));
            }
        }
        Ok(())
    }

    /// Row indices from the root to row `end` (root side first), or the names around a cycle.
    fn path(&self, end: usize) -> Result<Vec<usize>, Vec<String>> {
        let mut out = vec![end];
        let mut here = end;
        while self.rows[here].parent != self.root {
            let Some(p) = self
                .rows
                .iter()
                .position(|r| r.name == self.rows[here].parent)
            else {
                break;
            };
            if out.contains(&p) {
                let mut names: Vec<String> = out
                    .iter()
                    .rev()
                    .map(|&k| self.rows[k].name.clone())
                    .collect();
                names.push(self.rows[p].name.clone());
                return Err(names);
            }
            out.push(p);
            here = p;
        }
        out.reverse();
        Ok(out)
    }

    /// The serial chain named `name` (internal units: radians, the file's length unit), with
    /// parameters named as in a serial DH file of that path (entry i = i-th row on it).
    pub fn chain(&self, name: &str, file: &str) -> Result<Chain, ModelError> {
        let err = |f: String, r: String| ModelError::Field {
            field: format!("{file}: {f}"),
            reason: r,
        };
        let spec = self.chains.iter().find(|c| c.name == name).ok_or_else(|| {
            err(
                "chains".into(),
                format!(
                    "no chain named `{name}` (chains: {})",
                    self.chain_names().join(", ")
                ),
            )
        })?;
        let units: Units = self
            .units
            .to_units()
            .map_err(|e| err("units".into(), e.to_string()))?;
        let k = if units.deg {
            std::f64::consts::PI / 180.0
        } else {
            1.0
        };
        let end = self
            .rows
            .iter()
            .position(|r| r.name == spec.end)
            .ok_or_else(|| {
                err(
                    format!("chain `{name}`.end"),
                    format!("unknown end row `{}`", spec.end),
                )
            })?;
        let path = self
            .path(end)
            .map_err(|c| err("rows".into(), format!("cycle {}", c.join(" -> "))))?;
        let mut joints = Vec::with_capacity(path.len());
        // (alpha, a, beta) carried from the previous classic row.
        let mut carry = (0.0, 0.0, 0.0);
        for &ri in &path {
            let r = &self.rows[ri];
            let at = format!("{file}: rows[{ri}] (`{}`)", r.name);
            let moving = r.row_type != RowType::Fixed && r.mimic.is_none();
            let limits = match (r.limits, moving) {
                (Some(l), _) => l,
                (None, false) => [-f64::MAX, f64::MAX],
                (None, true) => {
                    return Err(ModelError::Field {
                        field: format!("{at}.limits"),
                        reason: "missing: a row with its own variable needs limits".into(),
                    });
                }
            };
            let (alpha, a, beta) = match self.convention {
                Convention::Modified => (r.alpha, r.a, r.beta),
                Convention::Classic => std::mem::replace(&mut carry, (r.alpha, r.a, r.beta)),
            };
            let row = DhJoint {
                name: r.name.clone(),
                alpha,
                a,
                beta,
                d: r.d,
                theta_offset: r.theta_offset,
                compliance: r.compliance,
                limits,
                row_type: r.row_type,
                mimic: r.mimic.clone(),
            };
            joints.push(row.to_joint(k, &at)?);
        }
        link_mimics(&mut joints, k).map_err(|(i, reason)| ModelError::Field {
            field: format!("{file}: rows[{}] (`{}`).mimic", path[i], joints[i].name),
            reason,
        })?;
        let chain_tool = spec
            .tool
            .map_or(Frame::identity(), |t| Frame::from_xyzabc(&xyzabc(t, k)));
        // A classic end row's own a, alpha, beta are the first part of the tool.
        let (alpha, a, beta) = carry;
        let tail = Frame::rot_x(alpha * k)
            .mul(&Frame::trans(a, 0.0, 0.0))
            .mul(&Frame::rot_y(beta * k));
        let tool = tail.mul(&chain_tool).to_xyzabc();
        let gravity = match &self.gravity {
            None => Vector3::new(0.0, 0.0, -super::urdf::G),
            Some(g) => {
                let d = Vector3::from(g.direction_in_base);
                if !d.iter().all(|v| v.is_finite()) || d.norm() == 0.0 || !g.magnitude.is_finite() {
                    return Err(err(
                        "gravity".into(),
                        "direction must be a non-zero vector and magnitude finite".into(),
                    ));
                }
                d.normalize() * g.magnitude
            }
        };
        debug_assert!(
            joints
                .iter()
                .all(|j| matches!(j.geometry, Geometry::Mdh { .. }))
        );
        Ok(Chain::new(
            joints,
            xyzabc(self.base, k),
            tool,
            gravity,
            Vec::new(),
            units,
        ))
    }
}

impl DhTreeFile {
    /// The chain `name` as a serial DH file (modified DH, the file's units): what a serial
    /// job identifies and writes back as its calibrated model. Its `identify` list is every
    /// row parameter except compliances (rank detection holds what the data cannot see).
    pub fn serial_file(&self, name: &str, file: &str) -> Result<DhFile, ModelError> {
        let chain = self.chain(name, file)?;
        let to = chain.units.to_file(Quantity::Angle);
        let mut joints = Vec::with_capacity(chain.joints.len());
        for j in &chain.joints {
            let Geometry::Mdh { alpha, a, beta, d } = j.geometry else {
                continue;
            };
            let row = self.rows.iter().find(|r| r.name == j.name);
            joints.push(DhJoint {
                name: j.name.clone(),
                alpha: alpha * to,
                a,
                beta: beta * to,
                d,
                theta_offset: j.offset * to,
                compliance: j.compliance * to,
                // File units; rows without their own variable may have none (ignored).
                limits: row.and_then(|r| r.limits).unwrap_or([-1.0, 1.0]),
                row_type: row.map_or(RowType::Revolute, |r| r.row_type),
                mimic: row.and_then(|r| r.mimic.clone()),
            });
        }
        let x = |v: &[f64; 6]| Xyzabc {
            x: v[0],
            y: v[1],
            z: v[2],
            a: v[3] * to,
            b: v[4] * to,
            c: v[5] * to,
        };
        let g = chain.gravity;
        let mut out = DhFile {
            kind: "serial".into(),
            name: format!("{} / {name}", self.name),
            units: self.units.clone(),
            joints,
            base: x(&chain.base),
            tool: x(&chain.tool),
            gravity: Gravity {
                magnitude: g.norm(),
                direction_in_base: [g.x, g.y, g.z],
            },
            links: Vec::new(),
            payload: None,
            identify: Vec::new(),
            sources: None,
            notes: Some(format!(
                "chain `{name}` of the {:?} DH tree file {file}",
                self.convention
            )),
            calibration: None,
        };
        out.identify = chain
            .param_ids()
            .into_iter()
            .filter(|id| matches!(id, ParamId::Joint(_, f) if *f != JointField::Compliance))
            .map(|id| chain.param_name(id))
            .collect();
        Ok(out)
    }
}

/// A pose with its angles in radians.
fn xyzabc(v: Xyzabc, k: f64) -> [f64; 6] {
    [v.x, v.y, v.z, v.a * k, v.b * k, v.c * k]
}

#[cfg(test)]
mod tests;
