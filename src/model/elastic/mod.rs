//! Elastic kinematic trees identified without torque data (issue 13, item 5).
//!
//! A tree of frames given by Craig's modified DH rows with a Hayati beta
//! (`Rx(alpha) Dx(a) Ry(beta) Rz(theta + q) Dz(d)`) and fixed frames (mounts, tool flanges),
//! each row hanging from a parent row or from the root. Markers sit on rows at unknown local
//! positions; the root is placed in the measurement frame by six unknowns (`xyzabc`).
//!
//! **Elasticity without masses.** Link masses are unknown, so torques cannot be computed.
//! The gravity moment about an axis `a` of a joint frame is `|g| M . (u x a)`, with `M` the
//! first mass moment of everything the joint carries and `u` the gravity direction. What the
//! data determine are products of compliance and mass moment, identified in one of two
//! lumpings ([`Lumping`]):
//!
//! * [`Lumping::Subtree`] ([`gravity`]): `M` constant in the joint frame, so the deflection is
//!   linear in `u` seen from the joint frame, with lumped coefficients (rad at full load):
//!   joint `dz = kz_gx ux + kz_gy uy`; lateral (Tenhumberg and Baeuml, Humanoids 2021: the
//!   joint bends about the two axes perpendicular to its rotation axis) `dx = kx_gy uy +
//!   kx_gz uz`, `dy = ky_gx ux + ky_gz uz`.
//! * [`Lumping::Bodies`] (`bodies.rs`): every link has an unknown weight and weight moment
//!   in its own frame, shared by every joint that carries it; the torque is exact for any
//!   configuration, and each elastic joint has compliances `c_z` (joint), `c_x`, `c_y`
//!   (lateral). Bilinear: one overall scale is a gauge.
//!
//! The deflection rotates the joint's output by `Rz(dz) Rx(dx) Ry(dy)` right after
//! `Rz(theta + q)`. As the static torques of serial arms (`serial-robot.md`), the gravity
//! factors are computed once per sample from the starting model with elasticity off
//! ([`ElasticTree::sample`]): they are data during a fit, so the Jacobians are exact.

mod bodies;
mod eval;
pub mod gravity;
pub mod justin;
mod params;

use nalgebra::Vector3;

use super::ModelError;
use crate::geometry::Frame;

pub use bodies::Loads;
pub use eval::TreeSample;
pub use params::TParam;

/// Names of the five geometric parameters of a revolute row, in storage order.
pub const GEOMETRY: [&str; 5] = ["alpha", "a", "beta", "theta", "d"];

/// How the joint variable of a revolute row follows the measured variables.
#[derive(Debug, Clone, PartialEq)]
pub enum Drive {
    /// The row's angle is measured variable `k`.
    Variable(usize),
    /// A passive joint coupled to measured variables: `sum(coefficient * q[k])`.
    Coupled(Vec<(usize, f64)>),
}

/// What a row is.
#[derive(Debug, Clone, PartialEq)]
pub enum RowKind {
    /// A fixed frame (a mount, a tool flange), with six placement errors
    /// `frame * Dx Dy Dz Rz(a) Ry(b) Rx(c)` (`xyzabc`).
    Fixed {
        /// Nominal transform from the parent row.
        frame: Frame,
        /// Placement errors x, y, z (m), a, b, c (rad).
        errors: [f64; 6],
    },
    /// A revolute joint: `Rx(alpha) Dx(a) Ry(beta) Rz(theta + q) Dz(d)`.
    Revolute {
        /// alpha (rad), a (m), beta (rad), theta (rad, the joint offset included), d (m).
        geometry: [f64; 5],
        /// Where its variable comes from.
        drive: Drive,
    },
}

/// One frame of the tree.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeRow {
    /// Name (used in parameter names: `<name>.alpha`, `<name>.kz_gx`, ...).
    pub name: String,
    /// Parent row (rows are ordered: a parent comes before its children); `None`: the root.
    pub parent: Option<usize>,
    /// The row's transform.
    pub kind: RowKind,
}

/// A marker fixed on a row at an unknown local position.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeMarker {
    /// Name (measurement columns `<name>_x`, ...).
    pub name: String,
    /// Row carrying it.
    pub row: usize,
    /// Current local position (m).
    pub local: Vector3<f64>,
}

