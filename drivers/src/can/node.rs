//! Simulated CiA 402 drive (SDO server) for the CAN mock: object dictionary, power state
//! machine, profile-position and homing set-points, motion from a [`DriveModel`].

use std::collections::HashMap;

use super::canopen::{SDO_RX, SDO_TX, SdoResponse, obj, response, upload_segment_response};

/// Vendor id the simulated drive reports in 0x1018:1 (not a CiA-assigned id).
pub const MOCK_VENDOR_ID: u32 = 0x00CA_1BD0;
/// Product code of the simulated drive (0x1018:2).
pub const MOCK_PRODUCT_CODE: u32 = 0x0000_0402;
/// Revision number of the simulated drive (0x1018:3): major 1, minor 3.
pub const MOCK_REVISION: u32 = 0x0001_0003;
/// Serial number of the simulated drive (0x1018:4).
pub const MOCK_SERIAL: u32 = 0x0000_1234;
/// Device name of the simulated drive (0x1008, read with a segmented upload).
pub const MOCK_DEVICE_NAME: &str = "calibd CiA402 sim";
use super::frame::CanFrame;

/// The axis behind the drive: the hook for a stage/joint twin.
pub trait DriveModel: Send + 'static {
    /// Next position (counts) after `dt_s` moving from `pos` towards `target` at `velocity`
    /// counts/s.
    fn advance(&mut self, pos: i32, target: i32, velocity: u32, dt_s: f64) -> i32;
    /// Software position limits (counts).
    fn limits(&self) -> (i32, i32);
}

/// Default: a linear axis that moves at the profile velocity, ±10 000 000 counts.
#[derive(Debug, Clone, Default)]
pub struct LinearAxis;

impl DriveModel for LinearAxis {
    fn advance(&mut self, pos: i32, target: i32, velocity: u32, dt_s: f64) -> i32 {
        let step = (f64::from(velocity) * dt_s).max(1.0) as i64;
        let d = i64::from(target) - i64::from(pos);
        (i64::from(pos) + d.clamp(-step, step)) as i32
    }
    fn limits(&self) -> (i32, i32) {
        (-10_000_000, 10_000_000)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Power {
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    Fault,
}

/// One drive on the bus.
pub struct Drive {
    node: u8,
    model: Box<dyn DriveModel>,
    od: HashMap<u16, Vec<u8>>,
    /// Objects with sub-indices (0x1018) and strings (0x1008), keyed by (index, sub).
    records: HashMap<(u16, u8), Vec<u8>>,
    /// A segmented upload in progress: index, sub, bytes still to send, next toggle bit.
    segment: Option<(u16, u8, Vec<u8>, bool)>,
    power: Power,
    controlword: u16,
    position: i32,
    target: i32,
    moving: bool,
    setpoint_ack: bool,
    homed: bool,
}

impl std::fmt::Debug for Drive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Drive(node {}, {:?}, pos {})",
            self.node, self.power, self.position
        )
    }
}

const READ_ONLY: [u16; 8] = [
    obj::STATUSWORD,
    obj::MODES_DISPLAY,
    obj::POSITION_ACTUAL,
    obj::ERROR_CODE,
    obj::DEVICE_TYPE,
    obj::DEVICE_NAME,
    obj::IDENTITY,
    0x6502,
];

