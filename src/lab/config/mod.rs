//! A lab from its configuration file: the cells of a real lab and the addresses, serial
//! ports and credentials of their devices, read into the same [`CellLink`] descriptions the
//! simulated lab produces. Everything is checked before a device is contacted: unknown
//! keys, missing device sections, model files that do not parse, inline passwords; each
//! error names the file, the line and the key. A device that is absent (an unplugged
//! receiver's serial port) is not a file error: its cell is unavailable, the rest serve. Secrets come from a
//! file or an environment variable and are never logged or echoed.
//!
//! The format is documented in `deploy/lab.example.toml`.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use calibd_drivers::uwave::AxisMap;
use serde::Deserialize;
use toml::Spanned;

use super::connect::{
    BallCentringCell, CameraLink, CellLink, FrameSourceLink, JointsLink, MocapCellLink,
    PcrCellLink, PoseSourceLink, RwsLink, StageBackend, StagesLink, UwaveLink,
};
use super::resume::{DEFAULT_MAX_AUTO_RESUMES, ResumeMode, ResumePolicy};
use crate::model::dh::DhFile;
use crate::model::humanoid::MarkerDef;
use crate::model::pcr::PcrFile;

/// Why a lab file was refused: the file, the line (1-based, 0 when unknown) and what.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}:{line}: {message}", file.display())]
pub struct LabConfigError {
    /// The lab file.
    pub file: PathBuf,
    /// Line of the offending key (1-based; 0 when the error is not tied to a line).
    pub line: usize,
    /// What is wrong, naming the key.
    pub message: String,
}

/// The kinds of cell a lab file can describe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum Kind {
    BallCentring,
    Pcr,
    Humanoid,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LabFile {
    #[serde(rename = "cell", default)]
    cells: Vec<Spanned<CellSpec>>,
}

/// One `[[cell]]`: the keys of every kind; which are required depends on `kind`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellSpec {
    name: Spanned<String>,
    kind: Kind,
    /// Model file, relative to the lab file: DH JSON, 3-PF JSON or URDF.
    model: Spanned<PathBuf>,
    #[serde(default)]
    ballbar_mm: Option<Ballbar>,
    #[serde(default)]
    controller: Option<Spanned<RwsSpec>>,
    #[serde(default)]
    indicators: Option<Spanned<UwaveSpec>>,
    #[serde(default)]
    stages: Option<Spanned<StagesSpec>>,
    #[serde(default)]
    microscope: Option<Spanned<AddressSpec>>,
    /// The microscope's camera, when calibd computes the pose itself.
    #[serde(default)]
    camera: Option<Spanned<CameraSpec>>,
    #[serde(default)]
    mocap: Option<Spanned<QtmSpec>>,
    #[serde(default)]
    joints: Option<Spanned<JointsSpec>>,
    #[serde(default)]
    envelope: EnvelopeSpec,
    /// Who resumes a campaign paused on a device fault: `operator` (default) or `auto`.
    #[serde(default)]
    resume: Option<Spanned<String>>,
    /// Automatic resumes allowed per job (with `resume = "auto"`).
    #[serde(default)]
    max_auto_resumes: Option<Spanned<i64>>,
    /// Folder (relative to the lab file) to record this cell's device traffic to.
    #[serde(default)]
    record: Option<Spanned<PathBuf>>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct Ballbar {
    d12: f64,
    d13: f64,
    d23: f64,
}

/// The controller; its password is given by file or environment variable, an inline
/// value is refused.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RwsSpec {
    address: Spanned<String>,
    #[serde(default = "default_rws_user")]
    user: String,
    #[serde(default)]
    password_file: Option<Spanned<PathBuf>>,
    #[serde(default)]
    password_env: Option<Spanned<String>>,
    /// Present only to refuse it with a clear message (never echoed).
    #[serde(default)]
    password: Option<Spanned<toml::Value>>,
    #[serde(default = "default_module")]
    module: String,
    /// Joint speed of the RAPID module's moves (deg/s), for estimated durations.
    #[serde(default)]
    joint_speed_deg_s: Option<f64>,
}

fn default_rws_user() -> String {
    "Default User".into()
}

