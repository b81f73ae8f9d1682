//! Joint interface of a humanoid (or any robot driven joint by joint to whole postures),
//! spoken over a small TCP protocol of calibd's design: the robot side runs a server speaking
//! it (for ROS 2 robots such as TALOS, `deploy/ros2/calibd_joint_bridge.py`).
//!
//! # Protocol (`calibd-joints/1`)
//!
//! JSON lines over TCP: one JSON object per line ended by LF (a CR before the LF is
//! ignored), at most 64 KiB per line LF included, UTF-8. One reply per request, requests
//! answered in order. Units are in the field names (`_rad`, `_s`).
//!
//! | request                                                        | reply (success)                                                                                   |
//! |----------------------------------------------------------------|---------------------------------------------------------------------------------------------------|
//! | `{"op":"hello"}`                                               | `{"ok":true,"protocol":"calibd-joints/1","robot":"<name>","joints":[names],"limits_rad":[[lo,hi],...]}` |
//! | `{"op":"read"}`                                                | `{"ok":true,"positions_rad":{name: value,...},"moving":bool}`                                   |
//! | `{"op":"move","positions_rad":{name: value,...},"duration_s":f}` | `{"ok":true,"positions_rad":{...}}`, sent only once the posture is reached                     |
//! | `{"op":"stop"}`                                                | `{"ok":true}`                                                                                     |
//!
//! Any request may instead fail with
//! `{"ok":false,"error":{"code":"<code>","message":"<text>"}}`, codes:
//!
//! | code            | meaning                                                        | [`DriverError::Device`](crate::DriverError) code |
//! |-----------------|----------------------------------------------------------------|-----|
//! | `unknown_joint` | a `move` names a joint the robot does not have                 | 1   |
//! | `out_of_limits` | a `move` target lies outside the joint's limits                | 2   |
//! | `busy`          | a `move` while another move is running                         | 3   |
//! | `fault`         | the controller failed (or the move was stopped before the end) | 4   |
//! | `bad_request`   | not JSON, not an object, unknown `op`, missing or bad fields, line too long | 5 |
//!
//! (an error code this version does not know is code 0 for the driver).
//!
//! `hello` lists the joints in the robot's order with their limits (`limits_rad[k]` belongs
//! to `joints[k]`, `lo <= hi`). A `move` names any subset of the joints (the others keep
//! their positions) and takes `duration_s >= 0` seconds; its reply carries the positions
//! reached (all joints). `stop` halts any move in progress, of any connection: that move
//! then fails with `fault`; requests that arrive on a connection while its move runs are
//! answered after the move's reply, in order, except that a `stop` takes effect at once.
//! A line longer than 64 KiB is answered with `bad_request` and skipped up to its LF.
//!
//! Example:
//!
//! ```text
//! -> {"op":"hello"}
//! <- {"ok":true,"protocol":"calibd-joints/1","robot":"talos","joints":["arm_left_1_joint","arm_left_2_joint"],"limits_rad":[[-1.57,0.79],[0.0087,2.88]]}
//! -> {"op":"read"}
//! <- {"ok":true,"positions_rad":{"arm_left_1_joint":0.0,"arm_left_2_joint":0.0087},"moving":false}
//! -> {"op":"move","positions_rad":{"arm_left_2_joint":0.5},"duration_s":0.25}
//! <- {"ok":true,"positions_rad":{"arm_left_1_joint":0.0,"arm_left_2_joint":0.5}}
//! -> {"op":"move","positions_rad":{"arm_left_1_joint":2.0},"duration_s":1.0}
//! <- {"ok":false,"error":{"code":"out_of_limits","message":"arm_left_1_joint = 2 rad is outside [-1.57, 0.79]"}}
//! ```

pub mod codec;
pub mod driver;
pub mod mock;

pub use codec::{ErrorCode, Identity, JointsCodec, Reply, Request, ServerCodec};
pub use driver::{JointsConfig, JointsHandle, JointsReading, JointsState};

/// The protocol name sent in the `hello` reply.
pub const PROTOCOL: &str = "calibd-joints/1";