impl Drive {
    /// A drive with node id `node`.
    pub fn new(node: u8, model: Box<dyn DriveModel>) -> Self {
        let mut od = HashMap::new();
        od.insert(0x1000, 0x0002_0192u32.to_le_bytes().to_vec()); // CiA 402 servo drive
        od.insert(obj::MODES, vec![0]);
        od.insert(obj::TARGET_POSITION, 0i32.to_le_bytes().to_vec());
        od.insert(obj::PROFILE_VELOCITY, 2_000_000u32.to_le_bytes().to_vec());
        od.insert(0x6083, 10_000_000u32.to_le_bytes().to_vec());
        od.insert(0x6084, 10_000_000u32.to_le_bytes().to_vec());
        od.insert(0x6098, vec![35]); // homing on the current position
        od.insert(0x6502, 0x21u32.to_le_bytes().to_vec()); // pp + hm
        od.insert(obj::ERROR_CODE, vec![0, 0]);
        let mut records = HashMap::new();
        records.insert((obj::DEVICE_NAME, 0), MOCK_DEVICE_NAME.as_bytes().to_vec());
        records.insert((obj::IDENTITY, 0), vec![4]);
        for (sub, v) in [
            (1, MOCK_VENDOR_ID),
            (2, MOCK_PRODUCT_CODE),
            (3, MOCK_REVISION),
            (4, MOCK_SERIAL),
        ] {
            records.insert((obj::IDENTITY, sub), v.to_le_bytes().to_vec());
        }
        Drive {
            node,
            model,
            od,
            records,
            segment: None,
            power: Power::SwitchOnDisabled,
            controlword: 0,
            position: 0,
            target: 0,
            moving: false,
            setpoint_ack: false,
            homed: false,
        }
    }

    /// Current statusword (bit 15 = manufacturer-specific "position referenced").
    pub fn statusword(&self) -> u16 {
        let mut s: u16 = match self.power {
            Power::SwitchOnDisabled => 0x0040,
            Power::ReadyToSwitchOn => 0x0021,
            Power::SwitchedOn => 0x0023,
            Power::OperationEnabled => 0x0027,
            Power::Fault => 0x0008,
        } | 0x0200
            | 0x0010;
        if self.power == Power::OperationEnabled && !self.moving {
            s |= 1 << 10;
        }
        if self.setpoint_ack {
            s |= 1 << 12;
        }
        if self.homed {
            s |= 1 << 15;
        }
        s
    }

    fn mode(&self) -> i8 {
        self.od
            .get(&obj::MODES)
            .and_then(|v| v.first())
            .map_or(0, |b| *b as i8)
    }

