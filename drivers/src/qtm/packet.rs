//! QTM RT packets (protocol 1.25, little endian): `u32 size` (incl. the 8-byte header),
//! `u32 type`, payload. Data packets carry a frame header and components; we decode the 3D
//! (labelled) and 3DNoLabels components and keep the others raw (devices.md §1).

use bytes::{Buf, BufMut, BytesMut};

use crate::error::{CodecError, quote};

/// Largest packet accepted (QTM XML can be large; frames are small).
pub const MAX_PACKET: usize = 16 * 1024 * 1024;

/// Event ids of type-6 packets.
pub mod event {
    /// A client connected.
    pub const CONNECTED: u8 = 1;
    /// Connection closed.
    pub const CONNECTION_CLOSED: u8 = 2;
    /// Capture started.
    pub const CAPTURE_STARTED: u8 = 3;
    /// Capture stopped.
    pub const CAPTURE_STOPPED: u8 = 4;
    /// QTM is shutting down.
    pub const QTM_SHUTTING_DOWN: u8 = 12;
}

/// Component type ids used here.
pub mod component {
    /// Labelled 3D markers.
    pub const THREE_D: u32 = 1;
    /// Unlabelled 3D markers with ids.
    pub const THREE_D_NO_LABELS: u32 = 2;
}

/// One component of a data frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Component {
    /// Type 1: markers in label order; occluded markers are NaN (mm).
    Markers3d {
        /// 2D drop rate, per mille.
        drop_rate: u16,
        /// 2D out-of-sync rate, per mille.
        out_of_sync_rate: u16,
        /// Positions x, y, z in mm.
        markers: Vec<[f32; 3]>,
    },
    /// Type 2: unlabelled markers with a tracking id.
    Markers3dNoLabels {
        /// 2D drop rate, per mille.
        drop_rate: u16,
        /// 2D out-of-sync rate, per mille.
        out_of_sync_rate: u16,
        /// Positions x, y, z in mm and marker id.
        markers: Vec<([f32; 3], u32)>,
    },
    /// Any other component, kept raw.
    Other {
        /// Component type id.
        kind: u32,
        /// Payload after the 8-byte component header.
        payload: Vec<u8>,
    },
}

/// A data packet (type 3).
#[derive(Debug, Clone, PartialEq)]
pub struct DataFrame {
    /// Camera time since measurement start, µs.
    pub timestamp_us: i64,
    /// Frame number (gaps = frames QTM skipped in real time).
    pub frame_number: u32,
    /// Components in packet order.
    pub components: Vec<Component>,
}

impl DataFrame {
    /// The labelled 3D markers, if the frame has that component.
    pub fn markers_3d(&self) -> Option<&[[f32; 3]]> {
        self.components.iter().find_map(|c| match c {
            Component::Markers3d { markers, .. } => Some(markers.as_slice()),
            _ => None,
        })
    }
}

/// One packet of either direction.
#[derive(Debug, Clone, PartialEq)]
pub enum Packet {
    /// Type 0: error text from the server.
    Error(String),
    /// Type 1: command or command response.
    Command(String),
    /// Type 2: XML parameters.
    Xml(String),
    /// Type 3: data frame.
    Data(DataFrame),
    /// Type 4: no measurement running.
    NoMoreData,
    /// Type 6: event id.
    Event(u8),
    /// Types 5, 7, 8 (files, discover): kept raw.
    Other {
        /// Packet type.
        kind: u32,
        /// Payload.
        payload: Vec<u8>,
    },
}

fn text(payload: &[u8]) -> String {
    let end = payload
        .iter()
        .position(|b| *b == 0)
        .unwrap_or(payload.len());
    String::from_utf8_lossy(&payload[..end]).into_owned()
}

fn need(b: &[u8], n: usize, what: &str) -> Result<(), CodecError> {
    if b.len() < n {
        return Err(CodecError::malformed(format!(
            "{what}: need {n} bytes, have {}",
            b.len()
        )));
    }
    Ok(())
}

fn read_f32x3(b: &mut &[u8]) -> [f32; 3] {
    [b.get_f32_le(), b.get_f32_le(), b.get_f32_le()]
}

