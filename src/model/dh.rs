//! DH model files (JSON, as `../shared/data/robots/irb120.json`): read into a [`Chain`] and
//! written back with identified values, so a calibrated model is a file of the same kind.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::ModelError;
use super::chain::{Chain, Geometry, Joint, PointMass, Units};
use super::joint::{JointKind, Mimic, link_mimics};

/// A DH model file, field for field.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhFile {
    /// Always `"serial"`.
    pub kind: String,
    /// Human-readable name.
    pub name: String,
    /// Units of every number in the file.
    pub units: DhUnits,
    /// Joint entries: entry i carries alpha, a, beta of i-1 and d, theta_offset of i.
    pub joints: Vec<DhJoint>,
    /// Robot frame {0} in the world frame {W}.
    pub base: Xyzabc,
    /// TCP frame in the flange frame.
    pub tool: Xyzabc,
    /// Gravity in the robot frame.
    pub gravity: Gravity,
    /// Link masses, one per joint, centres of mass in {0} at q = 0.
    #[serde(default)]
    pub links: Vec<DhLink>,
    /// Payload carried by the flange.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload: Option<Payload>,
    /// Default list of parameters to identify.
    #[serde(default)]
    pub identify: Vec<String>,
    /// Where the numbers come from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sources: Option<serde_json::Value>,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
    /// Calibration provenance, added by calibd to calibrated files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<serde_json::Value>,
}

/// Units block of a DH file.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhUnits {
    /// `mm` or `m`.
    pub length: String,
    /// `deg` or `rad`.
    pub angle: String,
    /// `kg`.
    pub mass: String,
    /// `deg/(N*m)` or `rad/(N*m)` (must match `angle`).
    pub compliance: String,
}

/// One joint entry.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhJoint {
    /// Joint name.
    pub name: String,
    /// alpha[i-1].
    pub alpha: f64,
    /// a[i-1].
    pub a: f64,
    /// beta[i-1] (Hayati).
    #[serde(default)]
    pub beta: f64,
    /// d[i].
    pub d: f64,
    /// theta_offset[i].
    pub theta_offset: f64,
    /// c[i] (revolute rows with their own variable only).
    #[serde(default)]
    pub compliance: f64,
    /// [lower, upper] of q[i] (angle unit; length unit for a prismatic row).
    pub limits: [f64; 2],
    /// What the row's variable moves: `revolute` (theta, the default) or `prismatic` (d).
    #[serde(default, rename = "type", skip_serializing_if = "RowType::is_revolute")]
    pub row_type: RowType,
    /// A coupling row: its variable follows another row's instead of a table column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mimic: Option<DhMimic>,
}

/// The variable of a DH row: theta (revolute), d (prismatic), or none (fixed).
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum RowType {
    /// `theta = q + theta_offset`.
    #[default]
    Revolute,
    /// `d_total = d + q`, theta = theta_offset constant.
    Prismatic,
    /// No variable and no table column: a constant transform (e.g. a mount or branch point);
    /// its `limits` are ignored.
    Fixed,
}

impl RowType {
    /// For `skip_serializing_if`: revolute is the default and is not written.
    pub fn is_revolute(&self) -> bool {
        *self == RowType::Revolute
    }

    /// The chain joint kind.
    pub fn kind(self) -> JointKind {
        match self {
            RowType::Revolute => JointKind::Revolute,
            RowType::Prismatic => JointKind::Prismatic,
            RowType::Fixed => JointKind::Fixed,
        }
    }
}

/// A DH coupling row: `variable = multiplier * leader's variable + offset`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhMimic {
    /// Name of the leader row (a row with its own variable in the same chain).
    pub joint: String,
    /// Follower unit per leader unit in file units (1 between two rows of the same type).
    #[serde(default = "one")]
    pub multiplier: f64,
    /// Constant in the follower's file unit (deg/rad or mm/m).
    #[serde(default)]
    pub offset: f64,
}

fn one() -> f64 {
    1.0
}

/// A pose x, y, z, a, b, c (`Dx Dy Dz Rz(a) Ry(b) Rx(c)`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Xyzabc {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// Rotation about z.
    pub a: f64,
    /// Rotation about y.
    pub b: f64,
    /// Rotation about x.
    pub c: f64,
}

