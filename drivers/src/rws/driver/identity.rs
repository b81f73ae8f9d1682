//! Who the RWS driver talks to: controller name and RobotWare version (`GET /rw/system`),
//! whether the calibd RAPID module is loaded in T_ROB1, and the controller state.
//!
//! Module list: RWS 1.0 (IRC5, RobotWare 6) lists the modules of a task with
//! `GET /rw/rapid/modules?task=T_ROB1` (the task resource links to it as
//! `modules?task=T_ROB1`); each `_state` item is a `rap-module-info-li` with `name` and
//! `type` (`ProgMod` / `SysMod`). `/rw/rapid/tasks/T_ROB1/modules` is the RWS 2.0
//! (OmniCore, RobotWare 7) form and is not used.

use serde::Serialize;

use super::{Actor, DEVICE, field, protocol};
use crate::error::DriverError;
use crate::identity::Identity;
use crate::link::Connect;

/// Name of the calibd RAPID module (`drivers/rapid/CalibServer.mod`).
pub const DEFAULT_CALIB_MODULE: &str = "CalibServer";

/// The RAPID task the calibd module runs in.
pub const TASK: &str = "T_ROB1";

/// Identity and readiness of an IRC5 controller.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RwsIdentity {
    /// Controller (system) name, `sys-system.name`.
    pub controller_name: String,
    /// RobotWare version, `sys-system.rwversion` (e.g. `6.15.1013`).
    pub robotware_version: String,
    /// RobotWare version name, `sys-system.rwversionname` (e.g. `6.15.01.00`).
    pub robotware_version_name: String,
    /// RAPID task inspected (`T_ROB1`).
    pub rapid_task: String,
    /// The calibd RAPID module looked for (default [`DEFAULT_CALIB_MODULE`]).
    pub calib_module: String,
    /// True when `calib_module` is among the task's modules.
    pub calib_module_loaded: bool,
    /// Every module of the task (program and system modules).
    pub rapid_modules: Vec<String>,
    /// `motoron`, `motoroff`, `guardstop`, `emergencystop`, ...
    pub ctrlstate: String,
    /// Operating mode: `AUTO`, `MANR`, `MANF`, ...
    pub opmode: String,
    /// RAPID execution state: `running` or `stopped`.
    pub execstate: String,
}

impl RwsIdentity {
    /// The error to report when the calib module is missing (None when it is loaded).
    pub fn module_error(&self) -> Option<DriverError> {
        (!self.calib_module_loaded).then(|| DriverError::Device {
            device: DEVICE,
            code: 0,
            message: module_fix(&self.calib_module, &self.rapid_task),
        })
    }
}

fn module_fix(module: &str, task: &str) -> String {
    format!(
        "RAPID module {module} is not loaded in {task}: load drivers/rapid/{module}.mod into \
         {task} (FlexPendant Program Editor > Load Module, or RobotStudio) and start the program"
    )
}

impl Identity for RwsIdentity {
    const DEVICE_KIND: &'static str = DEVICE;

    fn fingerprint(&self) -> String {
        format!(
            "{}, RobotWare {}",
            self.controller_name, self.robotware_version
        )
    }

    fn summary(&self) -> String {
        format!(
            "{}, RobotWare {}, {} {}, {} {} {}",
            self.controller_name,
            self.robotware_version_name,
            self.calib_module,
            if self.calib_module_loaded {
                "loaded"
            } else {
                "NOT loaded"
            },
            self.ctrlstate,
            self.opmode,
            self.execstate
        )
    }

    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if !self.calib_module_loaded {
            p.push(module_fix(&self.calib_module, &self.rapid_task));
        }
        if self.ctrlstate != "motoron" {
            p.push(format!(
                "motors are {}: switch the motors on (FlexPendant or the motors-on button)",
                self.ctrlstate
            ));
        }
        if self.opmode != "AUTO" {
            p.push(format!(
                "operating mode is {}: turn the key switch to AUTO",
                self.opmode
            ));
        }
        if self.execstate != "running" {
            p.push(format!(
                "RAPID execution is {}: start the program in {} (PP to main, then start)",
                self.execstate, self.rapid_task
            ));
        }
        p
    }
}

