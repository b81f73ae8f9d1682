//! Parameters of the elastic tree: the list, names, units, values, plausible ranges and
//! the rank-detection priority.

use super::gravity::COEFFICIENTS;
use super::{ElasticTree, GEOMETRY, RowKind};
use crate::model::params::XYZABC;

/// One parameter of an [`ElasticTree`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TParam {
    /// Geometry `k` (alpha, a, beta, theta, d) of revolute row `row`.
    Geometry(usize, u8),
    /// Placement error `k` (x, y, z, a, b, c) of fixed row `row`.
    Placement(usize, u8),
    /// Lumped elasticity coefficient `k` of row `row` (see [`COEFFICIENTS`]).
    Elastic(usize, u8),
    /// [`super::Lumping::Bodies`]: compliance of row `row` about z (0, joint), x, y (1, 2).
    Compliance(usize, u8),
    /// [`super::Lumping::Bodies`]: weight moment x, y, z (0..3, N*m) and weight (3, N) of
    /// row `row`'s link.
    Weight(usize, u8),
    /// Root pose component x, y, z, a, b, c.
    Base(u8),
    /// Local coordinate of marker `m`.
    Marker(usize, u8),
}

impl TParam {
    /// Smaller is kept first by the pivoted QR: offsets, translations, angles, elasticity,
    /// then the root and the markers (`humanoid.md` order), and last the fixed rows'
    /// placement errors, which mostly duplicate the root, the markers and the DH rows.
    pub fn priority(&self) -> u8 {
        match self {
            TParam::Geometry(_, 3) => 0,
            TParam::Geometry(_, 1 | 4) => 1,
            TParam::Geometry(..) => 2,
            TParam::Elastic(..) | TParam::Compliance(..) | TParam::Weight(..) => 4,
            TParam::Base(_) => 5,
            TParam::Marker(..) => 6,
            TParam::Placement(..) => 7,
        }
    }

    /// Whether the parameter is a length (m); else an angle or a lumped coefficient (rad).
    pub fn is_length(&self) -> bool {
        match self {
            TParam::Geometry(_, k) => *k == 1 || *k == 4,
            TParam::Placement(_, k) | TParam::Base(k) => *k < 3,
            TParam::Marker(..) => true,
            TParam::Elastic(..) | TParam::Compliance(..) | TParam::Weight(..) => false,
        }
    }

    /// Plausible size of the parameter's error, for effect sizes and physical scaling:
    /// 1 mm, 0.5 deg, 1 mrad of deflection at full gravity load.
    pub fn plausible_range(&self) -> f64 {
        match self {
            TParam::Elastic(..) => 1e-3,
            TParam::Compliance(..) => 5e-5,
            TParam::Weight(_, 3) => 20.0,
            TParam::Weight(..) => 5.0,
            p if p.is_length() => 1e-3,
            _ => 0.5f64.to_radians(),
        }
    }
}

impl ElasticTree {
    pub(super) fn build_params(&self) -> Vec<TParam> {
        let mut out = Vec::new();
        for (i, r) in self.rows.iter().enumerate() {
            match r.kind {
                RowKind::Fixed { .. } => out.extend((0..6).map(|k| TParam::Placement(i, k))),
                RowKind::Revolute { .. } => {
                    out.extend((0..5).map(|k| TParam::Geometry(i, k)));
                    let (j, l) = (self.joint_elastic[i], self.lateral_elastic[i]);
                    match self.lumping {
                        super::Lumping::Subtree => {
                            out.extend((0..2).filter(|_| j).map(|k| TParam::Elastic(i, k)));
                            out.extend((2..6).filter(|_| l).map(|k| TParam::Elastic(i, k)));
                        }
                        super::Lumping::Bodies => {
                            out.extend((0..1).filter(|_| j).map(|a| TParam::Compliance(i, a)));
                            out.extend((1..3).filter(|_| l).map(|a| TParam::Compliance(i, a)));
                            let carried = self.weights[i] != [0.0; 4];
                            out.extend((0..4).filter(|_| carried).map(|k| TParam::Weight(i, k)));
                        }
                    }
                }
            }
        }
        out.extend((0..6).map(TParam::Base));
        for m in 0..self.markers.len() {
            out.extend((0..3).map(|a| TParam::Marker(m, a)));
        }
        out
    }