/// Gravity block.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    /// m/s^2.
    pub magnitude: f64,
    /// Direction in {0} (normalised on load).
    pub direction_in_base: [f64; 3],
}

/// One link mass.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DhLink {
    /// Link name.
    pub name: String,
    /// kg.
    pub mass: f64,
    /// Centre of mass in {0} with every q = 0.
    pub com_at_home_in_base: [f64; 3],
}

/// The payload carried by the flange.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Payload {
    /// kg.
    pub mass: f64,
    /// Centre of mass in the flange frame.
    pub com_in_flange: [f64; 3],
}

impl Xyzabc {
    fn to_internal(self, deg: f64) -> [f64; 6] {
        [
            self.x,
            self.y,
            self.z,
            self.a * deg,
            self.b * deg,
            self.c * deg,
        ]
    }
    fn from_internal(v: &[f64; 6], to_deg: f64) -> Self {
        Xyzabc {
            x: v[0],
            y: v[1],
            z: v[2],
            a: v[3] * to_deg,
            b: v[4] * to_deg,
            c: v[5] * to_deg,
        }
    }
}

fn field(field: impl Into<String>, reason: impl Into<String>) -> ModelError {
    ModelError::Field {
        field: field.into(),
        reason: reason.into(),
    }
}

impl DhFile {
    /// Parse a DH model file from JSON text.
    pub fn parse(text: &str) -> Result<Self, ModelError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        serde_path_to_error::deserialize(de)
            .map_err(|e| ModelError::Parse(format!("{} (at `{}`)", e.inner(), e.path())))
    }

    /// Parse from an already-decoded JSON value.
    pub fn from_value(v: serde_json::Value) -> Result<Self, ModelError> {
        serde_path_to_error::deserialize(v)
            .map_err(|e| ModelError::Parse(format!("{} (at `{}`)", e.inner(), e.path())))
    }

    fn units(&self) -> Result<Units, ModelError> {
        self.units.to_units()
    }
}

impl DhUnits {
    /// The unit system, checked (`units.length`, `units.angle`, ... named on error).
    pub fn to_units(&self) -> Result<Units, ModelError> {
        let mm = match self.length.as_str() {
            "mm" => true,
            "m" => false,
            other => return Err(field("units.length", format!("`{other}` is not mm or m"))),
        };
        let deg = match self.angle.as_str() {
            "deg" => true,
            "rad" => false,
            other => return Err(field("units.angle", format!("`{other}` is not deg or rad"))),
        };
        let want = if deg { "deg/(N*m)" } else { "rad/(N*m)" };
        if self.compliance != want {
            return Err(field(
                "units.compliance",
                format!(
                    "`{}` must be `{want}` with angles in {}",
                    self.compliance, self.angle
                ),
            ));
        }
        if self.mass != "kg" {
            return Err(field("units.mass", format!("`{}` is not kg", self.mass)));
        }
        Ok(Units { mm, deg })
    }
}

impl DhJoint {
    /// The chain joint of this row (MDH geometry, internal units; `k` = rad per file angle
    /// unit), its mimic unresolved; `at` names the row in errors (e.g. `joints[3]`).
    pub(crate) fn to_joint(&self, k: f64, at: &str) -> Result<Joint, ModelError> {
        let j = self;
        let vals = [
            j.alpha,
            j.a,
            j.beta,
            j.d,
            j.theta_offset,
            j.compliance,
            j.limits[0],
            j.limits[1],
        ];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err(field(at, "every number must be finite"));
        }
        if j.limits[0] >= j.limits[1] {
            return Err(field(
                format!("{at}.limits"),
                format!("lower {} is not below upper {}", j.limits[0], j.limits[1]),
            ));
        }
        let kind = j.row_type.kind();
        if j.compliance != 0.0 && (kind != JointKind::Revolute || j.mimic.is_some()) {
            return Err(field(
                format!("{at}.compliance"),
                "only a revolute row with its own variable has a compliance",
            ));
        }
        // Internal per file unit of this row's variable.
        let unit = |t: RowType| if t == RowType::Prismatic { 1.0 } else { k };
        let mimic = match (&j.mimic, kind) {
            (None, _) => None,
            (Some(_), JointKind::Fixed) => {
                return Err(field(format!("{at}.mimic"), "a fixed row has no variable"));
            }
            (Some(m), _) => {
                if !m.multiplier.is_finite() || !m.offset.is_finite() {
                    return Err(field(format!("{at}.mimic"), "numbers must be finite"));
                }
                Some(Mimic {
                    leader: usize::MAX,
                    leader_name: m.joint.clone(),
                    // Converted to follower-internal per leader-internal in link_mimics.
                    multiplier: m.multiplier * unit(j.row_type),
                    offset: m.offset * unit(j.row_type),
                })
            }
        };
        let lim = unit(j.row_type);
        Ok(Joint {
            name: j.name.clone(),
            geometry: Geometry::Mdh {
                alpha: j.alpha * k,
                a: j.a,
                beta: j.beta * k,
                d: j.d,
            },
            kind,
            mimic,
            offset: j.theta_offset * k,
            compliance: j.compliance * k,
            limits: (kind != JointKind::Fixed).then_some([j.limits[0] * lim, j.limits[1] * lim]),
            effort: None,
        })
    }
}