impl<C: Connect> Actor<C> {
    /// Reads system info, the module list of T_ROB1 and the controller state.
    pub(super) async fn identity(&mut self, module: String) -> Result<RwsIdentity, DriverError> {
        let sys = self.get_state("/rw/system").await?;
        let modules = self.modules(TASK).await?;
        let state = self.ctrl_state().await?;
        Ok(RwsIdentity {
            controller_name: field(&sys, "name")?,
            robotware_version: field(&sys, "rwversion")?,
            robotware_version_name: field(&sys, "rwversionname")?,
            rapid_task: TASK.into(),
            calib_module_loaded: modules.contains(&module),
            calib_module: module,
            rapid_modules: modules,
            ctrlstate: state.ctrlstate,
            opmode: state.opmode,
            execstate: state.execstate,
        })
    }

    /// Names of the modules loaded in `task` (RWS 1.0 `rap-module-info-li` items).
    async fn modules(&mut self, task: &str) -> Result<Vec<String>, DriverError> {
        let r = self
            .exchange(
                "GET",
                &format!("/rw/rapid/modules?task={task}&json=1"),
                None,
            )
            .await?;
        parse_modules(&r.body)
    }
}

/// Parses the JSON reply of `GET /rw/rapid/modules?task=...&json=1`.
pub fn parse_modules(body: &[u8]) -> Result<Vec<String>, DriverError> {
    let v: serde_json::Value =
        serde_json::from_slice(body).map_err(|e| protocol(format!("reply is not JSON: {e}")))?;
    let items = v
        .pointer("/_embedded/_state")
        .and_then(|s| s.as_array())
        .ok_or_else(|| protocol("module list has no _embedded._state array".into()))?;
    items
        .iter()
        .filter(|i| i.get("_type").and_then(|t| t.as_str()) == Some("rap-module-info-li"))
        .map(|i| field(i, "name"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_module_list() {
        let body = br#"{"_links":{"base":{"href":"http://127.0.0.1/rw/rapid/"}},"_embedded":{"_state":[
            {"_type":"rap-module-info-li","_title":"CalibServer","name":"CalibServer","type":"ProgMod"},
            {"_type":"rap-module-info-li","_title":"BASE","name":"BASE","type":"SysMod"},
            {"_type":"something-else","name":"x"}]}}"#;
        assert_eq!(parse_modules(body).unwrap(), ["CalibServer", "BASE"]);
        assert!(parse_modules(b"{}").is_err());
        assert!(
            parse_modules(br#"{"_embedded":{"_state":[{"_type":"rap-module-info-li"}]}}"#).is_err()
        );
    }

    #[test]
    fn problems_name_the_fix() {
        let id = RwsIdentity {
            controller_name: "IRB120-sim".into(),
            robotware_version: "6.15.1013".into(),
            robotware_version_name: "6.15.01.00".into(),
            rapid_task: TASK.into(),
            calib_module: "CalibServer".into(),
            calib_module_loaded: false,
            rapid_modules: vec!["BASE".into()],
            ctrlstate: "motoron".into(),
            opmode: "AUTO".into(),
            execstate: "running".into(),
        };
        let p = id.problems();
        assert_eq!(p.len(), 1);
        assert!(p[0].starts_with("RAPID module CalibServer is not loaded in T_ROB1: load drivers/rapid/CalibServer.mod"), "{p:?}");
        assert!(id.module_error().is_some());
        assert_eq!(
            id.summary(),
            "IRB120-sim, RobotWare 6.15.01.00, CalibServer NOT loaded, motoron AUTO running"
        );
    }
}
