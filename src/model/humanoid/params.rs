//! Parameters of the humanoid model: names, units, values, and setting them consistently
//! in every chain that shares a joint; joint limits and efforts of the measured variables.

use super::{BaseMode, HParam, Humanoid, TreeChain};
use crate::model::params::{URDF_ERRORS, XYZABC};
use crate::model::{Chain, JointField, ParamId};

impl Humanoid {
    /// Public name of a parameter.
    pub fn param_name(&self, p: HParam) -> String {
        let base = match self.base_mode {
            BaseMode::SupportFoot { .. } => "foot",
            _ => "base",
        };
        match p {
            HParam::Joint(j, f) => {
                let n = &self.joints[j].name;
                match f {
                    JointField::Err(k) => format!("{n}.{}", URDF_ERRORS[k as usize]),
                    JointField::Offset => format!("{n}.offset"),
                    _ => format!("{n}.c"),
                }
            }
            HParam::Base(k) => format!("{base}.{}", XYZABC[k as usize]),
            HParam::BaseCompliance(k) => {
                format!(
                    "base_compliance.{}",
                    ["x", "y", "z", "rx", "ry", "rz"][k as usize]
                )
            }
            HParam::Marker(m, a) => {
                format!("{}.{}", self.markers[m].name, ["x", "y", "z"][a as usize])
            }
        }
    }

    /// SI unit of a parameter.
    pub fn param_unit(&self, p: HParam) -> &'static str {
        match p {
            HParam::Joint(_, JointField::Err(k)) | HParam::Base(k) if k < 3 => "m",
            HParam::Joint(_, JointField::Compliance) => "rad/(N*m)",
            HParam::BaseCompliance(k) if k < 3 => "m/N",
            HParam::BaseCompliance(_) => "rad/(N*m)",
            HParam::Marker(..) => "m",
            _ => "rad",
        }
    }

    /// Index of the parameter with this public name.
    pub fn param_by_name(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| self.param_name(*p) == name)
    }

    /// Current value of a parameter.
    pub fn value(&self, p: HParam) -> f64 {
        match p {
            HParam::Joint(j, f) => {
                let (tc, k) = self.joint_home(j);
                tc.chain.param(ParamId::Joint(k, f))
            }
            HParam::Base(k) => self.base[k as usize],
            HParam::BaseCompliance(k) => self.base_compliance[k as usize],
            HParam::Marker(m, a) => self.marker_pos[m][a as usize],
        }
    }

    /// All current values, in [`Humanoid::params`] order.
    pub fn values(&self) -> Vec<f64> {
        self.params.iter().map(|p| self.value(*p)).collect()
    }

    /// Set the parameters `idx` (indices into [`Humanoid::params`]) to `values`.
    pub fn set_values(&mut self, idx: &[usize], values: &[f64]) {
        let mut per_chain: Vec<(Vec<ParamId>, Vec<f64>)> =
            vec![(Vec::new(), Vec::new()); self.chains.len() + 1];
        for (&g, &v) in idx.iter().zip(values) {
            match self.params[g] {
                HParam::Joint(j, f) => {
                    let all = self.chains.iter().chain(self.support.iter());
                    for (c, tc) in all.enumerate() {
                        if let Some(k) = tc.joints.iter().position(|&x| x == j) {
                            per_chain[c].0.push(ParamId::Joint(k, f));
                            per_chain[c].1.push(v);
                        }
                    }
                }
                HParam::Base(k) => self.base[k as usize] = v,
                HParam::BaseCompliance(k) => self.base_compliance[k as usize] = v,
                HParam::Marker(m, a) => self.marker_pos[m][a as usize] = v,
            }
        }
        let all = self.chains.iter_mut().chain(self.support.iter_mut());
        for (tc, (ids, vals)) in all.zip(per_chain) {
            if !ids.is_empty() {
                tc.chain.set_params(&ids, &vals);
            }
        }
    }

    /// Set every parameter from a full value vector.
    pub fn set_all(&mut self, values: &[f64]) {
        let idx: Vec<usize> = (0..self.params.len()).collect();
        self.set_values(&idx, values);
    }

    /// A chain holding tree joint `j` and its index there.
    fn joint_home(&self, j: usize) -> (&TreeChain, usize) {
        for tc in self.chains.iter().chain(self.support.iter()) {
            if let Some(k) = tc.joints.iter().position(|&x| x == j) {
                return (tc, k);
            }
        }
        unreachable!("every tree joint belongs to a chain")
    }

    /// The serial chains (root to each leaf marker link), with calibrated values applied.
    pub fn chains(&self) -> impl Iterator<Item = &Chain> {
        self.chains
            .iter()
            .chain(self.support.iter())
            .map(|tc| &tc.chain)
    }

    /// Names of the measured joints on the support leg (empty without one).
    pub fn support_variables(&self) -> Vec<String> {
        self.support
            .iter()
            .flat_map(|tc| tc.vars.iter().map(|&v| self.variables[v].clone()))
            .collect()
    }

    /// Limits (rad) of each measured variable, if the URDF gives them.
    pub fn limits(&self) -> Vec<Option<[f64; 2]>> {
        self.variables
            .iter()
            .map(|v| {
                let j = self.joints.iter().position(|j| &j.name == v)?;
                let (tc, k) = self.joint_home(j);
                tc.chain.joints[k].limits
            })
            .collect()
    }

    /// Effort limits (N*m) of each measured variable, if known.
    pub fn efforts(&self) -> Vec<Option<f64>> {
        self.variables
            .iter()
            .map(|v| {
                let j = self.joints.iter().position(|j| &j.name == v)?;
                let (tc, k) = self.joint_home(j);
                tc.chain.joints[k].effort
            })
            .collect()
    }
}
