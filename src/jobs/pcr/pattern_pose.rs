//! `pcr.pattern_pose`: the pose (x, y in um, theta in rad) of the pattern on the 3-PF
//! platform in each microscope image, by the phase method ([`crate::measure::pattern`]):
//! a continuous track over the list for a periodic pattern, absolute poses for the encoded
//! one. Images are read and decoded when the job is prepared, so a bad file fails it early
//! with its name.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::measure::pattern::{
    GrayImage, PatternKind, PhaseEstimator, Track, codec, decode_absolute,
};
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::Monitor;

/// A `pcr.pattern_pose` job document.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    /// Image files (8- or 16-bit grayscale PNG or TIFF), relative to the job file, or
    /// uploaded dataset ids; all of one size.
    #[schemars(schema_with = "images_schema")]
    images: Vec<Value>,
    pattern: PatternSpec,
    camera: CameraSpec,
}

fn images_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
    schemars::json_schema!({"type": "array", "minItems": 1, "items": {"type": "string",
        "minLength": 1, "description": "an image file (relative to the job file) or an uploaded dataset id"}})
}

/// `"pattern": {"kind": "periodic" | "encoded", "period_um": p}`.
#[derive(Debug, Clone, Copy, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct PatternSpec {
    kind: PatternKind,
    /// Period of the grid (um).
    period_um: f64,
}

/// `"camera": {"pixel_um": s}`: pixel size in the object plane.
#[derive(Debug, Clone, Copy, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    pixel_um: f64,
}

/// A validated `pcr.pattern_pose` job: the decoded images.
#[derive(Debug)]
pub struct PatternPoseJob {
    names: Vec<String>,
    images: Vec<GrayImage>,
    kind: PatternKind,
    period_um: f64,
    pixel_um: f64,
}

/// Validate a `pcr.pattern_pose` job: read and decode every image.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<PatternPoseJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    if !(spec.pattern.period_um > 0.0 && spec.pattern.period_um.is_finite()) {
        return Err(JobError::invalid(
            "pattern.period_um",
            "must be a positive number",
        ));
    }
    if !(spec.camera.pixel_um > 0.0 && spec.camera.pixel_um.is_finite()) {
        return Err(JobError::invalid(
            "camera.pixel_um",
            "must be a positive number",
        ));
    }
    if spec.images.is_empty() {
        return Err(JobError::invalid("images", "at least one image is needed"));
    }
    let mut names = Vec::with_capacity(spec.images.len());
    let mut images: Vec<GrayImage> = Vec::with_capacity(spec.images.len());
    for (i, v) in spec.images.iter().enumerate() {
        let field = format!("images[{i}]");
        let name = v.as_str().unwrap_or_default().to_string();
        let bytes = inputs.bytes(&field, v)?;
        let img = codec::decode(&bytes).map_err(|e| JobError::Input {
            field: field.clone(),
            reference: name.clone(),
            message: e.to_string(),
        })?;
        if let Some(first) = images.first()
            && (first.width, first.height) != (img.width, img.height)
        {
            return Err(JobError::Input {
                field,
                reference: name,
                message: format!(
                    "{} x {} px where the first image is {} x {}",
                    img.width, img.height, first.width, first.height
                ),
            });
        }
        names.push(name);
        images.push(img);
    }
    // The sizes and the period must suit the method before anything runs.
    PhaseEstimator::new(
        images[0].width,
        images[0].height,
        spec.pattern.period_um / spec.camera.pixel_um,
    )
    .map_err(|e| JobError::invalid("pattern.period_um", e.to_string()))?;
    Ok(PatternPoseJob {
        names,
        images,
        kind: spec.pattern.kind,
        period_um: spec.pattern.period_um,
        pixel_um: spec.camera.pixel_um,
    })
}

/// Units of the poses table.
#[derive(Debug, Clone, Serialize)]
pub struct PatternUnits {
    /// `um`.
    pub length: &'static str,
    /// `rad`.
    pub angle: &'static str,
}

