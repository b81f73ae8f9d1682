//! The RAPID data types calibd reads and writes: `robtarget` (position, quaternion `q1..q4`
//! = w, x, y, z, configuration `cf1, cf4, cf6, cfx`), `tooldata` (the TCP frame `tframe` in
//! the flange frame `tool0`) and `wobjdata` (user frame and object frame in the world).

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::parse::Value;
use crate::geometry::Frame;

/// A number of a literal and its byte span in the module.
pub type Spanned = (f64, usize, usize);

/// A literal robtarget: its numbers with their spans.
#[derive(Debug, Clone, PartialEq)]
pub struct RobTarget {
    /// x, y, z (mm).
    pub pos: [Spanned; 3],
    /// q1..q4 (w, x, y, z).
    pub rot: [Spanned; 4],
    /// cf1, cf4, cf6, cfx.
    pub conf: [Spanned; 4],
    /// The external axes as written (bytes of the fourth component).
    pub extax: (usize, usize),
}

impl RobTarget {
    /// A robtarget literal `[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[e1..e6]]`; `None` if
    /// `v` is not one.
    pub fn of(v: &Value) -> Option<Self> {
        let it = v.items().filter(|i| i.len() == 4)?;
        let ext = match &it[3] {
            Value::List { items, start, end } if items.len() == 6 => (*start, *end),
            _ => return None,
        };
        Some(Self {
            pos: it[0].numbers(3)?.try_into().ok()?,
            rot: it[1].numbers(4)?.try_into().ok()?,
            conf: it[2].numbers(4)?.try_into().ok()?,
            extax: ext,
        })
    }

    /// The pose (TCP in the work object), the quaternion normalised; `None` for a zero
    /// quaternion.
    pub fn frame(&self) -> Option<Frame> {
        let q = self.rot.map(|r| r.0);
        Some(Frame {
            r: quat_to_matrix(&q)?,
            p: Vector3::new(self.pos[0].0, self.pos[1].0, self.pos[2].0),
        })
    }

    /// cf1, cf4, cf6, cfx as integers (`None` if one is not an integer).
    pub fn confdata(&self) -> Option<[i64; 4]> {
        let mut c = [0; 4];
        for (k, v) in self.conf.iter().enumerate() {
            if v.0.fract() != 0.0 || !v.0.is_finite() {
                return None;
            }
            c[k] = v.0 as i64;
        }
        Some(c)
    }
}

/// A pose literal `[[x,y,z],[q1,q2,q3,q4]]` as a frame.
pub fn pose(v: &Value) -> Option<Frame> {
    let it = v.items().filter(|i| i.len() == 2)?;
    let p = it[0].numbers(3)?;
    let q: Vec<f64> = it[1].numbers(4)?.iter().map(|n| n.0).collect();
    Some(Frame {
        r: quat_to_matrix(&[q[0], q[1], q[2], q[3]])?,
        p: Vector3::new(p[0].0, p[1].0, p[2].0),
    })
}

/// What a `tooldata` or `wobjdata` literal says, or why calibd cannot use it.
#[derive(Debug, Clone, PartialEq)]
pub enum Held {
    /// Usable: the frame (TCP in the flange for a tool; object frame in the world for a
    /// work object).
    Frame(Frame),
    /// Not usable, and why.
    Unsupported(String),
}

fn boolean(v: &Value) -> Option<bool> {
    match v {
        Value::Word(w) if w.eq_ignore_ascii_case("TRUE") => Some(true),
        Value::Word(w) if w.eq_ignore_ascii_case("FALSE") => Some(false),
        _ => None,
    }
}

/// A `tooldata` literal `[robhold, [[x,y,z],[q]], [mass, [cog], [aom], ix, iy, iz]]`.
pub fn tooldata(v: &Value) -> Option<Held> {
    let it = v.items().filter(|i| i.len() == 3)?;
    let robhold = boolean(&it[0])?;
    let tframe = pose(&it[1])?;
    Some(if robhold {
        Held::Frame(tframe)
    } else {
        Held::Unsupported("a stationary tool (robhold FALSE) is not supported".into())
    })
}

/// A `wobjdata` literal `[robhold, ufprog, ufmec, uframe, oframe]`: the object frame in the
/// world, `uframe * oframe`.
pub fn wobjdata(v: &Value) -> Option<Held> {
    let it = v.items().filter(|i| i.len() == 5)?;
    let robhold = boolean(&it[0])?;
    let ufprog = boolean(&it[1])?;
    let u = pose(&it[3])?;
    let o = pose(&it[4])?;
    Some(if robhold {
        Held::Unsupported("a work object held by the robot (robhold TRUE) is not supported".into())
    } else if !ufprog {
        Held::Unsupported("a moving user frame (ufprog FALSE) is not supported".into())
    } else {
        Held::Frame(u.mul(&o))
    })
}

/// The rotation of a quaternion (w, x, y, z), normalised; `None` for a zero quaternion.
pub fn quat_to_matrix(q: &[f64; 4]) -> Option<Matrix3<f64>> {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(n > 1e-9) || !n.is_finite() {
        return None;
    }
    let u = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    Some(*u.to_rotation_matrix().matrix())
}

/// The unit quaternion (w, x, y, z) of a rotation, signed to be nearest `near`.
pub fn matrix_to_quat(r: &Matrix3<f64>, near: &[f64; 4]) -> [f64; 4] {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(*r);
    let u = UnitQuaternion::from_rotation_matrix(&rot);
    let q = [u.w, u.i, u.j, u.k];
    let dot: f64 = q.iter().zip(near).map(|(a, b)| a * b).sum();
    if dot < 0.0 { q.map(|v| -v) } else { q }
}
