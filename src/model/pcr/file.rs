//! The 3-PF model file (JSON, as `../shared/data/robots/pcr3pf.json`): nominal parameters,
//! extrinsics, joint limits, repeatability and standard uncertainties, in SI units. Read with
//! unknown fields refused and every number checked; written back with identified values so
//! a calibrated model is a file of the same kind.

use serde::{Deserialize, Serialize};

use super::params::{E_INDEX, LimbParams, PcrParams};
use super::{Pcr, PcrError};
use crate::model::ModelError;

/// A 3-PF model file, field for field.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PcrFile {
    /// Always `"pcr3"`.
    pub kind: String,
    /// Human-readable name.
    pub name: String,
    /// Units of the file: length `m`, angle `rad`, modulus `Pa`.
    pub units: PcrUnits,
    /// Young's modulus of the rods (Pa).
    #[serde(rename = "E")]
    pub e: f64,
    /// Exactly three limbs.
    pub limbs: Vec<LimbEntry>,
    /// Sensor and pattern frames (planar transforms).
    pub extrinsics: Extrinsics,
    /// [lower, upper] of q1, q2, q3 (m).
    pub joint_limits: Vec<[f64; 2]>,
    /// Repeatability of the robot and sensor.
    pub repeatability: Repeatability,
    /// Standard uncertainty of each parameter type (bounds are nominal +/- 3 of these).
    pub uncertainty: Uncertainty,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
    /// Where the numbers come from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sources: Option<serde_json::Value>,
    /// Calibration provenance, added by calibd to calibrated files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<serde_json::Value>,
}

/// Units block.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PcrUnits {
    /// Must be `m`.
    pub length: String,
    /// Must be `rad`.
    pub angle: String,
    /// Must be `Pa`.
    pub modulus: String,
}

/// One limb entry (see the parameter table of `pcr.md`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
#[allow(non_snake_case)]
pub struct LimbEntry {
    /// Limb name.
    pub name: String,
    /// Proximal clamp x in {W} at q = 0 (m).
    pub Ax: f64,
    /// Proximal clamp y in {W} at q = 0 (m).
    pub Ay: f64,
    /// Stage axis angle in {W} (rad).
    pub gamma: f64,
    /// Proximal tangent relative to the stage axis (rad).
    pub alpha: f64,
    /// Distal clamp x in {P} (m).
    pub Bx: f64,
    /// Distal clamp y in {P} (m).
    pub By: f64,
    /// Distal tangent angle in {P} (rad).
    pub beta: f64,
    /// Rod length (m).
    pub l: f64,
    /// Rod diameter (m).
    pub d: f64,
}

/// Extrinsic parameters: W_T_Se = (sx, sy, stheta), M_T_P = (mx, my, mtheta).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Extrinsics {
    /// Sensor frame x in {W} (m).
    pub sx: f64,
    /// Sensor frame y in {W} (m).
    pub sy: f64,
    /// Sensor frame angle in {W} (rad).
    pub stheta: f64,
    /// Platform frame x in the pattern frame {M} (m).
    pub mx: f64,
    /// Platform frame y in {M} (m).
    pub my: f64,
    /// Platform frame angle in {M} (rad).
    pub mtheta: f64,
}

impl Extrinsics {
    /// The six values in the order sx, sy, stheta, mx, my, mtheta.
    pub fn to_array(&self) -> [f64; 6] {
        [self.sx, self.sy, self.stheta, self.mx, self.my, self.mtheta]
    }

    /// From the six values in the order of [`Extrinsics::to_array`].
    pub fn from_array(v: &[f64; 6]) -> Self {
        Self {
            sx: v[0],
            sy: v[1],
            stheta: v[2],
            mx: v[3],
            my: v[4],
            mtheta: v[5],
        }
    }
}

/// Repeatability (one standard deviation per coordinate).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Repeatability {
    /// Position (m).
    pub position: f64,
    /// Orientation (rad).
    pub orientation: f64,
}

/// Standard uncertainty of each parameter type (SI).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
#[allow(non_snake_case)]
pub struct Uncertainty {
    /// Of every Ax_i (m).
    pub Ax: f64,
    /// Of every Ay_i (m).
    pub Ay: f64,
    /// Of every gamma_i (rad).
    pub gamma: f64,
    /// Of every alpha_i (rad).
    pub alpha: f64,
    /// Of every Bx_i (m).
    pub Bx: f64,
    /// Of every By_i (m).
    pub By: f64,
    /// Of every beta_i (rad).
    pub beta: f64,
    /// Of every l_i (m).
    pub l: f64,
    /// Of every d_i (m).
    pub d: f64,
    /// Of E (Pa).
    pub E: f64,
    /// Of sx (m).
    pub sx: f64,
    /// Of sy (m).
    pub sy: f64,
    /// Of stheta (rad).
    pub stheta: f64,
    /// Of mx (m).
    pub mx: f64,
    /// Of my (m).
    pub my: f64,
    /// Of mtheta (rad).
    pub mtheta: f64,
}

impl Uncertainty {
    /// Uncertainty of each robot parameter in flat order (see [`PcrParams::get`]).
    pub fn robot(&self) -> [f64; super::ROBOT_PARAMS] {
        let limb = [
            self.Ax, self.Ay, self.gamma, self.alpha, self.Bx, self.By, self.beta, self.l, self.d,
        ];
        std::array::from_fn(|i| if i == E_INDEX { self.E } else { limb[i % 9] })
    }

    /// Uncertainty of the extrinsics in the order of [`Extrinsics::to_array`].
    pub fn extrinsics(&self) -> [f64; 6] {
        [self.sx, self.sy, self.stheta, self.mx, self.my, self.mtheta]
    }
}

