//! CANopen (CiA 301) expedited SDO frames and the CiA 402 object/state constants
//! (devices.md §5; constants as in canopen 2.4.1 `profiles/p402.py`).

use crate::error::CodecError;

/// SDO request COB-ID base (0x600 + node).
pub const SDO_RX: u16 = 0x600;
/// SDO response COB-ID base (0x580 + node).
pub const SDO_TX: u16 = 0x580;

/// CiA 402 objects used by calibd.
pub mod obj {
    /// Controlword (u16).
    pub const CONTROLWORD: u16 = 0x6040;
    /// Statusword (u16).
    pub const STATUSWORD: u16 = 0x6041;
    /// Modes of operation (i8): 1 profile position, 6 homing.
    pub const MODES: u16 = 0x6060;
    /// Modes of operation display (i8).
    pub const MODES_DISPLAY: u16 = 0x6061;
    /// Target position (i32).
    pub const TARGET_POSITION: u16 = 0x607A;
    /// Position actual value (i32).
    pub const POSITION_ACTUAL: u16 = 0x6064;
    /// Profile velocity (u32).
    pub const PROFILE_VELOCITY: u16 = 0x6081;
    /// Error code (u16).
    pub const ERROR_CODE: u16 = 0x603F;
    /// Device type (u32, CiA 301; low word 402 for a drive).
    pub const DEVICE_TYPE: u16 = 0x1000;
    /// Manufacturer device name (VISIBLE_STRING, segmented upload when > 4 bytes).
    pub const DEVICE_NAME: u16 = 0x1008;
    /// Identity object (CiA 301): sub 1 vendor id, 2 product code, 3 revision, 4 serial.
    pub const IDENTITY: u16 = 0x1018;
}

/// A parsed SDO response.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoResponse {
    /// Expedited upload: the data (1-4 bytes).
    Upload {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Data bytes, little endian.
        data: Vec<u8>,
    },
    /// Segmented upload initiated (`41`: size indicated, `40`: not): the data follows in
    /// segments ([`upload_segment_request`], [`parse_upload_segment`]).
    UploadSegmented {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Total size in bytes, when indicated.
        size: Option<u32>,
    },
    /// Download acknowledge.
    DownloadAck {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
    },
    /// Abort with a CiA 301 abort code.
    Abort {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Abort code.
        code: u32,
    },
}

/// Upload (read) request `40 ii ii ss 00 00 00 00`.
pub fn upload_request(index: u16, sub: u8) -> [u8; 8] {
    let i = index.to_le_bytes();
    [0x40, i[0], i[1], sub, 0, 0, 0, 0]
}

/// Expedited download (write) request of 1-4 bytes.
pub fn download_request(index: u16, sub: u8, data: &[u8]) -> Option<[u8; 8]> {
    if data.is_empty() || data.len() > 4 {
        return None;
    }
    let i = index.to_le_bytes();
    let cmd = 0x23 | (((4 - data.len()) as u8) << 2);
    let mut f = [cmd, i[0], i[1], sub, 0, 0, 0, 0];
    f[4..4 + data.len()].copy_from_slice(data);
    Some(f)
}

/// An SDO response frame.
pub fn response(r: &SdoResponse) -> [u8; 8] {
    match r {
        SdoResponse::Upload { index, sub, data } => {
            let i = index.to_le_bytes();
            let n = data.len().clamp(1, 4);
            let mut f = [0x43 | (((4 - n) as u8) << 2), i[0], i[1], *sub, 0, 0, 0, 0];
            f[4..4 + n].copy_from_slice(&data[..n]);
            f
        }
        SdoResponse::UploadSegmented { index, sub, size } => {
            let i = index.to_le_bytes();
            let n = size.unwrap_or(0).to_le_bytes();
            let cmd = if size.is_some() { 0x41 } else { 0x40 };
            [cmd, i[0], i[1], *sub, n[0], n[1], n[2], n[3]]
        }
        SdoResponse::DownloadAck { index, sub } => {
            let i = index.to_le_bytes();
            [0x60, i[0], i[1], *sub, 0, 0, 0, 0]
        }
        SdoResponse::Abort { index, sub, code } => {
            let i = index.to_le_bytes();
            let c = code.to_le_bytes();
            [0x80, i[0], i[1], *sub, c[0], c[1], c[2], c[3]]
        }
    }
}

