//! 8- and 16-bit grayscale images from PNG or TIFF bytes (the format from the magic
//! bytes), and PNG out for the twin. Errors say what is wrong with the file.

use std::io::Cursor;

use super::{GrayImage, PatternError};

/// Decode PNG or TIFF bytes into a grayscale image.
pub fn decode(bytes: &[u8]) -> Result<GrayImage, PatternError> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(bytes)
    } else if bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*") {
        decode_tiff(bytes)
    } else {
        Err(PatternError::Decode(
            "neither a PNG nor a TIFF file (unknown leading bytes)".into(),
        ))
    }
}

fn decode_png(bytes: &[u8]) -> Result<GrayImage, PatternError> {
    let bad = |e: png::DecodingError| PatternError::Decode(format!("invalid PNG: {e}"));
    let mut reader = png::Decoder::new(Cursor::new(bytes))
        .read_info()
        .map_err(bad)?;
    let (color, depth) = reader.output_color_type();
    if color != png::ColorType::Grayscale {
        return Err(PatternError::Decode(format!(
            "PNG of colour type {color:?}: 8- or 16-bit grayscale is needed"
        )));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| PatternError::Decode("PNG too large".into()))?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let (full_scale, pixels): (u16, Vec<u16>) = match depth {
        png::BitDepth::Eight => (
            255,
            (0..h)
                .flat_map(|r| buf[r * info.line_size..r * info.line_size + w].iter())
                .map(|&b| b as u16)
                .collect(),
        ),
        png::BitDepth::Sixteen => (
            u16::MAX,
            (0..h)
                .flat_map(|r| buf[r * info.line_size..r * info.line_size + 2 * w].chunks_exact(2))
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
                .collect(),
        ),
        d => {
            return Err(PatternError::Decode(format!(
                "PNG of {d:?} bits per pixel: 8 or 16 are needed"
            )));
        }
    };
    Ok(GrayImage {
        width: w,
        height: h,
        full_scale,
        pixels,
    })
}

fn decode_tiff(bytes: &[u8]) -> Result<GrayImage, PatternError> {
    use tiff::decoder::{Decoder, DecodingResult};
    let bad = |e: tiff::TiffError| PatternError::Decode(format!("invalid TIFF: {e}"));
    let mut dec = Decoder::new(Cursor::new(bytes)).map_err(bad)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    match dec.colortype().map_err(bad)? {
        tiff::ColorType::Gray(8 | 16) => {}
        other => {
            return Err(PatternError::Decode(format!(
                "TIFF of colour type {other:?}: 8- or 16-bit grayscale is needed"
            )));
        }
    }
    let (full_scale, pixels) = match dec.read_image().map_err(bad)? {
        DecodingResult::U8(v) => (255, v.into_iter().map(u16::from).collect()),
        DecodingResult::U16(v) => (u16::MAX, v),
        _ => {
            return Err(PatternError::Decode(
                "TIFF samples are not 8- or 16-bit unsigned integers".into(),
            ));
        }
    };
    let (w, h) = (w as usize, h as usize);
    if pixels.len() != w * h {
        return Err(PatternError::Decode(format!(
            "TIFF has {} samples for {w} x {h} pixels (one channel expected)",
            pixels.len()
        )));
    }
    Ok(GrayImage {
        width: w,
        height: h,
        full_scale,
        pixels,
    })
}

/// Encode as a grayscale PNG, 8-bit when the full scale is 255, else 16-bit.
pub fn encode_png(img: &GrayImage) -> Result<Vec<u8>, PatternError> {
    let mut out = Vec::new();
    let bad = |e: png::EncodingError| PatternError::Decode(format!("PNG encoding: {e}"));
    let (w, h) = (
        u32::try_from(img.width).map_err(|_| PatternError::Setup("image too wide".into()))?,
        u32::try_from(img.height).map_err(|_| PatternError::Setup("image too tall".into()))?,
    );
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Grayscale);
    let data: Vec<u8> = if img.full_scale == 255 {
        enc.set_depth(png::BitDepth::Eight);
        img.pixels.iter().map(|&p| p.min(255) as u8).collect()
    } else {
        enc.set_depth(png::BitDepth::Sixteen);
        img.pixels.iter().flat_map(|p| p.to_be_bytes()).collect()
    };
    let mut writer = enc.write_header().map_err(bad)?;
    writer.write_image_data(&data).map_err(bad)?;
    writer.finish().map_err(bad)?;
    Ok(out)
}