fn field_err(field: impl Into<String>, reason: impl Into<String>) -> ModelError {
    ModelError::Field {
        field: field.into(),
        reason: reason.into(),
    }
}

impl PcrFile {
    /// Parses and checks a model file's JSON text.
    pub fn parse(text: &str) -> Result<Self, ModelError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let file: PcrFile = serde_path_to_error::deserialize(de)
            .map_err(|e| ModelError::Parse(format!("{} (at `{}`)", e.inner(), e.path())))?;
        file.check()?;
        Ok(file)
    }

    /// Parses a model given as a JSON value (a model inlined in a job).
    pub fn from_value(value: serde_json::Value) -> Result<Self, ModelError> {
        let file: PcrFile = serde_path_to_error::deserialize(value)
            .map_err(|e| ModelError::Parse(format!("{} (at `{}`)", e.inner(), e.path())))?;
        file.check()?;
        Ok(file)
    }

    /// Checks kind, units, counts and every number.
    pub fn check(&self) -> Result<(), ModelError> {
        if self.kind != "pcr3" {
            return Err(field_err(
                "kind",
                format!("expected \"pcr3\", found {:?}", self.kind),
            ));
        }
        let u = &self.units;
        for (f, v, want) in [
            ("length", &u.length, "m"),
            ("angle", &u.angle, "rad"),
            ("modulus", &u.modulus, "Pa"),
        ] {
            if v != want {
                return Err(field_err(
                    format!("units.{f}"),
                    format!("expected {want:?}, found {v:?}"),
                ));
            }
        }
        if self.limbs.len() != 3 {
            return Err(field_err(
                "limbs",
                format!("expected 3 limbs, found {}", self.limbs.len()),
            ));
        }
        if self.joint_limits.len() != 3 {
            let n = self.joint_limits.len();
            return Err(field_err(
                "joint_limits",
                format!("expected 3 [lower, upper] pairs, found {n}"),
            ));
        }
        let params = self.params();
        if let Err(PcrError::InvalidParameter {
            name,
            value,
            reason,
        }) = params.validate()
        {
            let (field, limb) = name.rsplit_once('_').unwrap_or((name.as_str(), ""));
            let path = match limb.parse::<usize>() {
                Ok(k) => format!("limbs[{}].{field}", k - 1),
                Err(_) => field.to_string(),
            };
            return Err(field_err(path, format!("{value}: {reason}")));
        }
        for (k, [lo, hi]) in self.joint_limits.iter().enumerate() {
            if !(lo.is_finite() && hi.is_finite() && *lo <= 0.0 && *hi >= 0.0 && lo < hi) {
                return Err(field_err(
                    format!("joint_limits[{k}]"),
                    format!("[{lo}, {hi}] must be finite, ordered and contain 0"),
                ));
            }
        }
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(field_err(name, format!("{v} is not finite")))
            }
        };
        let ex = self.extrinsics.to_array();
        for (k, name) in ["sx", "sy", "stheta", "mx", "my", "mtheta"]
            .iter()
            .enumerate()
        {
            finite(&format!("extrinsics.{name}"), ex[k])?;
        }
        let rep = &self.repeatability;
        for (name, v) in [("position", rep.position), ("orientation", rep.orientation)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(field_err(
                    format!("repeatability.{name}"),
                    format!("{v} must be positive"),
                ));
            }
        }
        let u = &self.uncertainty;
        let list = [
            ("Ax", u.Ax),
            ("Ay", u.Ay),
            ("gamma", u.gamma),
            ("alpha", u.alpha),
            ("Bx", u.Bx),
            ("By", u.By),
            ("beta", u.beta),
            ("l", u.l),
            ("d", u.d),
            ("E", u.E),
            ("sx", u.sx),
            ("sy", u.sy),
            ("stheta", u.stheta),
            ("mx", u.mx),
            ("my", u.my),
            ("mtheta", u.mtheta),
        ];
        for (name, v) in list {
            if !(v.is_finite() && v >= 0.0) {
                return Err(field_err(
                    format!("uncertainty.{name}"),
                    format!("{v} must be >= 0"),
                ));
            }
        }
        Ok(())
    }

    /// The robot parameters of the file.
    pub fn params(&self) -> PcrParams {
        let limb = |e: &LimbEntry| LimbParams {
            ax: e.Ax,
            ay: e.Ay,
            gamma: e.gamma,
            alpha: e.alpha,
            bx: e.Bx,
            by: e.By,
            beta: e.beta,
            l: e.l,
            d: e.d,
        };
        PcrParams {
            limbs: std::array::from_fn(|i| limb(&self.limbs[i])),
            e: self.e,
        }
    }

    /// Joint limits as a fixed array (the file has been checked to hold three).
    pub fn limits(&self) -> [[f64; 2]; 3] {
        std::array::from_fn(|i| self.joint_limits[i])
    }

    /// The solvable robot of this file (unloaded, default solver settings).
    pub fn robot(&self) -> Result<Pcr, PcrError> {
        Pcr::new(self.params(), self.limits())
    }

    /// A copy of this file with other robot parameters and extrinsics (a calibrated model).
    pub fn with_values(&self, params: &PcrParams, extrinsics: &Extrinsics) -> PcrFile {
        let mut out = self.clone();
        for (e, p) in out.limbs.iter_mut().zip(&params.limbs) {
            e.Ax = p.ax;
            e.Ay = p.ay;
            e.gamma = p.gamma;
            e.alpha = p.alpha;
            e.Bx = p.bx;
            e.By = p.by;
            e.beta = p.beta;
            e.l = p.l;
            e.d = p.d;
        }
        out.e = params.e;
        out.extrinsics = *extrinsics;
        out
    }
}
