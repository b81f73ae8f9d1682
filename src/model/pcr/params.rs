//! The 28 robot parameters of the 3-PF model (9 per limb plus `E`), their names, units and
//! flat indexing, as `../shared/spec/pcr.md` names them (`Ax_1` is `Ax` of limb 1).

use super::PcrError;

/// Field names of one limb, in flat order.
pub const LIMB_FIELDS: [&str; 9] = ["Ax", "Ay", "gamma", "alpha", "Bx", "By", "beta", "l", "d"];
/// Number of robot parameters (3 limbs x 9 + E).
pub const ROBOT_PARAMS: usize = 28;
/// Flat index of `E`.
pub const E_INDEX: usize = 27;

/// Geometry and rod of one limb (SI: metres, radians).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimbParams {
    /// Proximal clamp x in {W} at q = 0.
    pub ax: f64,
    /// Proximal clamp y in {W} at q = 0.
    pub ay: f64,
    /// Angle of the stage axis in {W}.
    pub gamma: f64,
    /// Proximal tangent angle relative to the stage axis.
    pub alpha: f64,
    /// Distal clamp x in {P}.
    pub bx: f64,
    /// Distal clamp y in {P}.
    pub by: f64,
    /// Distal tangent angle in {P}.
    pub beta: f64,
    /// Rod length.
    pub l: f64,
    /// Rod diameter.
    pub d: f64,
}

impl LimbParams {
    fn field(&self, k: usize) -> f64 {
        [
            self.ax, self.ay, self.gamma, self.alpha, self.bx, self.by, self.beta, self.l, self.d,
        ][k]
    }

    fn field_mut(&mut self, k: usize) -> &mut f64 {
        match k {
            0 => &mut self.ax,
            1 => &mut self.ay,
            2 => &mut self.gamma,
            3 => &mut self.alpha,
            4 => &mut self.bx,
            5 => &mut self.by,
            6 => &mut self.beta,
            7 => &mut self.l,
            _ => &mut self.d,
        }
    }
}

/// All robot parameters: three limbs and the shared Young's modulus (Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcrParams {
    /// Limbs 1, 2, 3.
    pub limbs: [LimbParams; 3],
    /// Young's modulus of the rods (Pa).
    pub e: f64,
}

impl PcrParams {
    /// Value of the parameter with flat index `i` (< [`ROBOT_PARAMS`]).
    pub fn get(&self, i: usize) -> f64 {
        if i == E_INDEX {
            self.e
        } else {
            self.limbs[i / 9].field(i % 9)
        }
    }

    /// Sets the parameter with flat index `i` (< [`ROBOT_PARAMS`]).
    pub fn set(&mut self, i: usize, v: f64) {
        if i == E_INDEX {
            self.e = v;
        } else {
            *self.limbs[i / 9].field_mut(i % 9) = v;
        }
    }

    /// All parameters in flat order.
    pub fn to_array(&self) -> [f64; ROBOT_PARAMS] {
        std::array::from_fn(|i| self.get(i))
    }

    /// Parameters from the first [`ROBOT_PARAMS`] values of `v` in flat order (missing
    /// values are zero).
    pub fn from_slice(v: &[f64]) -> Self {
        let zero = LimbParams {
            ax: 0.0,
            ay: 0.0,
            gamma: 0.0,
            alpha: 0.0,
            bx: 0.0,
            by: 0.0,
            beta: 0.0,
            l: 0.0,
            d: 0.0,
        };
        let mut p = PcrParams {
            limbs: [zero; 3],
            e: 0.0,
        };
        for (k, x) in v.iter().take(ROBOT_PARAMS).enumerate() {
            p.set(k, *x);
        }
        p
    }

    /// Checks that every value is finite and lengths, diameters and `E` are positive.
    pub fn validate(&self) -> Result<(), PcrError> {
        for i in 0..ROBOT_PARAMS {
            let v = self.get(i);
            let bad = |reason: &str| PcrError::InvalidParameter {
                name: param_name(i),
                value: v,
                reason: reason.to_string(),
            };
            if !v.is_finite() {
                return Err(bad("not a finite number"));
            }
            let positive = i == E_INDEX || matches!(i % 9, 7 | 8);
            if positive && v <= 0.0 {
                return Err(bad("must be positive"));
            }
        }
        Ok(())
    }
}

/// Name of the parameter with flat index `i`: `Ax_1` ... `d_3`, `E`.
pub fn param_name(i: usize) -> String {
    if i == E_INDEX {
        "E".to_string()
    } else {
        format!("{}_{}", LIMB_FIELDS[i % 9], i / 9 + 1)
    }
}

/// Flat index of a parameter name, if it is one.
pub fn param_index(name: &str) -> Option<usize> {
    if name == "E" {
        return Some(E_INDEX);
    }
    let (field, limb) = name.rsplit_once('_')?;
    let limb: usize = limb.parse().ok()?;
    let k = LIMB_FIELDS.iter().position(|f| *f == field)?;
    (1..=3).contains(&limb).then_some((limb - 1) * 9 + k)
}

/// The type of a parameter (`Ax`, `gamma`, `E`, ...): the rows of the paper's Table 2.
pub fn param_type(i: usize) -> &'static str {
    if i == E_INDEX {
        "E"
    } else {
        LIMB_FIELDS[i % 9]
    }
}

/// SI unit of a parameter: `m`, `rad` or `Pa`.
pub fn param_unit(i: usize) -> &'static str {
    match param_type(i) {
        "E" => "Pa",
        "gamma" | "alpha" | "beta" => "rad",
        _ => "m",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_through_indices() {
        for i in 0..ROBOT_PARAMS {
            assert_eq!(param_index(&param_name(i)), Some(i));
        }
        assert_eq!(param_name(11), "gamma_2");
        assert_eq!(param_unit(11), "rad");
        assert_eq!(param_index("l_4"), None);
        assert_eq!(param_index("q_1"), None);
    }
}
