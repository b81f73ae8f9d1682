//! Stream codec for QTM RT packets over TCP: read the 8-byte header, then exactly
//! `size - 8` bytes (TCP may split or coalesce packets).

use bytes::{Buf, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use super::packet::{self, MAX_PACKET, Packet};
use crate::error::{CodecError, quote};

/// Codec used by both the driver and the mock (packets are symmetric).
#[derive(Debug, Clone, Copy, Default)]
pub struct QtmCodec;

impl Decoder for QtmCodec {
    type Item = Packet;
    type Error = CodecError;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Packet>, CodecError> {
        if src.len() < 8 {
            return Ok(None);
        }
        let size = u32::from_le_bytes([src[0], src[1], src[2], src[3]]) as usize;
        let kind = u32::from_le_bytes([src[4], src[5], src[6], src[7]]);
        if !(8..=MAX_PACKET).contains(&size) || kind > 8 {
            return Err(CodecError::malformed(format!(
                "bad packet header size {size} type {kind}: {}",
                quote(&src[..src.len().min(16)])
            )));
        }
        if src.len() < size {
            src.reserve(size - src.len());
            return Ok(None);
        }
        let frame = src.split_to(size);
        let mut payload = &frame[..];
        payload.advance(8);
        packet::decode(kind, payload).map(Some)
    }
}

impl Encoder<Packet> for QtmCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Packet, dst: &mut BytesMut) -> Result<(), CodecError> {
        packet::encode(&item, dst);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::qtm::packet::{Component, DataFrame};
    use crate::transcript::from_hex;

    fn one(bytes: &[u8]) -> Result<Option<Packet>, CodecError> {
        QtmCodec.decode(&mut BytesMut::from(bytes))
    }

    #[test]
    fn spec_example_bytes() {
        let welcome = from_hex("23000000 01000000").unwrap();
        let mut w = welcome.clone();
        w.extend_from_slice(b"QTM RT Interface connected\0");
        assert_eq!(
            one(&w).unwrap(),
            Some(Packet::Command("QTM RT Interface connected".into()))
        );
        assert_eq!(
            one(&from_hex("09000000 06000000 01").unwrap()).unwrap(),
            Some(Packet::Event(1))
        );
        assert_eq!(
            one(&from_hex("08000000 04000000").unwrap()).unwrap(),
            Some(Packet::NoMoreData)
        );
        let mut e = from_hex("14000000 00000000").unwrap();
        e.extend_from_slice(b"Parse Error\0");
        assert_eq!(one(&e).unwrap(), Some(Packet::Error("Parse Error".into())));
        // The data example: frame 42, ts 1234567 us, 2 markers, the second missing.
        let d = from_hex(
            "64000000 03000000 87d6120000000000 2a000000 01000000
             28000000 01000000 02000000 0000 0000 0000c942 0000a2c1 00009643
             ffffffff ffffffff ffffffff",
        )
        .unwrap();
        let d = &d[..d.len()];
        let mut fixed = d.to_vec();
        // devices.md writes the size as "64" (decimal 64 = 0x40, the real length); fix it.
        fixed[0] = d.len() as u8;
        let Some(Packet::Data(f)) = one(&fixed).unwrap() else {
            panic!("not data")
        };
        assert_eq!((f.timestamp_us, f.frame_number), (1_234_567, 42));
        let m = f.markers_3d().unwrap();
        assert_eq!(m[0], [100.5, -20.25, 300.0]);
        assert!(m[1].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn round_trip_and_partial() {
        let f = Packet::Data(DataFrame {
            timestamp_us: -5,
            frame_number: 7,
            components: vec![
                Component::Markers3d {
                    drop_rate: 1,
                    out_of_sync_rate: 2,
                    markers: vec![[1.0, 2.0, 3.0]],
                },
                Component::Markers3dNoLabels {
                    drop_rate: 0,
                    out_of_sync_rate: 0,
                    markers: vec![([4.0, 5.0, 6.0], 9)],
                },
                Component::Other {
                    kind: 17,
                    payload: vec![1, 2, 3],
                },
            ],
        });
        let mut b = BytesMut::new();
        QtmCodec.encode(f.clone(), &mut b).unwrap();
        QtmCodec.encode(Packet::Xml("<x/>".into()), &mut b).unwrap();
        let mut part = BytesMut::from(&b[..10]);
        assert!(matches!(QtmCodec.decode(&mut part), Ok(None)));
        assert_eq!(QtmCodec.decode(&mut b).unwrap(), Some(f));
        assert_eq!(
            QtmCodec.decode(&mut b).unwrap(),
            Some(Packet::Xml("<x/>".into()))
        );
        assert!(b.is_empty());
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(one(b"\xff\xfe\x00garbage<<>>").is_err());
        assert!(one(&from_hex("04000000 01000000").unwrap()).is_err());
        assert!(one(&from_hex("09000000 63000000 00").unwrap()).is_err());
        // Component claiming more markers than it carries.
        let bad = from_hex("20000000 03000000 0000000000000000 01000000 01000000 10000000 01000000 05000000 00000000").unwrap();
        assert!(one(&bad).is_err());
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..3000 {
            let mut v = Vec::new();
            let n = s % 80;
            for i in 0..n {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                v.push(if i < 4 {
                    (n as u8).wrapping_sub((s % 3) as u8)
                } else if i < 8 {
                    (s % 10) as u8 * (i == 4) as u8
                } else {
                    s as u8
                });
            }
            let _ = one(&v);
            let _ = packet::decode_whole(&v);
        }
    }
}
