//! Fiducial markers on the 3-PF robot's rod mounts, seen in one wide-field image: each is a
//! square of 5 x 5 cells, an always-bright ring around 3 x 3 inner cells of which one corner
//! is bright and three dark (the orientation) and the other five carry the mount's code
//! (missing squares say which mount). Rendered in [`render`], found in [`detect`]
//! (threshold, connected components, centre and orientation from line fits to the outer
//! edges, decode), written into a model file by [`into_model`]. Tested on rendered images
//! in `tests/it/pcr_mount_markers.rs`.
//!
//! Conventions: image coordinates in um in the wide-field camera frame (`origin_um` is the
//! centre of pixel (0, 0), x along columns, y along rows); a marker's pose places its centre
//! at (x, y) with its x axis (from the bright corner's column toward the ring's far side) at
//! theta from the image's x axis.

pub mod detect;
pub mod render;

pub use detect::{DetectSpec, detect};
pub use render::{FieldSpec, render_field};

use crate::model::pcr::PcrFile;

/// Cells along a marker's side.
pub const GRID: usize = 5;
/// The six mounts: ids 0..2 are the proximal clamps A1..A3, 3..5 the distal clamps B1..B3.
pub const MOUNTS: usize = 6;
/// The code of each id: five bits, two set, pairwise at least two bits apart.
const CODES: [u8; 10] = [
    0b00011, 0b00101, 0b00110, 0b01001, 0b01010, 0b01100, 0b10001, 0b10010, 0b10100, 0b11000,
];
/// Inner cells carrying the code bits, (column, row) in 0..5.
const BITS: [(usize, usize); 5] = [(2, 1), (1, 2), (2, 2), (3, 2), (2, 3)];

/// A marker's identity and pose.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MarkerPose {
    /// Which mount (0..=9; 0..5 for the six mounts).
    pub id: u8,
    /// Centre x (um).
    pub x_um: f64,
    /// Centre y (um).
    pub y_um: f64,
    /// Angle of the marker's x axis (rad).
    pub theta_rad: f64,
}

/// What went wrong with markers.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FiducialError {
    /// Sizes or ids that cannot work.
    #[error("{0}")]
    Setup(String),
    /// Markers not found or not readable.
    #[error("markers: {0}")]
    NotFound(String),
}

/// Which cells of marker `id` are bright: `[row][column]`.
pub fn cells(id: u8) -> Result<[[bool; GRID]; GRID], FiducialError> {
    let code = *CODES.get(usize::from(id)).ok_or_else(|| {
        FiducialError::Setup(format!("marker id {id}: 0..={} exist", CODES.len() - 1))
    })?;
    let mut c = [[false; GRID]; GRID];
    for (r, row) in c.iter_mut().enumerate() {
        for (k, cell) in row.iter_mut().enumerate() {
            *cell = r == 0 || k == 0 || r == GRID - 1 || k == GRID - 1;
        }
    }
    c[1][1] = true;
    for (b, &(col, row)) in BITS.iter().enumerate() {
        c[row][col] = code & (1 << b) != 0;
    }
    Ok(c)
}

/// The id whose code is `bits`, if any.
fn id_of(bits: u8) -> Option<u8> {
    CODES.iter().position(|&c| c == bits).map(|i| i as u8)
}

/// Write the six mounts into `file` as the nominal clamp positions: A_i (ids 0..2, world
/// frame) and B_i (ids 3..5, platform frame: the image taken at q = 0 with the platform at
/// `platform` = (x, y, theta) in the image frame), metres, with `std_m` as the standard
/// uncertainty of Ax, Ay, Bx, By. The image frame is the world frame.
pub fn into_model(
    file: &mut PcrFile,
    found: &[MarkerPose],
    platform_um: [f64; 3],
    std_m: f64,
) -> Result<(), FiducialError> {
    if file.limbs.len() != 3 {
        return Err(FiducialError::Setup(format!(
            "the model has {} limbs, 3 are needed",
            file.limbs.len()
        )));
    }
    let get = |id: u8| {
        let mut it = found.iter().filter(|m| m.id == id);
        match (it.next(), it.next()) {
            (Some(m), None) => Ok(*m),
            (None, _) => Err(FiducialError::NotFound(format!(
                "mount {id} not in the image"
            ))),
            (Some(_), Some(_)) => Err(FiducialError::NotFound(format!("mount {id} found twice"))),
        }
    };
    let (s, c) = platform_um[2].sin_cos();
    for i in 0..3 {
        let a = get(i as u8)?;
        let b = get(3 + i as u8)?;
        let (dx, dy) = (b.x_um - platform_um[0], b.y_um - platform_um[1]);
        let limb = &mut file.limbs[i];
        limb.Ax = a.x_um * 1e-6;
        limb.Ay = a.y_um * 1e-6;
        limb.Bx = (c * dx + s * dy) * 1e-6;
        limb.By = (-s * dx + c * dy) * 1e-6;
    }
    for u in [
        &mut file.uncertainty.Ax,
        &mut file.uncertainty.Ay,
        &mut file.uncertainty.Bx,
        &mut file.uncertainty.By,
    ] {
        *u = std_m;
    }
    Ok(())
}
