//! `pcr.mount_markers`: the six rod-mount markers of a 3-PF robot in one wide-field image
//! (identity, position in um, angle in rad; [`crate::measure::fiducial`]), and the model
//! file with the measured clamp positions as nominal values and the detection's standard
//! uncertainty (`measured_model.json`), so `pcr.identify` starts from measured geometry.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::measure::fiducial::{DetectSpec, MOUNTS, detect, into_model};
use crate::measure::pattern::{GrayImage, codec};
use crate::model::pcr::PcrFile;
use crate::run::{
    Artefact, Cx, Inputs, JobError, Kind, Run, RunFuture, Table, computed, parse_spec,
};
use crate::util::Monitor;

/// A `pcr.mount_markers` job document.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    /// The wide-field image (8- or 16-bit grayscale PNG or TIFF; a file relative to the job
    /// file or an uploaded dataset id).
    #[schemars(schema_with = "image_schema")]
    image: Value,
    /// The 3-PF model file whose clamp positions are replaced (file or inline object).
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    camera: CameraSpec,
    /// Side of one of the marker's 5 x 5 cells (um).
    cell_um: f64,
    /// The platform's pose (x, y in um, theta in rad) in the image when it was taken at
    /// q = 0; B_i are written in its frame. Default: at the image frame's origin.
    #[serde(default)]
    platform: Option<[f64; 3]>,
    /// Standard uncertainty written for Ax, Ay, Bx, By (um); default 0.25.
    #[serde(default)]
    uncertainty_um: Option<f64>,
}

fn image_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
    schemars::json_schema!({"type": "string", "minLength": 1,
        "description": "an image file (relative to the job file) or an uploaded dataset id"})
}

/// `"camera": {"pixel_um": s, "origin_um": [x, y]}`: the wide-field camera's scale and
/// where its pixel (0, 0) is in the world frame.
#[derive(Debug, Clone, Copy, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    pixel_um: f64,
    origin_um: [f64; 2],
}

/// A validated `pcr.mount_markers` job.
#[derive(Debug)]
pub struct MountMarkersJob {
    image: GrayImage,
    file: PcrFile,
    detect: DetectSpec,
    platform: [f64; 3],
    uncertainty_um: f64,
}

/// Validate a `pcr.mount_markers` job: decode the image, load the model.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<MountMarkersJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let positive = |v: f64, field: &str| {
        if v > 0.0 && v.is_finite() {
            Ok(v)
        } else {
            Err(JobError::invalid(field, "must be a positive number"))
        }
    };
    positive(spec.camera.pixel_um, "camera.pixel_um")?;
    positive(spec.cell_um, "cell_um")?;
    let uncertainty_um = positive(spec.uncertainty_um.unwrap_or(0.25), "uncertainty_um")?;
    let name = spec.image.as_str().unwrap_or_default().to_string();
    let bytes = inputs.bytes("image", &spec.image)?;
    let image = codec::decode(&bytes).map_err(|e| JobError::Input {
        field: "image".into(),
        reference: name,
        message: e.to_string(),
    })?;
    let file = super::load_model(inputs, &spec.model)?.file;
    Ok(MountMarkersJob {
        image,
        file,
        detect: DetectSpec {
            cell_um: spec.cell_um,
            pixel_um: spec.camera.pixel_um,
            origin_um: spec.camera.origin_um,
        },
        platform: spec.platform.unwrap_or_default(),
        uncertainty_um,
    })
}

/// The result of `pcr.mount_markers`.
#[derive(Debug, Clone, Serialize)]
pub struct MountMarkers {
    /// id, x_um, y_um, theta_rad per marker found (ids 0..2: A1..A3, 3..5: B1..B3); also the
    /// main table.
    #[serde(serialize_with = "crate::report::json_rows")]
    pub markers: Table,
    /// The model file with the measured clamp positions (also `measured_model.json`).
    pub measured_model: PcrFile,
}

impl MountMarkersJob {
    /// Find the markers and write the model.
    pub fn markers(&self, monitor: &dyn Monitor) -> Result<Run<MountMarkers>, JobError> {
        monitor.progress(0.0, "markers");
        let found =
            detect(&self.image, &self.detect).map_err(|e| JobError::Failed(e.to_string()))?;
        let mut table = Table::new(&["id", "x_um", "y_um", "theta_rad"]);
        for m in &found {
            table.push(vec![f64::from(m.id), m.x_um, m.y_um, m.theta_rad]);
        }
        if found.iter().filter(|m| usize::from(m.id) < MOUNTS).count() != MOUNTS {
            return Err(JobError::Failed(format!(
                "{} of the {MOUNTS} mounts found (ids {:?})",
                found.len(),
                found.iter().map(|m| m.id).collect::<Vec<_>>()
            )));
        }
        let mut file = self.file.clone();
        into_model(&mut file, &found, self.platform, self.uncertainty_um * 1e-6)
            .map_err(|e| JobError::Failed(e.to_string()))?;
        file.robot()
            .map_err(|e| JobError::Failed(format!("the measured model does not solve: {e}")))?;
        let content = serde_json::to_vec_pretty(&file)
            .map_err(|e| JobError::internal("serialising the measured model", e))?;
        Ok(Run {
            result: MountMarkers {
                markers: table.clone(),
                measured_model: file,
            },
            main_table: Some(table),
            artefacts: vec![Artefact {
                name: "measured_model.json".into(),
                media_type: "application/json".into(),
                content,
            }],
        })
    }
}

impl Kind for MountMarkersJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::markers)
    }
}