fn default_module() -> String {
    "CalibServer".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct UwaveSpec {
    port: Spanned<String>,
    #[serde(default = "default_baud")]
    baud: u32,
    /// Data-request template (`{cc}`, `{gg}`); empty waits for spontaneous readings.
    #[serde(default)]
    request: String,
    axes: Spanned<Vec<AxisSpec>>,
}

fn default_baud() -> u32 {
    57_600
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisSpec {
    channel: u8,
    #[serde(default = "one")]
    sign: f64,
    #[serde(default)]
    zero_mm: f64,
    #[serde(default)]
    range_mm: Option<[f64; 2]>,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "lowercase")]
enum StageKind {
    Mcs2,
    Mcs,
    Cia402,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StagesSpec {
    controller: StageKind,
    /// `host:port` of the controller (MCS2, MCS over TCP) or of socketcand.
    #[serde(default)]
    address: Option<Spanned<String>>,
    /// socketcand bus name, or the SocketCAN interface when no address is given.
    #[serde(default)]
    can_interface: Option<String>,
    channels: [u8; 3],
    #[serde(default)]
    pm_per_count: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AddressSpec {
    address: Spanned<String>,
}

/// `[cell.camera]`: where the frames come from, the acquisition settings and the pattern.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    source: CameraSourceKind,
    /// `host:port` of a `calibd-frames/1` server (source = "network").
    #[serde(default)]
    address: Option<Spanned<String>>,
    /// Folder the frames are written to (source = "folder").
    #[serde(default)]
    folder: Option<PathBuf>,
    exposure_us: f64,
    frame_rate_hz: f64,
    pixel_um: f64,
    #[serde(default = "default_pattern")]
    pattern: crate::measure::pattern::PatternKind,
    period_um: f64,
}

fn default_pattern() -> crate::measure::pattern::PatternKind {
    crate::measure::pattern::PatternKind::Encoded
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(rename_all = "lowercase")]
enum CameraSourceKind {
    Network,
    Folder,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct QtmSpec {
    address: Spanned<String>,
    /// QTM label -> model marker name (labels not listed keep their name).
    #[serde(default)]
    labels: BTreeMap<String, String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JointsSpec {
    address: Spanned<String>,
    root_link: String,
    names: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default = "default_speed")]
    speed_rad_s: f64,
}

fn default_speed() -> f64 {
    0.5
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct MarkerSpec {
    name: String,
    link: String,
    #[serde(default)]
    initial_m: [f64; 3],
}

/// The motion envelope keys (which apply depends on the kind).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvelopeSpec {
    #[serde(default)]
    joint_limits_deg: Option<Spanned<Vec<[f64; 2]>>>,
    #[serde(default)]
    max_joint_step_deg: Option<f64>,
    #[serde(default)]
    max_tool_step_mm: Option<f64>,
    #[serde(default)]
    workspace_mm: Option<Spanned<Workspace>>,
    #[serde(default)]
    max_stage_step_m: Option<f64>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct Workspace {
    min: [f64; 3],
    max: [f64; 3],
}

/// Where the secrets of a lab file are looked up (the process environment in the daemon;
/// a map in tests).
pub trait Environment {
    /// The value of variable `name`, if set.
    fn var(&self, name: &str) -> Option<String>;
}

/// The process environment.
#[derive(Debug, Clone, Copy, Default)]
pub struct ProcessEnv;

impl Environment for ProcessEnv {
    fn var(&self, name: &str) -> Option<String> {
        std::env::var(name).ok()
    }
}

impl Environment for BTreeMap<String, String> {
    fn var(&self, name: &str) -> Option<String> {
        self.get(name).cloned()
    }
}

/// Read the lab file at `path` into cell descriptions (no device is contacted).
pub fn load(path: &Path, env: &dyn Environment) -> Result<Vec<CellLink>, LabConfigError> {
    let text = std::fs::read_to_string(path).map_err(|e| LabConfigError {
        file: path.into(),
        line: 0,
        message: format!("cannot read the lab file: {e}"),
    })?;
    parse(&text, path, env)
}

/// Parse lab file `text` (read from `path`, against which relative paths resolve).
pub fn parse(
    text: &str,
    path: &Path,
    env: &dyn Environment,
) -> Result<Vec<CellLink>, LabConfigError> {
    let r = Reader { text, path, env };
    let file: LabFile = toml::from_str(text).map_err(|e| {
        let line = e.span().map_or(0, |s| r.line(&s));
        r.err_at(line, e.message().trim().to_string())
    })?;
    if file.cells.is_empty() {
        return Err(r.err_at(
            0,
            "no [[cell]]: a lab file describes at least one cell".into(),
        ));
    }
    let mut names = BTreeMap::new();
    let mut out = Vec::new();
    for c in &file.cells {
        let name = c.get_ref().name.get_ref();
        if let Some(first) = names.insert(name.clone(), r.line(&c.get_ref().name.span())) {
            return Err(r.err(
                &c.get_ref().name.span(),
                format!("cell `{name}` is already described at line {first}"),
            ));
        }
        out.push(r.cell(c)?);
    }
    Ok(out)
}

struct Reader<'a> {
    text: &'a str,
    path: &'a Path,
    env: &'a dyn Environment,
}

impl Reader<'_> {
    fn line(&self, span: &Range<usize>) -> usize {
        let end = span.start.min(self.text.len());
        self.text[..end].matches('\n').count() + 1
    }

    fn err_at(&self, line: usize, message: String) -> LabConfigError {
        LabConfigError {
            file: self.path.into(),
            line,
            message,
        }
    }

    fn err(&self, span: &Range<usize>, message: String) -> LabConfigError {
        self.err_at(self.line(span), message)
    }

    /// A required section of a cell kind.
    fn need<'s, T>(
        &self,
        c: &Spanned<CellSpec>,
        v: &'s Option<Spanned<T>>,
        key: &str,
    ) -> Result<&'s Spanned<T>, LabConfigError> {
        v.as_ref().ok_or_else(|| {
            let s = c.get_ref();
            self.err(
                &c.span(),
                format!(
                    "cell `{}` ({:?}) needs [cell.{key}]",
                    s.name.get_ref(),
                    s.kind
                ),
            )
        })
    }

    /// Refuse the sections and envelope keys a cell's kind does not use (a typo for
    /// another kind's key would otherwise be silently ignored).
    fn only(
        &self,
        c: &Spanned<CellSpec>,
        sections: &[&str],
        envelope: &[&str],
    ) -> Result<(), LabConfigError> {
        let s = c.get_ref();
        let present = [
            ("controller", s.controller.as_ref().map(Spanned::span)),
            ("indicators", s.indicators.as_ref().map(Spanned::span)),
            ("stages", s.stages.as_ref().map(Spanned::span)),
            ("microscope", s.microscope.as_ref().map(Spanned::span)),
            ("camera", s.camera.as_ref().map(Spanned::span)),
            ("mocap", s.mocap.as_ref().map(Spanned::span)),
            ("joints", s.joints.as_ref().map(Spanned::span)),
        ];
        let wrong = |what: String| {
            format!(
                "cell `{}`: {what} does not belong to a {:?} cell",
                s.name.get_ref(),
                s.kind
            )
        };
        for (key, at) in present {
            if let Some(at) = at.filter(|_| !sections.contains(&key)) {
                return Err(self.err(&at, wrong(format!("[cell.{key}]"))));
            }
        }
        let e = &s.envelope;
        let keys = [
            ("joint_limits_deg", e.joint_limits_deg.is_some()),
            ("max_joint_step_deg", e.max_joint_step_deg.is_some()),
            ("max_tool_step_mm", e.max_tool_step_mm.is_some()),
            ("workspace_mm", e.workspace_mm.is_some()),
            ("max_stage_step_m", e.max_stage_step_m.is_some()),
        ];
        match keys.iter().find(|(k, set)| *set && !envelope.contains(k)) {
            Some((k, _)) => Err(self.err(&c.span(), wrong(format!("envelope.{k}")))),
            None => Ok(()),
        }
    }

    fn model_text(&self, c: &CellSpec) -> Result<String, LabConfigError> {
        let p = self.resolve(c.model.get_ref());
        std::fs::read_to_string(&p).map_err(|e| {
            self.err(
                &c.model.span(),
                format!("model: cannot read {}: {e}", p.display()),
            )
        })
    }

    fn resolve(&self, p: &Path) -> PathBuf {
        match self.path.parent() {
            Some(dir) if p.is_relative() => dir.join(p),
            _ => p.to_path_buf(),
        }
    }

    fn address(&self, a: &Spanned<String>, key: &str) -> Result<String, LabConfigError> {
        let s = a.get_ref().trim();
        let ok = s
            .rsplit_once(':')
            .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok_and(|p| p > 0));
        if ok {
            Ok(s.to_string())
        } else {
            Err(self.err(&a.span(), format!("{key} = {s:?} is not host:port")))
        }
    }

    fn secret(&self, s: &RwsSpec, key: &str) -> Result<String, LabConfigError> {
        if let Some(p) = &s.password {
            return Err(self.err(
                &p.span(),
                format!(
                    "{key}.password: an inline password is refused; give {key}.password_file or {key}.password_env"
                ),
            ));
        }
        match (&s.password_file, &s.password_env) {
            (Some(f), None) => {
                // systemd's LoadCredential=: the unit's private credentials folder.
                let raw = f.get_ref().display().to_string();
                let p = match raw.strip_prefix("${CREDENTIALS_DIRECTORY}/") {
                    Some(rest) => match self.env.var("CREDENTIALS_DIRECTORY") {
                        Some(dir) => PathBuf::from(dir).join(rest),
                        None => {
                            return Err(self.err(
                                &f.span(),
                                format!("{key}.password_file: CREDENTIALS_DIRECTORY is not set (give the credential with LoadCredential= in the unit)"),
                            ));
                        }
                    },
                    None => self.resolve(f.get_ref()),
                };
                let t = std::fs::read_to_string(&p).map_err(|e| {
                    self.err(
                        &f.span(),
                        format!("{key}.password_file: cannot read {}: {e}", p.display()),
                    )
                })?;
                Ok(t.trim_end_matches(['\r', '\n']).to_string())
            }
            (None, Some(v)) => self.env.var(v.get_ref()).ok_or_else(|| {
                self.err(
                    &v.span(),
                    format!(
                        "{key}.password_env: environment variable {} is not set",
                        v.get_ref()
                    ),
                )
            }),
            (Some(f), Some(_)) => Err(self.err(
                &f.span(),
                format!("{key}: give password_file or password_env, not both"),
            )),
            (None, None) => Err(self.err(
                &s.address.span(),
                format!("{key}: password_file or password_env is required"),
            )),
        }
    }

    fn cell(&self, c: &Spanned<CellSpec>) -> Result<CellLink, LabConfigError> {
        let s = c.get_ref();
        let resume = self.resume_policy(s)?;
        let record = s.record.as_ref().map(|r| self.resolve(r.get_ref()));
        match s.kind {
            Kind::BallCentring => self.ball_centring(c).map(|d| {
                CellLink::BallCentring(BallCentringCell {
                    resume,
                    record,
                    ..d
                })
            }),
            Kind::Pcr => self.pcr(c).map(|d| {
                CellLink::Pcr(PcrCellLink {
                    resume,
                    record,
                    ..d
                })
            }),
            Kind::Humanoid => self.humanoid(c).map(|d| {
                CellLink::Mocap(MocapCellLink {
                    resume,
                    record,
                    ..d
                })
            }),
        }
    }

    /// The cell's `resume` and `max_auto_resumes`.
    fn resume_policy(&self, s: &CellSpec) -> Result<ResumePolicy, LabConfigError> {
        let mode = match &s.resume {
            None => ResumeMode::Operator,
            Some(m) => match m.get_ref().as_str() {
                "operator" => ResumeMode::Operator,
                "auto" => ResumeMode::Auto,
                other => {
                    return Err(self.err(
                        &m.span(),
                        format!("resume = {other:?}: give \"operator\" or \"auto\""),
                    ));
                }
            },
        };
        let max_auto_resumes = match &s.max_auto_resumes {
            None => DEFAULT_MAX_AUTO_RESUMES,
            Some(n) if mode == ResumeMode::Operator => {
                return Err(self.err(
                    &n.span(),
                    "max_auto_resumes applies with resume = \"auto\" only".into(),
                ));
            }
            Some(n) => u32::try_from(*n.get_ref())
                .ok()
                .filter(|v| (1..=100).contains(v))
                .ok_or_else(|| {
                    self.err(
                        &n.span(),
                        format!("max_auto_resumes = {} must be 1 to 100", n.get_ref()),
                    )
                })?,
        };
        Ok(ResumePolicy {
            mode,
            max_auto_resumes,
        })
    }
}

mod cells;
#[cfg(test)]
mod tests;