/// The result of `pcr.pattern_pose`.
#[derive(Debug, Clone, Serialize)]
pub struct PatternPoses {
    /// um and rad.
    pub units: PatternUnits,
    /// `periodic` (a continuous track modulo the period) or `encoded` (absolute).
    pub pattern: PatternKind,
    /// The image files, in the order of the table's `image` column (1-based).
    pub images: Vec<String>,
    /// image, x_um, y_um, theta_rad, contrast, residual_rad, period_px per image (also the
    /// main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub poses: Table,
}

impl PatternPoseJob {
    /// Measure every image.
    pub fn poses(&self, monitor: &dyn Monitor) -> Result<Run<PatternPoses>, JobError> {
        let first = &self.images[0];
        let mut est =
            PhaseEstimator::new(first.width, first.height, self.period_um / self.pixel_um)
                .map_err(|e| JobError::invalid("pattern.period_um", e.to_string()))?;
        let mut track = Track::new();
        let mut table = Table::new(&[
            "image",
            "x_um",
            "y_um",
            "theta_rad",
            "contrast",
            "residual_rad",
            "period_px",
        ]);
        let n = self.images.len();
        for (i, img) in self.images.iter().enumerate() {
            if monitor.is_cancelled() {
                return Err(JobError::Cancelled);
            }
            monitor.progress(i as f64 / n as f64, "pattern poses");
            let fail = |e: crate::measure::pattern::PatternError| {
                JobError::Failed(format!("image {} (`{}`): {e}", i + 1, self.names[i]))
            };
            let fit = est.fit(img).map_err(fail)?;
            let pose = match self.kind {
                PatternKind::Periodic => track.push(fit.pose(self.period_um), self.period_um),
                PatternKind::Encoded => decode_absolute(img, &fit, self.period_um).map_err(fail)?,
            };
            table.push(vec![
                (i + 1) as f64,
                pose.x,
                pose.y,
                pose.theta_rad,
                fit.contrast(),
                fit.residual_rad(),
                fit.period_px(),
            ]);
        }
        Ok(Run {
            result: PatternPoses {
                units: PatternUnits {
                    length: "um",
                    angle: "rad",
                },
                pattern: self.kind,
                images: self.names.clone(),
                poses: table.clone(),
            },
            main_table: Some(table),
            artefacts: vec![],
        })
    }
}

impl Kind for PatternPoseJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::poses)
    }
}

/// What `calibd twin pattern` renders: a sequence of microscope frames of the pattern
/// moving on a seeded random walk.
#[derive(Debug, Clone)]
pub struct PatternTwin {
    /// Periodic or encoded.
    pub kind: PatternKind,
    /// Frames.
    pub count: usize,
    /// Square frames of this side (px).
    pub size_px: usize,
    /// Period (um).
    pub period_um: f64,
    /// Pixel size in the object plane (um).
    pub pixel_um: f64,
    /// 8 or 16.
    pub bit_depth: u8,
    /// Noise sigma as a fraction of full scale.
    pub noise_frac: f64,
    /// Seed of the walk and of the noise.
    pub seed: u64,
}