impl DhFile {
    /// Build the chain (internal units: radians, the file's length unit).
    pub fn to_chain(&self) -> Result<Chain, ModelError> {
        if self.kind != "serial" {
            return Err(field("kind", format!("`{}` is not `serial`", self.kind)));
        }
        let units = self.units()?;
        let k = if units.deg {
            std::f64::consts::PI / 180.0
        } else {
            1.0
        };
        if self.joints.is_empty() {
            return Err(field("joints", "at least one joint is needed"));
        }
        let mut joints = Vec::with_capacity(self.joints.len());
        for (i, j) in self.joints.iter().enumerate() {
            joints.push(j.to_joint(k, &format!("joints[{i}]"))?);
        }
        link_mimics(&mut joints, k)
            .map_err(|(i, reason)| field(format!("joints[{i}].mimic"), reason))?;
        let g = Vector3::from(self.gravity.direction_in_base);
        if !(g.norm() > 0.0) || !self.gravity.magnitude.is_finite() {
            return Err(field(
                "gravity",
                "direction must be a non-zero vector and magnitude finite",
            ));
        }
        let gravity = g.normalize() * self.gravity.magnitude;
        let mut chain = Chain::new(
            joints,
            self.base.to_internal(k),
            self.tool.to_internal(k),
            gravity,
            Vec::new(),
            units,
        );
        if !self.links.is_empty() && self.links.len() != self.joints.len() {
            return Err(field(
                "links",
                format!(
                    "{} links for {} joints (one link per joint)",
                    self.links.len(),
                    self.joints.len()
                ),
            ));
        }
        // Centres of mass are given in {0} at q = 0: carry them into each link's frame
        // with the geometry as loaded (compliance off).
        let mut frames = Vec::new();
        chain.joint_frames(&vec![0.0; chain.dof()], None, &mut frames);
        let mut masses = Vec::new();
        for (i, l) in self.links.iter().enumerate() {
            if !(l.mass >= 0.0) || l.com_at_home_in_base.iter().any(|v| !v.is_finite()) {
                return Err(field(
                    format!("links[{i}]"),
                    "mass must be >= 0 and the centre of mass finite",
                ));
            }
            let com = frames[i]
                .inverse()
                .apply(&Vector3::from(l.com_at_home_in_base));
            masses.push(PointMass {
                name: l.name.clone(),
                body: i,
                mass: l.mass,
                com,
            });
        }
        if let Some(p) = &self.payload {
            if !(p.mass >= 0.0) || p.com_in_flange.iter().any(|v| !v.is_finite()) {
                return Err(field(
                    "payload",
                    "mass must be >= 0 and the centre of mass finite",
                ));
            }
            masses.push(PointMass {
                name: "payload".into(),
                body: self.joints.len() - 1,
                mass: p.mass,
                com: Vector3::from(p.com_in_flange),
            });
        }
        chain.masses = masses;
        for name in &self.identify {
            chain
                .param_by_name(name)
                .map_err(|_| field("identify", format!("unknown parameter name `{name}`")))?;
        }
        Ok(chain)
    }

