//! The RWS resources the mock serves: motion system, RAPID symbols, execution, panel.

use serde_json::json;
use tokio::time::Instant;

use super::{Robot, error, files, json_response, no_content, state};
use crate::rws::http::{Request, Response, parse_form};
use crate::rws::rapid::{parse_jointtarget, parse_pos};

pub(super) fn route(r: &mut Robot, req: &Request) -> Response {
    let (path, query) = req.target.split_once('?').unwrap_or((&req.target, ""));
    let q: Vec<(String, String)> = parse_form(query);
    let action = q
        .iter()
        .find(|(k, _)| k == "action")
        .map(|(_, v)| v.as_str());
    let form = parse_form(&String::from_utf8_lossy(&req.body));
    let path = path.trim_end_matches('/');
    match (req.method.as_str(), path, action) {
        ("GET", "/rw/motionsystem/mechunits/ROB_1/jointtarget", _) => {
            let j = r.joints;
            let f = |v: f64| format!("{v:.4}");
            state(json!({"_type": "ms-jointtarget", "_title": "ROB_1",
                "rax_1": f(j[0]), "rax_2": f(j[1]), "rax_3": f(j[2]), "rax_4": f(j[3]), "rax_5": f(j[4]), "rax_6": f(j[5]),
                "eax_a": "9E+09", "eax_b": "9E+09", "eax_c": "9E+09", "eax_d": "9E+09", "eax_e": "9E+09", "eax_f": "9E+09"}))
        }
        ("GET", "/rw/motionsystem/mechunits/ROB_1/robtarget", _) => {
            let (p, qt) = r.model.tool_pose(&r.joints);
            let f = |v: f64| format!("{v:.6}");
            state(json!({"_type": "ms-robtargets", "_title": "ROB_1",
                "x": f(p[0]), "y": f(p[1]), "z": f(p[2]), "q1": f(qt[0]), "q2": f(qt[1]), "q3": f(qt[2]), "q4": f(qt[3]),
                "cf1": "0", "cf4": "0", "cf6": "0", "cfx": "0",
                "eaxa": "9E+09", "eaxb": "9E+09", "eaxc": "9E+09", "eaxd": "9E+09", "eaxe": "9E+09", "eaxf": "9E+09"}))
        }
        (m, p, a) if p.starts_with("/rw/rapid/symbol/data/RAPID/T_ROB1/") => {
            let var = p.rsplit('/').next().unwrap_or_default().to_string();
            if !r.vars.contains_key(&var) {
                return error(400, -1073445865, &format!("Symbol {var} not found"));
            }
            match (m, a) {
                ("GET", _) => state(
                    json!({"_type": "rap-data", "_title": format!("RAPID/T_ROB1/{var}"), "value": r.vars[&var]}),
                ),
                ("POST", Some("set")) => match form.iter().find(|(k, _)| k == "value") {
                    Some((_, v)) if valid_value(&var, v) => {
                        r.vars.insert(var, v.clone());
                        r.update(Instant::now());
                        no_content()
                    }
                    _ => error(400, -1073445879, "Invalid value for data type"),
                },
                _ => error(400, -1073445888, "Unsupported action"),
            }
        }
        ("GET", "/rw/rapid/execution", _) => {
            let s = if r.running { "running" } else { "stopped" };
            state(
                json!({"_type": "rap-execution", "_title": "execution", "ctrlexecstate": s, "cycle": "forever"}),
            )
        }
        ("POST", "/rw/rapid/execution", Some("start")) => {
            if !r.motors_on {
                return error(400, -1073442816, "Motors are off");
            }
            r.running = true;
            no_content()
        }
        ("POST", "/rw/rapid/execution", Some("stop")) => {
            r.running = false;
            r.motion = None;
            no_content()
        }
        ("POST", "/rw/rapid/execution", Some("resetpp")) => no_content(),
        ("GET", "/rw/rapid/tasks", _) => json_response(
            200,
            json!({"_embedded": {"_state": [
            {"_type": "rap-task-li", "_title": "T_ROB1", "name": "T_ROB1", "type": "normal",
             "taskstate": "started", "excstate": if r.running { "started" } else { "stopped" },
             "active": "On", "motiontask": "TRUE"}]}}),
        ),
        ("GET", "/rw/system", _) => state(json!({"_type": "sys-system", "_title": "system",
            "name": r.info.name, "rwversion": r.info.rwversion,
            "sysid": "{4C5C6B6E-3A0B-4F4B-9E64-4952423132305F}",
            "starttm": "2026-11-25 T 08:00:00", "rwversionname": r.info.rwversionname})),
        ("GET", "/rw/rapid/modules", _) => {
            let task = q.iter().find(|(k, _)| k == "task").map(|(_, v)| v.as_str());
            if task != Some("T_ROB1") {
                return error(400, -1073445876, "Task not found");
            }
            let item = |name: &str, ty: &str| json!({"_type": "rap-module-info-li", "_title": name, "name": name, "type": ty});
            let mut items: Vec<serde_json::Value> = r
                .info
                .program_modules
                .iter()
                .map(|m| item(m, "ProgMod"))
                .collect();
            items.push(item("BASE", "SysMod"));
            items.push(item("user", "SysMod"));
            json_response(200, json!({"_links": {}, "_embedded": {"_state": items}}))
        }
        ("GET", "/rw/panel/ctrlstate", _) => {
            let s = if r.motors_on { "motoron" } else { "motoroff" };
            state(json!({"_type": "pnl-ctrlstate", "_title": "ctrlstate", "ctrlstate": s}))
        }
        ("POST", "/rw/panel/ctrlstate", Some("setctrlstate")) => {
            match form
                .iter()
                .find(|(k, _)| k == "ctrl-state")
                .map(|(_, v)| v.as_str())
            {
                Some("motoron") => r.motors_on = true,
                Some("motoroff") => {
                    r.motors_on = false;
                    r.motion = None;
                }
                _ => return error(400, -1073445879, "Invalid ctrl-state"),
            }
            no_content()
        }
        ("GET", "/rw/panel/opmode", _) => {
            state(json!({"_type": "pnl-opmode", "_title": "opmode", "opmode": "AUTO"}))
        }
        ("POST", "/rw/mastership", Some("request")) => {
            r.mastership = true;
            no_content()
        }
        ("POST", "/rw/mastership", Some("release")) => {
            r.mastership = false;
            no_content()
        }
        ("POST", "/rw/mastership", _) | ("POST", "/rw/mastership/rapid", _) => no_content(),
        ("PUT", p, _) if p.starts_with("/fileservice/") => files::put(r, p, &req.body),
        ("GET", p, _) if p.starts_with("/fileservice/") => files::get(r, p),
        ("POST", "/rw/rapid/tasks/T_ROB1", Some("loadmod")) => files::loadmod(r, &form),
        _ => error(
            404,
            -1073479661,
            &format!("Resource {} not found", req.target),
        ),
    }
}

fn valid_value(var: &str, v: &str) -> bool {
    match var {
        "calib_q" => parse_jointtarget(v).is_some(),
        "calib_dp" => parse_pos(v).is_some(),
        _ => v.trim().parse::<f64>().is_ok(),
    }
}