/// Decodes a data payload (after the packet header).
pub fn decode_data(mut b: &[u8]) -> Result<DataFrame, CodecError> {
    need(b, 16, "data frame header")?;
    let timestamp_us = b.get_i64_le();
    let frame_number = b.get_u32_le();
    let count = b.get_u32_le();
    let mut components = Vec::with_capacity(count.min(32) as usize);
    for i in 0..count {
        need(b, 8, "component header")?;
        let size = b.get_u32_le() as usize;
        let kind = b.get_u32_le();
        if size < 8 || size - 8 > b.len() {
            return Err(CodecError::malformed(format!(
                "component {i} (type {kind}) size {size} does not fit the {} bytes left",
                b.len() + 8
            )));
        }
        let (mut body, rest) = b.split_at(size - 8);
        b = rest;
        components.push(match kind {
            component::THREE_D | component::THREE_D_NO_LABELS => {
                need(body, 8, "3D component header")?;
                let n = body.get_u32_le() as usize;
                let drop_rate = body.get_u16_le();
                let out_of_sync_rate = body.get_u16_le();
                let per = if kind == component::THREE_D { 12 } else { 16 };
                if n.checked_mul(per) != Some(body.len()) {
                    return Err(CodecError::malformed(format!(
                        "3D component says {n} markers but carries {} bytes",
                        body.len()
                    )));
                }
                if kind == component::THREE_D {
                    let markers = (0..n).map(|_| read_f32x3(&mut body)).collect();
                    Component::Markers3d {
                        drop_rate,
                        out_of_sync_rate,
                        markers,
                    }
                } else {
                    let markers = (0..n)
                        .map(|_| (read_f32x3(&mut body), body.get_u32_le()))
                        .collect();
                    Component::Markers3dNoLabels {
                        drop_rate,
                        out_of_sync_rate,
                        markers,
                    }
                }
            }
            _ => Component::Other {
                kind,
                payload: body.to_vec(),
            },
        });
    }
    if !b.is_empty() {
        return Err(CodecError::malformed(format!(
            "{} bytes after the last component",
            b.len()
        )));
    }
    Ok(DataFrame {
        timestamp_us,
        frame_number,
        components,
    })
}

/// Decodes a packet from its type and payload.
pub fn decode(kind: u32, payload: &[u8]) -> Result<Packet, CodecError> {
    Ok(match kind {
        0 => Packet::Error(text(payload)),
        1 => Packet::Command(text(payload)),
        2 => Packet::Xml(text(payload)),
        3 => Packet::Data(decode_data(payload)?),
        4 => Packet::NoMoreData,
        6 => {
            need(payload, 1, "event packet")?;
            Packet::Event(payload[0])
        }
        5 | 7 | 8 => Packet::Other {
            kind,
            payload: payload.to_vec(),
        },
        _ => {
            return Err(CodecError::malformed(format!(
                "unknown packet type {kind} (payload {})",
                quote(payload)
            )));
        }
    })
}

/// Decodes one whole packet (header included), e.g. a UDP datagram.
pub fn decode_whole(b: &[u8]) -> Result<Packet, CodecError> {
    need(b, 8, "packet header")?;
    let size = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
    let kind = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
    if size != b.len() {
        return Err(CodecError::malformed(format!(
            "datagram of {} bytes says size {size}",
            b.len()
        )));
    }
    decode(kind, &b[8..])
}

fn put_header(dst: &mut BytesMut, size: usize, kind: u32) {
    dst.put_u32_le(size as u32);
    dst.put_u32_le(kind);
}

fn put_text(dst: &mut BytesMut, kind: u32, s: &str) {
    put_header(dst, 8 + s.len() + 1, kind);
    dst.put_slice(s.as_bytes());
    dst.put_u8(0);
}

/// Appends the encoding of `p` to `dst`.
pub fn encode(p: &Packet, dst: &mut BytesMut) {
    match p {
        Packet::Error(s) => put_text(dst, 0, s),
        Packet::Command(s) => put_text(dst, 1, s),
        Packet::Xml(s) => put_text(dst, 2, s),
        Packet::NoMoreData => put_header(dst, 8, 4),
        Packet::Event(e) => {
            put_header(dst, 9, 6);
            dst.put_u8(*e);
        }
        Packet::Other { kind, payload } => {
            put_header(dst, 8 + payload.len(), *kind);
            dst.put_slice(payload);
        }
        Packet::Data(f) => {
            let start = dst.len();
            put_header(dst, 0, 3);
            dst.put_i64_le(f.timestamp_us);
            dst.put_u32_le(f.frame_number);
            dst.put_u32_le(f.components.len() as u32);
            for c in &f.components {
                let cstart = dst.len();
                match c {
                    Component::Markers3d {
                        drop_rate,
                        out_of_sync_rate,
                        markers,
                    } => {
                        put_header(dst, 0, component::THREE_D);
                        dst.put_u32_le(markers.len() as u32);
                        dst.put_u16_le(*drop_rate);
                        dst.put_u16_le(*out_of_sync_rate);
                        for m in markers {
                            m.iter().for_each(|v| dst.put_f32_le(*v));
                        }
                    }
                    Component::Markers3dNoLabels {
                        drop_rate,
                        out_of_sync_rate,
                        markers,
                    } => {
                        put_header(dst, 0, component::THREE_D_NO_LABELS);
                        dst.put_u32_le(markers.len() as u32);
                        dst.put_u16_le(*drop_rate);
                        dst.put_u16_le(*out_of_sync_rate);
                        for (m, id) in markers {
                            m.iter().for_each(|v| dst.put_f32_le(*v));
                            dst.put_u32_le(*id);
                        }
                    }
                    Component::Other { kind, payload } => {
                        put_header(dst, 8 + payload.len(), *kind);
                        dst.put_slice(payload);
                    }
                }
                let csize = (dst.len() - cstart) as u32;
                dst[cstart..cstart + 4].copy_from_slice(&csize.to_le_bytes());
            }
            let size = (dst.len() - start) as u32;
            dst[start..start + 4].copy_from_slice(&size.to_le_bytes());
        }
    }
}