    fn u32_of(&self, index: u16) -> u32 {
        self.od
            .get(&index)
            .and_then(|v| v.get(..4))
            .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn apply_controlword(&mut self, cw: u16) {
        let rising = |bit: u16| cw & bit != 0 && self.controlword & bit == 0;
        if rising(0x80) && self.power == Power::Fault {
            self.power = Power::SwitchOnDisabled;
        } else if self.power != Power::Fault {
            self.power = match (cw & 0x8F, self.power) {
                (0x06, _) => Power::ReadyToSwitchOn,
                (0x07, Power::ReadyToSwitchOn | Power::OperationEnabled) => Power::SwitchedOn,
                (0x0F, Power::ReadyToSwitchOn | Power::SwitchedOn | Power::OperationEnabled) => {
                    Power::OperationEnabled
                }
                (c, _) if c & 0x02 == 0 => Power::SwitchOnDisabled,
                (_, p) => p,
            };
        }
        if self.power != Power::OperationEnabled {
            self.moving = false;
        } else if rising(0x10) {
            match self.mode() {
                1 => {
                    let t = self
                        .od
                        .get(&obj::TARGET_POSITION)
                        .map_or(0, |b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]));
                    let t = if cw & 0x40 != 0 {
                        self.position.saturating_add(t)
                    } else {
                        t
                    };
                    let (lo, hi) = self.model.limits();
                    self.target = t.clamp(lo, hi);
                    self.moving = self.target != self.position;
                    self.setpoint_ack = true;
                }
                6 => {
                    self.position = 0;
                    self.target = 0;
                    self.homed = true;
                    self.setpoint_ack = true;
                }
                _ => {}
            }
        }
        if cw & 0x10 == 0 {
            self.setpoint_ack = false;
        }
        self.controlword = cw;
    }

    /// Advances the motion by `dt_s`.
    pub fn tick(&mut self, dt_s: f64) {
        if self.moving {
            let v = self.u32_of(obj::PROFILE_VELOCITY);
            self.position = self.model.advance(self.position, self.target, v, dt_s);
            self.moving = self.position != self.target;
        }
    }

    fn read(&self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        if let Some(v) = self.records.get(&(index, sub)) {
            return Ok(v.clone());
        }
        if self.records.keys().any(|(i, _)| *i == index) {
            return Err(0x0609_0011);
        }
        let v = match index {
            obj::STATUSWORD => self.statusword().to_le_bytes().to_vec(),
            obj::CONTROLWORD => self.controlword.to_le_bytes().to_vec(),
            obj::MODES_DISPLAY => vec![self.mode() as u8],
            obj::POSITION_ACTUAL => self.position.to_le_bytes().to_vec(),
            i => self.od.get(&i).cloned().ok_or(0x0602_0000u32)?,
        };
        if sub != 0 {
            return Err(0x0609_0011);
        }
        Ok(v)
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
        if READ_ONLY.contains(&index) {
            return Err(0x0601_0002);
        }
        let len = match index {
            obj::CONTROLWORD => 2,
            i => self.od.get(&i).map(Vec::len).ok_or(0x0602_0000u32)?,
        };
        if sub != 0 {
            return Err(0x0609_0011);
        }
        if data.len() != len {
            return Err(0x0607_0010);
        }
        if index == obj::CONTROLWORD {
            self.apply_controlword(u16::from_le_bytes([data[0], data[1]]));
        } else {
            self.od.insert(index, data.to_vec());
        }
        Ok(())
    }

    /// The next upload segment, or an abort (no transfer running, toggle not alternated).
    fn next_segment(&mut self, toggle: bool) -> [u8; 8] {
        let Some((index, sub, mut rest, t)) = self.segment.take() else {
            return response(&SdoResponse::Abort {
                index: 0,
                sub: 0,
                code: 0x0504_0001,
            });
        };
        if t != toggle {
            return response(&SdoResponse::Abort {
                index,
                sub,
                code: 0x0503_0000,
            });
        }
        let chunk: Vec<u8> = rest.drain(..rest.len().min(7)).collect();
        let last = rest.is_empty();
        if !last {
            self.segment = Some((index, sub, rest, !toggle));
        }
        upload_segment_response(toggle, &chunk, last)
    }

    /// Handles one bus frame; returns the reply frame, if any.
    pub fn on_frame(&mut self, f: &CanFrame) -> Option<CanFrame> {
        let node = u16::from(self.node);
        if f.extended {
            return None;
        }
        if f.id == 0 && f.data.len() == 2 && (f.data[1] == self.node || f.data[1] == 0) {
            // NMT: reset node (0x81) returns to switch-on disabled and announces boot-up.
            if f.data[0] == 0x81 {
                self.power = Power::SwitchOnDisabled;
                return Some(CanFrame::new(0x700 + node, &[0x00]));
            }
            return None;
        }
        if f.id != u32::from(SDO_RX + node) || f.data.len() != 8 {
            return None;
        }
        let d = &f.data;
        let (index, sub) = (u16::from_le_bytes([d[1], d[2]]), d[3]);
        let r = match d[0] {
            0x40 => match self.read(index, sub) {
                Ok(data) if data.len() > 4 => {
                    let size = u32::try_from(data.len()).ok();
                    self.segment = Some((index, sub, data, false));
                    SdoResponse::UploadSegmented { index, sub, size }
                }
                Ok(data) => SdoResponse::Upload { index, sub, data },
                Err(code) => SdoResponse::Abort { index, sub, code },
            },
            // Upload segment request, toggle in bit 4 (no index in segment frames).
            0x60 | 0x70 => {
                let toggle = d[0] == 0x70;
                return Some(CanFrame::new(SDO_TX + node, &self.next_segment(toggle)));
            }
            c if c & 0xE3 == 0x23 => {
                let n = 4 - ((c >> 2) & 3) as usize;
                match self.write(index, sub, &d[4..4 + n]) {
                    Ok(()) => SdoResponse::DownloadAck { index, sub },
                    Err(code) => SdoResponse::Abort { index, sub, code },
                }
            }
            _ => SdoResponse::Abort {
                index,
                sub,
                code: 0x0504_0001,
            },
        };
        Some(CanFrame::new(SDO_TX + node, &response(&r)))
    }
}