/// How the unknown masses are lumped with the compliances.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Lumping {
    /// Each joint carries a first mass moment constant in its own frame: the deflection is
    /// linear in the gravity direction seen from the joint, with lumped coefficients
    /// `kz_gx, kz_gy` (joint) and `kx_gy, kx_gz, ky_gx, ky_gz` (lateral), rad. Exact when
    /// the joints a joint carries do not move mass; on Agile Justin it leaves 6.9 mm where
    /// [`Lumping::Bodies`] reaches 3.0 mm.
    #[default]
    Subtree,
    /// Each revolute row's link has an unknown weight `w` (N) and weight moment `w_m*`
    /// (N*m, its frame), shared by every joint that carries it; each elastic joint has
    /// compliances `c_z` (joint), `c_x`, `c_y` (lateral), rad/(N*m). The deflection is
    /// compliance x gravity torque, bilinear; only the products are determined (one scale
    /// is a gauge, held by the rank step).
    Bodies,
}

/// Which rows carry lumped elasticity parameters.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ElasticOptions {
    /// Revolute rows with joint compliance (about their axis).
    pub joint: Vec<String>,
    /// Revolute rows with lateral compliance (about the two perpendicular axes).
    pub lateral: Vec<String>,
    /// How masses and compliances are lumped.
    pub lumping: Lumping,
}

/// Which parameter groups a fit frees (the cumulative steps of the Justin table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Groups {
    /// Joint offsets (theta of revolute rows).
    pub offsets: bool,
    /// The other geometry: alpha, a, beta, d and fixed-row placement errors.
    pub geometry: bool,
    /// Lumped joint compliance.
    pub joint: bool,
    /// Lumped lateral compliance.
    pub lateral: bool,
}

/// The elastic tree model.
#[derive(Debug, Clone)]
pub struct ElasticTree {
    /// Rows, parents first.
    pub rows: Vec<TreeRow>,
    /// Markers.
    pub markers: Vec<TreeMarker>,
    /// Root in the measurement frame: x, y, z (m), a, b, c (rad), `Dx Dy Dz Rz Ry Rx`.
    pub base: [f64; 6],
    /// Lumped elasticity coefficients of each row (rad at full gravity load), in the order
    /// `kz_gx, kz_gy, kx_gy, kx_gz, ky_gx, ky_gz`; zero where not identified.
    pub elastic: Vec<[f64; 6]>,
    /// [`Lumping::Bodies`]: compliances `[c_z, c_x, c_y]` (rad/(N*m)) of each row.
    pub compliance: Vec<[f64; 3]>,
    /// [`Lumping::Bodies`]: weight moment (N*m, row frame) and weight (N) of each row's link.
    pub weights: Vec<[f64; 4]>,
    /// How masses are lumped.
    pub lumping: Lumping,
    /// Unit gravity direction in the root frame (default `-z`).
    pub gravity_root: Vector3<f64>,
    /// Number of measured joint variables.
    pub variables: usize,
    /// Every parameter, in a fixed order.
    pub params: Vec<TParam>,
    /// Rows carrying joint / lateral elasticity parameters.
    joint_elastic: Vec<bool>,
    lateral_elastic: Vec<bool>,
    /// Rows from the root to each marker's row, root first.
    paths: Vec<Vec<usize>>,
    /// Revolute rows carried by each row (its own link included), [`Lumping::Bodies`].
    subtree: Vec<Vec<usize>>,
}

fn field(field: &str, reason: String) -> ModelError {
    ModelError::Field {
        field: field.into(),
        reason,
    }
}

