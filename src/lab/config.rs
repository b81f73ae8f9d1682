//! A lab from its configuration file: the cells of a real lab and the addresses, serial
//! ports and credentials of their devices, read into the same [`CellLink`] descriptions the
//! simulated lab produces. Everything is checked before a device is contacted: unknown
//! keys, missing devices, serial ports that do not exist, model files that do not parse,
//! inline passwords; each error names the file, the line and the key. Secrets come from a
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
    BallCentringCell, CellLink, JointsLink, MocapCellLink, PcrCellLink, RwsLink, StageBackend,
    StagesLink, UwaveLink,
};
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
    #[serde(default)]
    mocap: Option<Spanned<QtmSpec>>,
    #[serde(default)]
    joints: Option<Spanned<JointsSpec>>,
    #[serde(default)]
    envelope: EnvelopeSpec,
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
    parse_with(text, path, env, true)
}

/// [`load`] for the side that serves the devices (`calibd mock lab`): serial ports are
/// created, not checked.
pub fn load_for_mocks(path: &Path, env: &dyn Environment) -> Result<Vec<CellLink>, LabConfigError> {
    let text = std::fs::read_to_string(path).map_err(|e| LabConfigError {
        file: path.into(),
        line: 0,
        message: format!("cannot read the lab file: {e}"),
    })?;
    parse_with(&text, path, env, false)
}