/// The twin's files: `frame_NNN.png`, `truth.csv` (image, x_um, y_um, theta_rad: the
/// rendered poses) and `pattern_pose.json` (the job measuring the frames).
pub fn twin_files(t: &PatternTwin) -> Result<Vec<(String, Vec<u8>)>, JobError> {
    let fail = |e: crate::measure::pattern::PatternError| JobError::Failed(e.to_string());
    let mut rng = crate::util::Rng::new(t.seed);
    // Absolute positions far from the origin show what the encoded pattern decodes.
    let mut pose = crate::measure::pattern::PatternPose {
        x: rng.range(-1.0, 1.0) * 200.0 * t.period_um,
        y: rng.range(-1.0, 1.0) * 200.0 * t.period_um,
        theta_rad: rng.range(-0.3, 0.3),
    };
    let mut files = Vec::new();
    let mut truth = Table::new(&["image", "x_um", "y_um", "theta_rad"]);
    let mut names = Vec::new();
    for k in 0..t.count {
        let img = crate::measure::pattern::render(&crate::measure::pattern::RenderSpec {
            kind: t.kind,
            pose,
            period_um: t.period_um,
            pixel_um: t.pixel_um,
            width: t.size_px,
            height: t.size_px,
            bit_depth: t.bit_depth,
            noise_frac: t.noise_frac,
            seed: t.seed.wrapping_add(1 + k as u64),
        })
        .map_err(fail)?;
        let name = format!("frame_{k:03}.png");
        files.push((name.clone(), codec::encode_png(&img).map_err(fail)?));
        names.push(name);
        truth.push(vec![(k + 1) as f64, pose.x, pose.y, pose.theta_rad]);
        // Steps under a third of a period and a milliradian: a continuous track.
        pose.x += rng.range(-0.3, 0.3) * t.period_um;
        pose.y += rng.range(-0.3, 0.3) * t.period_um;
        pose.theta_rad += rng.range(-1e-3, 1e-3);
    }
    let job = serde_json::json!({
        "kind": "pcr.pattern_pose",
        "images": names,
        "pattern": {"kind": t.kind, "period_um": t.period_um},
        "camera": {"pixel_um": t.pixel_um},
    });
    files.push(("truth.csv".into(), truth.to_csv().into_bytes()));
    files.push((
        "pattern_pose.json".into(),
        serde_json::to_vec_pretty(&job)
            .map_err(|e| JobError::internal("serialising the twin's job", e))?,
    ));
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::prepare as prepare_job;
    use crate::measure::pattern::{PatternPose, RenderSpec, render};
    use crate::run::DirResolver;
    use crate::util::monitor::NoMonitor;

    fn write(dir: &std::path::Path, name: &str, kind: PatternKind, pose: PatternPose, seed: u64) {
        let img = render(&RenderSpec {
            kind,
            pose,
            period_um: 20.0,
            pixel_um: 2.0,
            width: 320,
            height: 300,
            bit_depth: 16,
            noise_frac: 0.01,
            seed,
        })
        .unwrap();
        std::fs::write(dir.join(name), codec::encode_png(&img).unwrap()).unwrap();
    }

    #[test]
    fn a_job_tracks_a_sequence_of_png_files_in_um() {
        let dir = tempfile::tempdir().unwrap();
        // Steps under half a period (20 um) in the pattern's axes: the track follows them.
        let truths = [(3.1, -4.2, 0.1), (9.6, -1.0, 0.1002), (15.0, 3.5, 0.1004)];
        let mut names = Vec::new();
        for (k, &(x, y, t)) in truths.iter().enumerate() {
            let name = format!("f{k}.png");
            write(
                dir.path(),
                &name,
                PatternKind::Periodic,
                PatternPose { x, y, theta_rad: t },
                k as u64,
            );
            names.push(name);
        }
        let doc = serde_json::json!({
            "kind": "pcr.pattern_pose",
            "images": names,
            "pattern": {"kind": "periodic", "period_um": 20.0},
            "camera": {"pixel_um": 2.0},
        });
        let job = prepare_job(
            &doc,
            &DirResolver {
                dir: dir.path().into(),
            },
        )
        .unwrap();
        assert!(job.inputs_sha256.contains_key("images[2]"));
        let done = job.run(&NoMonitor).unwrap();
        let t = done.main_table.unwrap();
        assert_eq!(t.columns[..4], ["image", "x_um", "y_um", "theta_rad"]);
        // The first pose is modulo the period: compare the steps.
        for k in 1..3 {
            for (c, truth) in [(1, 0), (2, 1)] {
                let step = t.rows[k][c] - t.rows[0][c];
                let want = [truths[k].0 - truths[0].0, truths[k].1 - truths[0].1][truth];
                assert!(
                    (step - want).abs() < 0.01,
                    "row {k} col {c}: {step} vs {want}"
                );
            }
            assert!((t.rows[k][3] - truths[k].2).abs() < 1e-4);
        }
        assert_eq!(done.result["pattern"], "periodic");
    }

    #[test]
    fn an_encoded_pattern_gives_absolute_positions() {
        let dir = tempfile::tempdir().unwrap();
        let truth = PatternPose {
            x: 5432.1,
            y: -987.6,
            theta_rad: -0.05,
        };
        write(dir.path(), "a.png", PatternKind::Encoded, truth, 7);
        let doc = serde_json::json!({
            "kind": "pcr.pattern_pose",
            "images": ["a.png"],
            "pattern": {"kind": "encoded", "period_um": 20.0},
            "camera": {"pixel_um": 2.0},
        });
        let job = prepare_job(
            &doc,
            &DirResolver {
                dir: dir.path().into(),
            },
        )
        .unwrap();
        let t = job.run(&NoMonitor).unwrap().main_table.unwrap();
        // Within 0.05 period (the code's perturbation of the phase, see the module's
        // tests); a wrong period index would be 20 um off.
        assert!((t.rows[0][1] - truth.x).abs() < 1.0, "{:?}", t.rows[0]);
        assert!((t.rows[0][2] - truth.y).abs() < 1.0, "{:?}", t.rows[0]);
    }

    #[test]
    fn the_twin_writes_frames_a_truth_table_and_a_job_that_measures_them() {
        let files = twin_files(&PatternTwin {
            kind: PatternKind::Periodic,
            count: 3,
            size_px: 256,
            period_um: 10.0,
            pixel_um: 1.0,
            bit_depth: 8,
            noise_frac: 0.01,
            seed: 5,
        })
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in &files {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let doc: Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("pattern_pose.json")).unwrap())
                .unwrap();
        let job = prepare_job(
            &doc,
            &DirResolver {
                dir: dir.path().into(),
            },
        )
        .unwrap();
        let t = job.run(&NoMonitor).unwrap().main_table.unwrap();
        let text = std::fs::read_to_string(dir.path().join("truth.csv")).unwrap();
        let truth = Table::from_csv("truth", &text).unwrap();
        // A periodic pattern's track follows the lattice point nearest the centre in the
        // first frame, (X, Y) in the pattern: find it, then where each frame puts it.
        let (r0, e0) = (&truth.rows[0], &t.rows[0]);
        let (s, c) = r0[3].sin_cos();
        let (dx, dy) = (e0[1] - r0[1], e0[2] - r0[2]);
        let lattice = |v: f64| 10.0 * (v / 10.0).round();
        let (xl, yl) = (lattice(c * dx + s * dy), lattice(-s * dx + c * dy));
        for k in 0..3 {
            let (r, e) = (&truth.rows[k], &t.rows[k]);
            let (s, c) = r[3].sin_cos();
            let want = [r[1] + c * xl - s * yl, r[2] + s * xl + c * yl];
            for (got, want) in [(e[1], want[0]), (e[2], want[1])] {
                assert!((got - want).abs() < 0.01, "frame {k}: {got} vs {want}");
            }
            assert!(
                (e[3] - r[3]).abs() < 1e-4,
                "frame {k}: theta {} vs {}",
                e[3],
                r[3]
            );
        }
    }

    #[test]
    fn bad_files_and_patternless_images_fail_naming_the_image() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("bad.png"), b"not an image").unwrap();
        let doc = |images: serde_json::Value| {
            serde_json::json!({
                "kind": "pcr.pattern_pose",
                "images": images,
                "pattern": {"kind": "periodic", "period_um": 20.0},
                "camera": {"pixel_um": 2.0},
            })
        };
        let r = DirResolver {
            dir: dir.path().into(),
        };
        let e = prepare_job(&doc(serde_json::json!(["bad.png"])), &r).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("bad.png") && m.contains("neither a PNG nor a TIFF"),
            "{m}"
        );
        let e = prepare_job(&doc(serde_json::json!(["missing.png"])), &r).unwrap_err();
        assert!(e.to_string().contains("missing.png"), "{e}");
        // A flat grey image: decodes, but holds no pattern.
        let flat = GrayImage {
            width: 320,
            height: 300,
            full_scale: 255,
            pixels: vec![128; 96000],
        };
        std::fs::write(
            dir.path().join("flat.png"),
            codec::encode_png(&flat).unwrap(),
        )
        .unwrap();
        let job = prepare_job(&doc(serde_json::json!(["flat.png"])), &r).unwrap();
        let m = job.run(&NoMonitor).unwrap_err().to_string();
        assert!(
            m.contains("flat.png") && m.contains("no periodic pattern"),
            "{m}"
        );
    }
}