    /// Public name of a parameter (`<row>.alpha`, `<row>.kz_gx`, `base.x`, `<marker>.y`).
    pub fn param_name(&self, p: TParam) -> String {
        match p {
            TParam::Geometry(i, k) => format!("{}.{}", self.rows[i].name, GEOMETRY[k as usize]),
            TParam::Placement(i, k) => format!("{}.{}", self.rows[i].name, XYZABC[k as usize]),
            TParam::Elastic(i, k) => {
                format!("{}.{}", self.rows[i].name, COEFFICIENTS[k as usize])
            }
            TParam::Compliance(i, a) => {
                format!("{}.c_{}", self.rows[i].name, ["z", "x", "y"][a as usize])
            }
            TParam::Weight(i, k) => {
                format!(
                    "{}.{}",
                    self.rows[i].name,
                    ["w_mx", "w_my", "w_mz", "w"][k as usize]
                )
            }
            TParam::Base(k) => format!("base.{}", XYZABC[k as usize]),
            TParam::Marker(m, a) => {
                format!("{}.{}", self.markers[m].name, ["x", "y", "z"][a as usize])
            }
        }
    }

    /// SI unit of a parameter: `m`, `rad`, or `rad` at full gravity load for the lumped
    /// coefficients (compliance x first mass moment x 9.80665 m/s^2).
    pub fn param_unit(&self, p: TParam) -> &'static str {
        match p {
            TParam::Compliance(..) => "rad/(N*m)",
            TParam::Weight(_, 3) => "N",
            TParam::Weight(..) => "N*m",
            p if p.is_length() => "m",
            _ => "rad",
        }
    }

    /// Index of the parameter with this public name.
    pub fn param_by_name(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| self.param_name(*p) == name)
    }

    /// Current value of a parameter.
    pub fn value(&self, p: TParam) -> f64 {
        match p {
            TParam::Geometry(i, k) => match &self.rows[i].kind {
                RowKind::Revolute { geometry, .. } => geometry[k as usize],
                RowKind::Fixed { .. } => 0.0,
            },
            TParam::Placement(i, k) => match &self.rows[i].kind {
                RowKind::Fixed { errors, .. } => errors[k as usize],
                RowKind::Revolute { .. } => 0.0,
            },
            TParam::Elastic(i, k) => self.elastic[i][k as usize],
            TParam::Compliance(i, a) => self.compliance[i][a as usize],
            TParam::Weight(i, k) => self.weights[i][k as usize],
            TParam::Base(k) => self.base[k as usize],
            TParam::Marker(m, a) => self.markers[m].local[a as usize],
        }
    }

    /// All current values, in [`ElasticTree::params`] order.
    pub fn values(&self) -> Vec<f64> {
        self.params.iter().map(|p| self.value(*p)).collect()
    }

    /// Set one parameter.
    pub fn set(&mut self, p: TParam, v: f64) {
        match p {
            TParam::Geometry(i, k) => {
                if let RowKind::Revolute { geometry, .. } = &mut self.rows[i].kind {
                    geometry[k as usize] = v;
                }
            }
            TParam::Placement(i, k) => {
                if let RowKind::Fixed { errors, .. } = &mut self.rows[i].kind {
                    errors[k as usize] = v;
                }
            }
            TParam::Elastic(i, k) => self.elastic[i][k as usize] = v,
            TParam::Compliance(i, a) => self.compliance[i][a as usize] = v,
            TParam::Weight(i, k) => self.weights[i][k as usize] = v,
            TParam::Base(k) => self.base[k as usize] = v,
            TParam::Marker(m, a) => self.markers[m].local[a as usize] = v,
        }
    }

    /// Set the parameters `idx` (indices into [`ElasticTree::params`]) to `values`.
    pub fn set_values(&mut self, idx: &[usize], values: &[f64]) {
        for (&g, &v) in idx.iter().zip(values) {
            self.set(self.params[g], v);
        }
    }
}