impl ElasticTree {
    /// Build and check a tree: parents before children, drives within `variables`, marker
    /// rows that exist, elastic rows that are revolute rows of the tree.
    pub fn new(
        rows: Vec<TreeRow>,
        markers: Vec<TreeMarker>,
        variables: usize,
        elastic: &ElasticOptions,
    ) -> Result<Self, ModelError> {
        for (i, r) in rows.iter().enumerate() {
            if rows[..i].iter().any(|o| o.name == r.name) {
                return Err(field("rows", format!("row `{}` is defined twice", r.name)));
            }
            if r.parent.is_some_and(|p| p >= i) {
                return Err(field(
                    &format!("rows.{}.parent", r.name),
                    "a parent must come before its child".into(),
                ));
            }
            if let RowKind::Revolute { drive, geometry } = &r.kind {
                let vars: Vec<usize> = match drive {
                    Drive::Variable(k) => vec![*k],
                    Drive::Coupled(c) => c.iter().map(|x| x.0).collect(),
                };
                if let Some(k) = vars.iter().find(|&&k| k >= variables) {
                    return Err(field(
                        &format!("rows.{}.drive", r.name),
                        format!("variable {k} out of {variables}"),
                    ));
                }
                if geometry.iter().any(|v| !v.is_finite()) {
                    return Err(field(
                        &format!("rows.{}.geometry", r.name),
                        "not finite".into(),
                    ));
                }
            }
        }
        let mut paths = Vec::with_capacity(markers.len());
        for m in &markers {
            if m.row >= rows.len() {
                return Err(field(
                    &format!("markers.{}.row", m.name),
                    format!("row {} out of {}", m.row, rows.len()),
                ));
            }
            let mut path = ancestors(&rows, m.row);
            path.reverse();
            paths.push(path);
        }
        let flags = |names: &[String], what: &str| -> Result<Vec<bool>, ModelError> {
            let mut f = vec![false; rows.len()];
            for n in names {
                let i = rows
                    .iter()
                    .position(|r| &r.name == n && matches!(r.kind, RowKind::Revolute { .. }))
                    .ok_or_else(|| {
                        field(
                            &format!("elastic.{what}"),
                            format!("`{n}` is not a revolute row of the tree"),
                        )
                    })?;
                f[i] = true;
            }
            Ok(f)
        };
        let joint_elastic = flags(&elastic.joint, "joint")?;
        let lateral_elastic = flags(&elastic.lateral, "lateral")?;
        let revolute = |i: usize| matches!(rows[i].kind, RowKind::Revolute { .. });
        let subtree: Vec<Vec<usize>> = (0..rows.len())
            .map(|i| {
                (i..rows.len())
                    .filter(|&b| revolute(b) && ancestors(&rows, b).contains(&i))
                    .collect()
            })
            .collect();
        // Bodies: links of 20 N at their frame origins to start from; rigid until a fit
        // frees the compliances (see `seed_compliance`).
        let elastic_any = joint_elastic.iter().chain(&lateral_elastic).any(|&b| b);
        let weights = (0..rows.len())
            .map(|i| {
                if revolute(i) && elastic_any {
                    [0.0, 0.0, 0.0, 20.0]
                } else {
                    [0.0; 4]
                }
            })
            .collect();
        let compliance = vec![[0.0; 3]; rows.len()];
        let mut model = Self {
            compliance,
            weights,
            lumping: elastic.lumping,
            subtree,
            elastic: vec![[0.0; 6]; rows.len()],
            rows,
            markers,
            base: [0.0; 6],
            gravity_root: -Vector3::z(),
            variables,
            params: Vec::new(),
            joint_elastic,
            lateral_elastic,
            paths,
        };
        model.params = model.build_params();
        Ok(model)
    }

    /// Row index by name.
    pub fn row(&self, name: &str) -> Option<usize> {
        self.rows.iter().position(|r| r.name == name)
    }

    /// Rows from the root to marker `m`'s row.
    pub fn path(&self, m: usize) -> &[usize] {
        &self.paths[m]
    }

    /// Whether a row carries joint (about its axis) elasticity parameters.
    pub fn has_joint_elasticity(&self, row: usize) -> bool {
        self.joint_elastic[row]
    }

    /// Whether a row carries lateral elasticity parameters.
    pub fn has_lateral_elasticity(&self, row: usize) -> bool {
        self.lateral_elastic[row]
    }

    /// Indices into [`ElasticTree::params`] of the parameters a fit with `groups` frees:
    /// always the base and the markers, then the chosen groups.
    pub fn free_params(&self, groups: Groups) -> Vec<usize> {
        (0..self.params.len())
            .filter(|&i| match self.params[i] {
                TParam::Base(_) | TParam::Marker(..) => true,
                TParam::Geometry(_, 3) => groups.offsets,
                TParam::Geometry(..) | TParam::Placement(..) => groups.geometry,
                TParam::Elastic(_, k) if k < 2 => groups.joint,
                TParam::Elastic(..) => groups.lateral,
                TParam::Compliance(_, 0) => groups.joint,
                TParam::Compliance(..) => groups.lateral,
                TParam::Weight(..) => groups.joint || groups.lateral,
            })
            .collect()
    }
}

impl ElasticTree {
    /// [`Lumping::Bodies`]: give each compliance that `groups` frees and that is still zero
    /// the value `c` (rad/(N*m)): the products with the weights have no derivative at zero.
    pub fn seed_compliance(&mut self, groups: Groups, c: f64) {
        if self.lumping != Lumping::Bodies {
            return;
        }
        for (i, ci) in self.compliance.iter_mut().enumerate() {
            for (a, v) in ci.iter_mut().enumerate() {
                let on = if a == 0 {
                    groups.joint && self.joint_elastic[i]
                } else {
                    groups.lateral && self.lateral_elastic[i]
                };
                if on && *v == 0.0 {
                    *v = c;
                }
            }
        }
    }
}

/// Row `b` and its ancestors.
fn ancestors(rows: &[TreeRow], b: usize) -> Vec<usize> {
    let mut out = vec![b];
    while let Some(p) = rows[*out.last().unwrap_or(&b)].parent {
        out.push(p);
    }
    out
}

#[cfg(test)]
mod tests;