/// Parses an SDO response (server → client) frame's 8 data bytes.
pub fn parse_response(d: &[u8]) -> Result<SdoResponse, CodecError> {
    if d.len() != 8 {
        return Err(CodecError::malformed(format!(
            "SDO response has {} bytes, not 8",
            d.len()
        )));
    }
    let index = u16::from_le_bytes([d[1], d[2]]);
    let sub = d[3];
    match d[0] {
        0x60 => Ok(SdoResponse::DownloadAck { index, sub }),
        0x40 | 0x41 => Ok(SdoResponse::UploadSegmented {
            index,
            sub,
            size: (d[0] == 0x41).then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]])),
        }),
        0x80 => Ok(SdoResponse::Abort {
            index,
            sub,
            code: u32::from_le_bytes([d[4], d[5], d[6], d[7]]),
        }),
        c if c & 0xE3 == 0x43 => {
            let n = 4 - ((c >> 2) & 3) as usize;
            Ok(SdoResponse::Upload {
                index,
                sub,
                data: d[4..4 + n].to_vec(),
            })
        }
        c => Err(CodecError::malformed(format!(
            "unsupported SDO response command byte {c:#04x} (segmented transfer?)"
        ))),
    }
}

/// Upload segment request (client → server): `60` with toggle bit 4.
pub fn upload_segment_request(toggle: bool) -> [u8; 8] {
    [0x60 | (u8::from(toggle) << 4), 0, 0, 0, 0, 0, 0, 0]
}

/// One segment of a segmented upload (server → client).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UploadSegment {
    /// 1-7 data bytes; `last` when the server set the no-more-segments bit.
    Data {
        /// The segment's data bytes.
        data: Vec<u8>,
        /// No more segments follow.
        last: bool,
    },
    /// The server aborted the transfer.
    Abort {
        /// Abort code.
        code: u32,
    },
}

/// Parses an upload segment response `0 t nnn c` + 7 bytes, checking the toggle bit.
pub fn parse_upload_segment(d: &[u8], toggle: bool) -> Result<UploadSegment, CodecError> {
    if d.len() != 8 {
        return Err(CodecError::malformed(format!(
            "SDO segment has {} bytes, not 8",
            d.len()
        )));
    }
    if d[0] == 0x80 {
        return Ok(UploadSegment::Abort {
            code: u32::from_le_bytes([d[4], d[5], d[6], d[7]]),
        });
    }
    if d[0] & 0xE0 != 0 {
        return Err(CodecError::malformed(format!(
            "SDO upload segment expected, got command byte {:#04x}",
            d[0]
        )));
    }
    if (d[0] & 0x10 != 0) != toggle {
        return Err(CodecError::malformed(
            "SDO upload segment toggle bit not alternated",
        ));
    }
    let unused = usize::from((d[0] >> 1) & 7);
    Ok(UploadSegment::Data {
        data: d[1..8 - unused].to_vec(),
        last: d[0] & 1 != 0,
    })
}

/// An upload segment response carrying `chunk` (1-7 bytes).
pub fn upload_segment_response(toggle: bool, chunk: &[u8], last: bool) -> [u8; 8] {
    let n = chunk.len().clamp(1, 7);
    let unused = (7 - n) as u8;
    let mut f = [
        (u8::from(toggle) << 4) | (unused << 1) | u8::from(last),
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    ];
    f[1..1 + n].copy_from_slice(&chunk[..n]);
    f
}