fn parse_with(
    text: &str,
    path: &Path,
    env: &dyn Environment,
    check_ports: bool,
) -> Result<Vec<CellLink>, LabConfigError> {
    let r = Reader {
        text,
        path,
        env,
        check_ports,
    };
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
    check_ports: bool,
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
        match s.kind {
            Kind::BallCentring => self.ball_centring(c).map(CellLink::BallCentring),
            Kind::Pcr => self.pcr(c).map(CellLink::Pcr),
            Kind::Humanoid => self.humanoid(c).map(CellLink::Mocap),
        }
    }

    fn ball_centring(&self, c: &Spanned<CellSpec>) -> Result<BallCentringCell, LabConfigError> {
        let s = c.get_ref();
        self.only(
            c,
            &["controller", "indicators"],
            &[
                "joint_limits_deg",
                "max_joint_step_deg",
                "max_tool_step_mm",
                "workspace_mm",
            ],
        )?;
        let name = s.name.get_ref().clone();
        let model = DhFile::parse(&self.model_text(s)?)
            .and_then(|m| m.to_chain().map(|_| m))
            .map_err(|e| self.err(&s.model.span(), format!("model: {e}")))?;
        let ballbar = s.ballbar_mm.ok_or_else(|| {
            self.err(
                &c.span(),
                format!("cell `{name}` needs ballbar_mm = {{ d12, d13, d23 }}"),
            )
        })?;
        let ctl = self.need(c, &s.controller, "controller")?;
        let rws = RwsLink {
            address: self.address(&ctl.get_ref().address, "controller.address")?,
            user: ctl.get_ref().user.clone(),
            password: self.secret(ctl.get_ref(), "controller")?,
            module: ctl.get_ref().module.clone(),
        };
        let ind = self.need(c, &s.indicators, "indicators")?.get_ref();
        let port = ind.port.get_ref();
        if self.check_ports && !Path::new(port).exists() {
            return Err(self.err(
                &ind.port.span(),
                format!("indicators.port: serial port {port} does not exist (is the U-WAVE-R receiver plugged in? see `ls /dev/serial/by-id/`)"),
            ));
        }
        let axes = ind.axes.get_ref();
        let [x, y, z] = axes.as_slice() else {
            return Err(self.err(
                &ind.axes.span(),
                format!(
                    "indicators.axes: {} entries for the three tool axes x, y, z",
                    axes.len()
                ),
            ));
        };
        let map = |a: &AxisSpec| -> Result<AxisMap, LabConfigError> {
            if a.sign != 1.0 && a.sign != -1.0 {
                return Err(self.err(
                    &ind.axes.span(),
                    format!("indicators.axes: sign {} must be 1 or -1", a.sign),
                ));
            }
            if let Some([lo, hi]) = a.range_mm
                && !(lo < hi && a.zero_mm >= lo && a.zero_mm <= hi)
            {
                return Err(self.err(
                    &ind.axes.span(),
                    format!(
                        "indicators.axes: channel {} zero_mm {} outside its range [{lo}, {hi}] mm",
                        a.channel, a.zero_mm
                    ),
                ));
            }
            Ok(AxisMap {
                channel: a.channel,
                sign: a.sign,
                zero_mm: a.zero_mm,
            })
        };
        let env = &s.envelope;

        let dof = model.to_chain().map(|ch| ch.actuated().len()).unwrap_or(0);
        let limits_deg = match &env.joint_limits_deg {
            Some(l) if l.get_ref().len() != dof => {
                return Err(self.err(
                    &l.span(),
                    format!(
                        "envelope.joint_limits_deg: {} pairs for {dof} joints",
                        l.get_ref().len()
                    ),
                ));
            }
            Some(l) if l.get_ref().iter().any(|[lo, hi]| !(lo < hi)) => {
                return Err(self.err(
                    &l.span(),
                    "envelope.joint_limits_deg: each pair is [lower, upper] with lower < upper"
                        .into(),
                ));
            }
            Some(l) => Some(l.get_ref().clone()),
            None => None,
        };
        let workspace_mm = match &env.workspace_mm {
            Some(w) => {
                let v = *w.get_ref();
                if (0..3).any(|k| !(v.min[k] < v.max[k])) {
                    return Err(self.err(
                        &w.span(),
                        "envelope.workspace_mm: min must be below max on every axis".into(),
                    ));
                }
                Some([v.min, v.max])
            }
            None => None,
        };
        Ok(BallCentringCell {
            name,
            rws,
            uwave: UwaveLink {
                path: port.clone(),
                baud: ind.baud,
                axes: [map(x)?, map(y)?, map(z)?],
                request_template: ind.request.clone(),
            },
            ballbar: [ballbar.d12, ballbar.d13, ballbar.d23],
            model,
            max_joint_step_deg: positive(
                self,
                c,
                env.max_joint_step_deg,
                10.0,
                "max_joint_step_deg",
            )?,
            max_tool_step_mm: positive(self, c, env.max_tool_step_mm, 2.0, "max_tool_step_mm")?,
            joint_limits_deg: limits_deg,
            workspace_mm,
        })
    }

    fn pcr(&self, c: &Spanned<CellSpec>) -> Result<PcrCellLink, LabConfigError> {
        let s = c.get_ref();
        self.only(c, &["stages", "microscope"], &["max_stage_step_m"])?;
        let env = &s.envelope;
        let model = PcrFile::parse(&self.model_text(s)?)
            .map_err(|e| e.to_string())
            .and_then(|m| m.robot().map(|_| m).map_err(|e| e.to_string()))
            .map_err(|e| self.err(&s.model.span(), format!("model: {e}")))?;
        let st = self.need(c, &s.stages, "stages")?;
        let spec = st.get_ref();
        let backend = match (&spec.controller, &spec.address, &spec.can_interface) {
            (StageKind::Mcs2, Some(a), None) => {
                StageBackend::Mcs2(self.address(a, "stages.address")?)
            }
            (StageKind::Mcs, Some(a), None) => {
                StageBackend::Mcs(self.address(a, "stages.address")?)
            }
            (StageKind::Cia402, Some(a), bus) => StageBackend::Socketcand {
                address: self.address(a, "stages.address")?,
                bus: bus.clone().unwrap_or_else(|| "can0".into()),
            },
            (StageKind::Cia402, None, Some(iface)) => StageBackend::SocketCan(iface.clone()),
            (StageKind::Cia402, None, None) => {
                return Err(self.err(
                    &st.span(),
                    "stages: a cia402 controller needs address (socketcand) or can_interface (SocketCAN)".into(),
                ));
            }
            (_, None, _) => {
                return Err(self.err(&st.span(), "stages.address is required".into()));
            }
            (_, Some(_), Some(_)) => {
                return Err(self.err(
                    &st.span(),
                    "stages.can_interface applies to cia402 controllers only".into(),
                ));
            }
        };
        if spec.pm_per_count.is_some_and(|p| p <= 0) {
            return Err(self.err(&st.span(), "stages.pm_per_count must be positive".into()));
        }
        let scope = self.need(c, &s.microscope, "microscope")?;
        Ok(PcrCellLink {
            name: s.name.get_ref().clone(),
            stages: StagesLink {
                backend,
                channels: spec.channels,
                pm_per_count: spec.pm_per_count.unwrap_or(1000),
            },
            microscope: self.address(&scope.get_ref().address, "microscope.address")?,
            max_stage_step_m: positive(self, c, env.max_stage_step_m, 0.01, "max_stage_step_m")?,
            model,
        })
    }

    fn humanoid(&self, c: &Spanned<CellSpec>) -> Result<MocapCellLink, LabConfigError> {
        let s = c.get_ref();
        self.only(
            c,
            &["mocap", "joints"],
            &["joint_limits_deg", "max_joint_step_deg"],
        )?;
        let env = &s.envelope;
        let urdf = self.model_text(s)?;
        let js = self.need(c, &s.joints, "joints")?;
        let j = js.get_ref();
        let markers: Vec<MarkerDef> = j
            .markers
            .iter()
            .map(|m| MarkerDef {
                name: m.name.clone(),
                link: m.link.clone(),
                initial: nalgebra::Vector3::from(m.initial_m),
            })
            .collect();
        let model = crate::model::urdf::UrdfModel::parse(&urdf)
            .map_err(|e| self.err(&s.model.span(), format!("model: {e}")))?;
        let limits = urdf_limits(&model, &j.names).map_err(|m| self.err(&js.span(), m))?;
        let limits = match &env.joint_limits_deg {
            Some(l) => {
                let l = l.get_ref();
                if l.len() != j.names.len() {
                    return Err(self.err(
                        &js.span(),
                        format!(
                            "envelope.joint_limits_deg: {} pairs for {} joints",
                            l.len(),
                            j.names.len()
                        ),
                    ));
                }
                // The configured envelope narrows the URDF's limits, never widens them.
                limits
                    .iter()
                    .zip(l)
                    .map(|(u, c)| [u[0].max(c[0].to_radians()), u[1].min(c[1].to_radians())])
                    .collect()
            }
            None => limits,
        };
        if !(j.speed_rad_s > 0.0 && j.speed_rad_s.is_finite()) {
            return Err(self.err(&js.span(), "joints.speed_rad_s must be positive".into()));
        }
        let qtm = self.need(c, &s.mocap, "mocap")?;
        Ok(MocapCellLink {
            name: s.name.get_ref().clone(),
            joints: JointsLink {
                address: self.address(&j.address, "joints.address")?,
                speed_rad_s: j.speed_rad_s,
                max_step_rad: positive(
                    self,
                    c,
                    env.max_joint_step_deg,
                    180.0,
                    "max_joint_step_deg",
                )?
                .to_radians(),
            },
            qtm: self.address(&qtm.get_ref().address, "mocap.address")?,
            labels: qtm.get_ref().labels.clone(),
            urdf,
            root_link: j.root_link.clone(),
            joint_names: j.names.clone(),
            limits,
            markers,
        })
    }
}

