//! DLR's Agile Justin upper body as an [`ElasticTree`]: 3 torso joints and a fourth coupled
//! one, two 7-joint arms, one marker per hand (Tenhumberg and Baeuml, Humanoids 2021).
//!
//! The nominal DH rows and the published initial guesses are read from the data set's
//! `nominal_dh.yaml` and `initial_guess.yaml` (text handed in; the data stay outside the
//! repository). What those files do not say, and what was checked against the measurements
//! (a frames-only fit of the nominal model leaves about 21 mm, as published):
//!
//! * the rows are Craig's *modified* DH (`Rx(alpha) Dx(r) Rz(theta + q) Dz(d)`); the classic
//!   convention leaves errors near 1 m;
//! * joint columns `q00..q02` drive torso rows 0-2, torso row 3 is passive with
//!   `q3 = -(q01 + q02)` (the upper body stays level), `q03..q09` the right arm rows 4-10,
//!   `q10..q16` the left arm rows 11-17, `q17, q18` the (unused) head;
//! * the fixed frames that the DH image leaves out: torso base 0.5884 m above the mobile
//!   base, the shoulder mounts (rotations of 150 and 30 deg about y, (0.190, 0.088, -+0.256) m)
//!   and the hand flange (0.118 m), from DLR's kinematics package `rokin`
//!   (`Robots/Justin19/justin19_par.py`, as in the fork a-doering/rokin at d332973).

use nalgebra::{Matrix3, Vector3};

use super::{Drive, ElasticOptions, ElasticTree, RowKind, TreeMarker, TreeRow};
use crate::geometry::Frame;
use crate::model::ModelError;

/// Number of joint columns in the data (`q00..q18`).
pub const JOINT_COLUMNS: usize = 19;

/// The nominal DH rows `[d (m), theta (deg), r (m), alpha (deg)]` of the three chains.
#[derive(Debug, Clone, PartialEq)]
pub struct JustinDh {
    /// Torso rows 0-3.
    pub torso: Vec<[f64; 4]>,
    /// Right arm rows 4-10.
    pub right: Vec<[f64; 4]>,
    /// Left arm rows 11-17.
    pub left: Vec<[f64; 4]>,
}

/// The published starting values.
#[derive(Debug, Clone, PartialEq)]
pub struct JustinGuess {
    /// Rotation of the robot base in the camera frame.
    pub rotation: Matrix3<f64>,
    /// Position of the robot base in the camera frame (m).
    pub translation: Vector3<f64>,
    /// Right-hand marker in the right flange frame (m).
    pub marker_right: Vector3<f64>,
    /// Left-hand marker in the left flange frame (m).
    pub marker_left: Vector3<f64>,
}

fn parse_err(what: &str, line: usize, text: &str) -> ModelError {
    ModelError::Parse(format!(
        "{what}, line {line}: cannot read `{}`",
        text.trim()
    ))
}

/// Numbers of a `[a, b, c]` list (after an optional `key:` or `-`), or `None`.
fn bracket_numbers(line: &str) -> Option<Result<Vec<f64>, ()>> {
    let code = line.split('#').next()?;
    let (open, close) = (code.find('[')?, code.rfind(']')?);
    Some(
        code[open + 1..close]
            .split(',')
            .map(|v| v.trim().parse::<f64>().map_err(|_| ()))
            .collect(),
    )
}

/// Read `nominal_dh.yaml`: sections `torso`, `right_arm`, `left_arm` of rows
/// `[i, d, theta, r, alpha]` (m, deg).
pub fn parse_nominal_dh(text: &str) -> Result<JustinDh, ModelError> {
    let mut dh = JustinDh {
        torso: Vec::new(),
        right: Vec::new(),
        left: Vec::new(),
    };
    let mut section = "";
    for (n, line) in text.lines().enumerate() {
        let t = line.trim_start();
        if !line.starts_with([' ', '-', '#']) && t.ends_with(':') {
            section = t.trim_end_matches(':');
            continue;
        }
        if !t.starts_with("- [") {
            continue;
        }
        let v = match bracket_numbers(t) {
            Some(Ok(v)) if v.len() == 5 => v,
            _ => return Err(parse_err("nominal_dh.yaml", n + 1, line)),
        };
        let row = [v[1], v[2], v[3], v[4]];
        match section {
            "torso" => dh.torso.push(row),
            "right_arm" => dh.right.push(row),
            "left_arm" => dh.left.push(row),
            _ => {}
        }
    }
    for (name, rows, want) in [
        ("torso", &dh.torso, 4),
        ("right_arm", &dh.right, 7),
        ("left_arm", &dh.left, 7),
    ] {
        if rows.len() != want {
            return Err(ModelError::Parse(format!(
                "nominal_dh.yaml: section `{name}` has {} rows, Justin has {want}",
                rows.len()
            )));
        }
    }
    Ok(dh)
}