/// Text of a CiA 301 SDO abort code.
pub fn abort_text(code: u32) -> &'static str {
    match code {
        0x0503_0000 => "toggle bit not alternated",
        0x0504_0000 => "SDO protocol timed out",
        0x0504_0001 => "command specifier not valid",
        0x0601_0001 => "attempt to read a write-only object",
        0x0601_0002 => "attempt to write a read-only object",
        0x0602_0000 => "object does not exist in the object dictionary",
        0x0607_0010 => "data type does not match, length of service parameter does not match",
        0x0609_0011 => "sub-index does not exist",
        0x0609_0030 => "invalid value for parameter",
        0x0800_0000 => "general error",
        0x0800_0022 => "data cannot be transferred because of the present device state",
        _ => "unknown abort code",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn documented_frames() {
        assert_eq!(upload_request(0x6041, 0), [0x40, 0x41, 0x60, 0, 0, 0, 0, 0]);
        // Segmented upload of 0x1008 "CalibAxis 1" (11 bytes): initiate, then 7 + 4 bytes.
        assert_eq!(
            parse_response(&[0x41, 0x08, 0x10, 0x00, 0x0B, 0, 0, 0]).unwrap(),
            SdoResponse::UploadSegmented {
                index: 0x1008,
                sub: 0,
                size: Some(11)
            }
        );
        assert_eq!(upload_segment_request(false), [0x60, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(upload_segment_request(true), [0x70, 0, 0, 0, 0, 0, 0, 0]);
        let s1 = [0x00, b'C', b'a', b'l', b'i', b'b', b'A', b'x'];
        let s2 = [0x17, b'i', b's', b' ', b'1', 0, 0, 0];
        assert_eq!(upload_segment_response(false, b"CalibAx", false), s1);
        assert_eq!(upload_segment_response(true, b"is 1", true), s2);
        assert_eq!(
            parse_upload_segment(&s1, false).unwrap(),
            UploadSegment::Data {
                data: b"CalibAx".to_vec(),
                last: false
            }
        );
        assert_eq!(
            parse_upload_segment(&s2, true).unwrap(),
            UploadSegment::Data {
                data: b"is 1".to_vec(),
                last: true
            }
        );
        assert!(parse_upload_segment(&s2, false).is_err());
        assert_eq!(
            parse_upload_segment(&[0x80, 0x08, 0x10, 0, 0x00, 0x00, 0x04, 0x05], true).unwrap(),
            UploadSegment::Abort { code: 0x0504_0000 }
        );
        // devices.md: 601 23 7A 60 00 A0 86 01 00 writes 100000 to 0x607A.
        assert_eq!(
            download_request(0x607A, 0, &100_000i32.to_le_bytes()),
            Some([0x23, 0x7A, 0x60, 0x00, 0xA0, 0x86, 0x01, 0x00])
        );
        assert_eq!(
            download_request(0x6040, 0, &[0x0f, 0]).map(|f| f[0]),
            Some(0x2B)
        );
        assert_eq!(download_request(0x6060, 0, &[1]).map(|f| f[0]), Some(0x2F));
        // 581 4B 41 60 00 37 02 00 00: statusword 0x0237.
        let r = parse_response(&[0x4B, 0x41, 0x60, 0, 0x37, 0x02, 0, 0]).unwrap();
        assert_eq!(
            r,
            SdoResponse::Upload {
                index: 0x6041,
                sub: 0,
                data: vec![0x37, 0x02]
            }
        );
        assert_eq!(response(&r), [0x4B, 0x41, 0x60, 0, 0x37, 0x02, 0, 0]);
        let a = SdoResponse::Abort {
            index: 0x1234,
            sub: 1,
            code: 0x0602_0000,
        };
        assert_eq!(parse_response(&response(&a)).unwrap(), a);
        // A download segment response is not something an upload or expedited write gets.
        assert!(parse_response(&[0x20, 0, 0, 0, 0, 0, 0, 0]).is_err());
        assert!(parse_response(&[0x60, 0, 0]).is_err());
    }
}