/// A positive envelope value, or its default.
fn positive(
    r: &Reader<'_>,
    c: &Spanned<CellSpec>,
    v: Option<f64>,
    default: f64,
    key: &str,
) -> Result<f64, LabConfigError> {
    match v {
        None => Ok(default),
        Some(v) if v > 0.0 && v.is_finite() => Ok(v),
        Some(v) => Err(r.err(&c.span(), format!("envelope.{key} = {v} must be positive"))),
    }
}

/// The URDF limits (rad) of the named joints.
fn urdf_limits(
    model: &crate::model::urdf::UrdfModel,
    names: &[String],
) -> Result<Vec<[f64; 2]>, String> {
    if names.is_empty() {
        return Err("joints.names: at least one joint".into());
    }
    names
        .iter()
        .map(|n| {
            let j = model
                .robot
                .joints
                .iter()
                .find(|j| &j.name == n)
                .ok_or_else(|| format!("joints.names: `{n}` is not a joint of the URDF"))?;
            let (lo, hi) = (j.limit.lower, j.limit.upper);
            Ok(if lo < hi {
                [lo, hi]
            } else {
                [-std::f64::consts::PI, std::f64::consts::PI]
            })
        })
        .collect()
}

#[cfg(test)]
#[path = "config_tests.rs"]
mod tests;