    /// This file with the geometry, offsets, compliances, base and tool of `chain` (which
    /// must have been built from a file of the same layout). Centres of mass are moved so
    /// that each stays where it is on its link.
    pub fn with_chain(&self, chain: &Chain) -> DhFile {
        let to = chain.units.to_file(super::Quantity::Angle);
        let mut out = self.clone();
        for (entry, joint) in out.joints.iter_mut().zip(&chain.joints) {
            if let Geometry::Mdh { alpha, a, beta, d } = joint.geometry {
                entry.alpha = alpha * to;
                entry.a = a;
                entry.beta = beta * to;
                entry.d = d;
            }
            entry.theta_offset = joint.offset * to;
            entry.compliance = joint.compliance * to;
            if let (Some(m), Some(e)) = (&joint.mimic, entry.mimic.as_mut()) {
                e.multiplier = m.multiplier * mimic_scale(chain, joint, m, to);
            }
        }
        out.base = Xyzabc::from_internal(&chain.base, to);
        out.tool = Xyzabc::from_internal(&chain.tool, to);
        let mut frames = Vec::new();
        chain.joint_frames(&vec![0.0; chain.dof()], None, &mut frames);
        for (i, l) in out.links.iter_mut().enumerate() {
            if let Some(m) = chain
                .masses
                .iter()
                .find(|m| m.body == i && m.name == l.name)
            {
                let c = frames[i].apply(&m.com);
                l.com_at_home_in_base = [c.x, c.y, c.z];
            }
        }
        out
    }
}

/// File multiplier per internal multiplier of a coupling (`to` = file per internal angle).
fn mimic_scale(chain: &Chain, follower: &Joint, m: &Mimic, to: f64) -> f64 {
    let per = |kind: JointKind| {
        if kind == JointKind::Prismatic {
            1.0
        } else {
            to
        }
    };
    let leader = chain
        .actuated()
        .get(m.leader)
        .map_or(JointKind::Revolute, |&j| chain.joints[j].kind);
    per(follower.kind) / per(leader)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const IRB120: &str = include_str!("../../tests/data/robots/irb120.json");

    #[test]
    fn irb120_loads_with_spec_conventions() {
        let f = DhFile::parse(IRB120).expect("irb120.json parses");
        let c = f.to_chain().expect("chain builds");
        assert_eq!(c.dof(), 6);
        // The 31 names of the spec all resolve.
        assert_eq!(f.identify.len(), 31);
        // Wrist centre at q = 0 in {0}: x = a2 + d4 (70 + 302), z = d1 + a2 (290 + 270).
        let fl = c.flange(&[0.0; 6], None);
        // Flange: wrist centre plus d6 = 72 along +x (joint 6 axis points forward at home).
        assert!(
            (fl.p - Vector3::new(302.0 + 72.0, 0.0, 290.0 + 270.0 + 70.0)).norm() < 1e-9,
            "{:?}",
            fl.p
        );
    }

    #[test]
    fn unknown_field_and_bad_units_are_named() {
        let bad = IRB120.replacen("\"name\": \"j1\"", "\"name\": \"j1\", \"alhpa\": 0", 1);
        let e = DhFile::parse(&bad).unwrap_err().to_string();
        assert!(e.contains("alhpa") && e.contains("joints[0]"), "{e}");
        let mut f = DhFile::parse(IRB120).unwrap();
        f.units.length = "inch".into();
        let e = f.to_chain().unwrap_err().to_string();
        assert!(e.contains("units.length") && e.contains("inch"), "{e}");
    }

    #[test]
    fn write_back_round_trips() {
        let f = DhFile::parse(IRB120).unwrap();
        let mut c = f.to_chain().unwrap();
        let id = c.param_by_name("a2").unwrap();
        c.set_param(id, 270.5);
        let back = f.with_chain(&c).to_chain().unwrap();
        let q = [0.1, 0.2, -0.3, 0.4, 0.5, 0.6];
        assert!((back.tcp(&q, None).p - c.tcp(&q, None).p).norm() < 1e-9);
        let (t1, t2) = (back.static_torques(&q), c.static_torques(&q));
        for k in 0..6 {
            assert!((t1[k] - t2[k]).abs() < 1e-9);
        }
    }
}
