//! The cells of a lab file by kind: a ball-centring cell, a PCR cell and a humanoid
//! (motion-capture) cell, each read from its `[[cell]]` into the link the lab connects.

use super::*;

impl Reader<'_> {
    pub(super) fn ball_centring(
        &self,
        c: &Spanned<CellSpec>,
    ) -> Result<BallCentringCell, LabConfigError> {
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
            joint_speed_deg_s: match ctl.get_ref().joint_speed_deg_s {
                None => 20.0,
                Some(v) if v > 0.0 && v.is_finite() => v,
                Some(v) => {
                    return Err(self.err(
                        &ctl.span(),
                        format!("controller.joint_speed_deg_s = {v} must be positive"),
                    ));
                }
            },
            resume: ResumePolicy::default(),
            record: None,
        })
    }

    pub(super) fn pcr(&self, c: &Spanned<CellSpec>) -> Result<PcrCellLink, LabConfigError> {
        let s = c.get_ref();
        self.only(
            c,
            &["stages", "microscope", "camera"],
            &["max_stage_step_m"],
        )?;
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
        let microscope = self.pose_source(c)?;
        Ok(PcrCellLink {
            name: s.name.get_ref().clone(),
            stages: StagesLink {
                backend,
                channels: spec.channels,
                pm_per_count: spec.pm_per_count.unwrap_or(1000),
            },
            microscope,
            max_stage_step_m: positive(self, c, env.max_stage_step_m, 0.01, "max_stage_step_m")?,
            model,
            resume: ResumePolicy::default(),
            record: None,
        })
    }

    /// The microscope: a pose server (`[cell.microscope]`) or a camera whose frames calibd
    /// measures (`[cell.camera]`), exactly one of them.
    fn pose_source(&self, c: &Spanned<CellSpec>) -> Result<PoseSourceLink, LabConfigError> {
        let s = c.get_ref();
        let cam = match (&s.microscope, &s.camera) {
            (Some(m), None) => {
                return Ok(PoseSourceLink::Server(
                    self.address(&m.get_ref().address, "microscope.address")?,
                ));
            }
            (None, Some(cam)) => cam,
            (Some(_), Some(cam)) => {
                return Err(self.err(
                    &cam.span(),
                    "give [cell.microscope] (a pose server) or [cell.camera] (frames calibd measures), not both".into(),
                ));
            }
            (None, None) => {
                return Err(self.err(
                    &c.span(),
                    format!(
                        "cell `{}` needs [cell.microscope] (a pose server) or [cell.camera]",
                        s.name.get_ref()
                    ),
                ));
            }
        };
        let spec = cam.get_ref();
        let bad = |m: String| self.err(&cam.span(), m);
        for (key, v) in [
            ("exposure_us", spec.exposure_us),
            ("frame_rate_hz", spec.frame_rate_hz),
            ("pixel_um", spec.pixel_um),
            ("period_um", spec.period_um),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(bad(format!("camera.{key} = {v} must be positive")));
            }
        }
        let source = match (spec.source, &spec.address, &spec.folder) {
            (CameraSourceKind::Network, Some(a), None) => {
                FrameSourceLink::Network(self.address(a, "camera.address")?)
            }
            (CameraSourceKind::Folder, None, Some(f)) => FrameSourceLink::Folder(self.resolve(f)),
            (CameraSourceKind::Network, _, _) => {
                return Err(bad(
                    "camera: source = \"network\" needs address (and no folder)".into(),
                ));
            }
            (CameraSourceKind::Folder, _, _) => {
                return Err(bad(
                    "camera: source = \"folder\" needs folder (and no address)".into(),
                ));
            }
        };
        Ok(PoseSourceLink::Camera(CameraLink {
            source,
            exposure_us: spec.exposure_us,
            frame_rate_hz: spec.frame_rate_hz,
            pattern: crate::measure::pattern::PatternSetup {
                kind: spec.pattern,
                period_um: spec.period_um,
                pixel_um: spec.pixel_um,
            },
        }))
    }

    pub(super) fn humanoid(&self, c: &Spanned<CellSpec>) -> Result<MocapCellLink, LabConfigError> {
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
            resume: ResumePolicy::default(),
            record: None,
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