/// Read `initial_guess.yaml`: `T_camera_base` (4 rows), `marker_right`, `marker_left`.
pub fn parse_initial_guess(text: &str) -> Result<JustinGuess, ModelError> {
    let mut t_rows: Vec<Vec<f64>> = Vec::new();
    let (mut right, mut left) = (None, None);
    for (n, line) in text.lines().enumerate() {
        let t = line.trim_start();
        let nums = || match bracket_numbers(t) {
            Some(Ok(v)) if v.len() >= 3 => Ok(v),
            _ => Err(parse_err("initial_guess.yaml", n + 1, line)),
        };
        if t.starts_with("- [") {
            t_rows.push(nums()?);
        } else if t.starts_with("marker_right:") {
            right = Some(nums()?);
        } else if t.starts_with("marker_left:") {
            left = Some(nums()?);
        }
    }
    let missing = |k: &str| ModelError::Parse(format!("initial_guess.yaml: no `{k}`"));
    if t_rows.len() < 3 || t_rows.iter().take(3).any(|r| r.len() != 4) {
        return Err(missing("T_camera_base (three rows of four numbers)"));
    }
    let right = right.ok_or_else(|| missing("marker_right"))?;
    let left = left.ok_or_else(|| missing("marker_left"))?;
    Ok(JustinGuess {
        rotation: Matrix3::from_fn(|i, j| t_rows[i][j]),
        translation: Vector3::new(t_rows[0][3], t_rows[1][3], t_rows[2][3]),
        marker_right: Vector3::new(right[0], right[1], right[2]),
        marker_left: Vector3::new(left[0], left[1], left[2]),
    })
}

fn frame(r: [[f64; 3]; 3], p: [f64; 3]) -> Frame {
    Frame {
        r: Matrix3::from_fn(|i, j| r[i][j]),
        p: Vector3::from(p),
    }
}

/// Names of the revolute rows: `torso0..3`, `right0..6`, `left0..6`.
pub fn revolute_rows() -> Vec<String> {
    let mut v: Vec<String> = (0..4).map(|i| format!("torso{i}")).collect();
    v.extend((0..7).map(|i| format!("right{i}")));
    v.extend((0..7).map(|i| format!("left{i}")));
    v
}

/// The Justin tree with markers `right` and `left` at the guessed positions and the root at
/// the guessed camera pose; `elastic` names the rows with lumped elasticity.
pub fn model(
    dh: &JustinDh,
    guess: &JustinGuess,
    elastic: &ElasticOptions,
) -> Result<ElasticTree, ModelError> {
    let rev = |name: String, parent: usize, row: &[f64; 4], drive: Drive| TreeRow {
        name,
        parent: Some(parent),
        kind: RowKind::Revolute {
            geometry: [
                row[3].to_radians(),
                row[2],
                0.0,
                row[1].to_radians(),
                row[0],
            ],
            drive,
        },
    };
    let fixed = |name: &str, parent: Option<usize>, f: Frame| TreeRow {
        name: name.into(),
        parent,
        kind: RowKind::Fixed {
            frame: f,
            errors: [0.0; 6],
        },
    };
    let (s, c) = (0.5, 3f64.sqrt() / 2.0);
    let mut rows = vec![fixed("torso_base", None, Frame::trans(0.0, 0.0, 0.5884))];
    for (i, r) in dh.torso.iter().enumerate() {
        let drive = if i < 3 {
            Drive::Variable(i)
        } else {
            Drive::Coupled(vec![(1, -1.0), (2, -1.0)])
        };
        rows.push(rev(format!("torso{i}"), rows.len() - 1, r, drive));
    }
    let torso_top = rows.len() - 1;
    let mut markers = Vec::new();
    let flange = frame(
        [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
        [0.0, 0.118, 0.0],
    );
    for (side, arm, first_var, mount, local) in [
        (
            "right",
            &dh.right,
            3,
            frame(
                [[-c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, -c]],
                [0.190, 0.088, -0.256],
            ),
            guess.marker_right,
        ),
        (
            "left",
            &dh.left,
            10,
            frame(
                [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
                [0.190, 0.088, 0.256],
            ),
            guess.marker_left,
        ),
    ] {
        rows.push(fixed(&format!("{side}_mount"), Some(torso_top), mount));
        for (k, r) in arm.iter().enumerate() {
            let drive = Drive::Variable(first_var + k);
            rows.push(rev(format!("{side}{k}"), rows.len() - 1, r, drive));
        }
        rows.push(fixed(
            &format!("{side}_flange"),
            Some(rows.len() - 1),
            flange,
        ));
        markers.push(TreeMarker {
            name: side.into(),
            row: rows.len() - 1,
            local,
        });
    }
    let mut tree = ElasticTree::new(rows, markers, JOINT_COLUMNS, elastic)?;
    let base = Frame {
        r: guess.rotation,
        p: guess.translation,
    };
    tree.base = base.to_xyzabc();
    Ok(tree)
}
