//! Image I/O for RGB-D datasets: 16-bit depth (PNG, or binary PGM with maxval > 255) scaled
//! to metres, 8-bit colour (JPEG/PNG, any channel layout made RGB), 8-bit label images, the
//! registration of a colour image to the depth camera's pixel grid, and atomic PNG writers.
//!
//! Depth files are strict on purpose: an 8-bit PNG or an RGB PNG where depth is expected is
//! almost always a wrong path (a colour image), and silently reading it as depth would give
//! a plausible-looking but meaningless reconstruction.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageFormat};
use rayon::prelude::*;

use crate::atomic_file::write_atomic;
use crate::camera::Intrinsics;
use crate::error::{DataError, Result};

/// A depth image in metres (0 = no measurement).
///
/// # Shapes
/// `depth` is row-major, `width * height` long.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Depth along the optical axis in metres; 0 where invalid.
    pub depth: Vec<f32>,
}

/// An 8-bit RGB image.
///
/// # Shapes
/// `pixels` is row-major, `width * height` long.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGB pixels.
    pub pixels: Vec<[u8; 3]>,
}

/// An 8-bit single-channel label image (class ids).
///
/// # Shapes
/// `labels` is row-major, `width * height` long.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// One label per pixel.
    pub labels: Vec<u8>,
}

/// Loads a 16-bit single-channel depth image (PNG or binary PGM) and converts it to metres:
/// `raw / units_per_metre` (1000 for millimetres, 5000 for TUM, 6553.5 for Replica); raw
/// values listed in `invalid` (and 0) become 0.
pub fn load_depth(path: impl AsRef<Path>, units_per_metre: f32, invalid: &[u16]) -> Result<DepthImage> {
    let path = path.as_ref();
    if !(units_per_metre.is_finite() && units_per_metre > 0.0) {
        return Err(DataError::InvalidArgument(format!(
            "depth scale {units_per_metre} units per metre is not positive"
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let (image, format) = decode(path, &bytes)?;
    let kind = format_name(format);
    let raw = match image {
        DynamicImage::ImageLuma16(buf) => buf,
        DynamicImage::ImageLuma8(_) => {
            return Err(DataError::image(path, format!("8-bit {kind}, expected 16-bit depth")))
        }
        other => {
            return Err(DataError::image(
                path,
                format!("{kind} with colour type {:?}, expected 16-bit single-channel depth", other.color()),
            ))
        }
    };
    let (width, height) = raw.dimensions();
    let mut values = raw.into_raw();
    if format == Some(ImageFormat::Pnm) {
        // The pnm decoder stretches samples to 0..=65535 when maxval is smaller; depth needs
        // the raw sensor units back, and the stretch is exactly invertible.
        if let Some(maxval) = pnm_maxval(&bytes) {
            if maxval > 255 && maxval < 65535 {
                let f = maxval as f32 / 65535.0;
                values.iter_mut().for_each(|v| *v = (*v as f32 * f).round() as u16);
            }
        }
    }
    let depth =
        values.iter().map(|&v| if v == 0 || invalid.contains(&v) { 0.0 } else { v as f32 / units_per_metre }).collect();
    Ok(DepthImage { width, height, depth })
}

/// Loads a colour image (JPEG, PNG, PPM; gray, RGB or RGBA, 8 or 16 bits) as 8-bit RGB.
pub fn load_color(path: impl AsRef<Path>) -> Result<ColorImage> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let (image, _) = decode(path, &bytes)?;
    let rgb = image.into_rgb8();
    let (width, height) = rgb.dimensions();
    let pixels = rgb.pixels().map(|p| p.0).collect();
    Ok(ColorImage { width, height, pixels })
}

/// Loads an 8-bit single-channel label image.
pub fn load_labels(path: impl AsRef<Path>) -> Result<LabelImage> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let (image, format) = decode(path, &bytes)?;
    match image {
        DynamicImage::ImageLuma8(buf) => {
            let (width, height) = buf.dimensions();
            Ok(LabelImage { width, height, labels: buf.into_raw() })
        }
        other => Err(DataError::image(
            path,
            format!(
                "{} with colour type {:?}, expected an 8-bit single-channel label image",
                format_name(format),
                other.color()
            ),
        )),
    }
}

/// Checks that an image read from `path` has the size of `expected`; the error names the
/// file and both sizes.
pub fn check_size(path: impl AsRef<Path>, width: u32, height: u32, expected: &Intrinsics) -> Result<()> {
    if width != expected.width || height != expected.height {
        return Err(DataError::image(
            path.as_ref(),
            format!(
                "image is {width}x{height}, but the camera intrinsics are for {}x{}",
                expected.width, expected.height
            ),
        ));
    }
    Ok(())
}

/// Resamples `color` onto the depth camera's pixel grid: each depth pixel's viewing ray is
/// projected with `color_intrinsics` (the colour camera, assumed to share the depth camera's
/// centre and orientation, as in registered datasets) and sampled bilinearly; without colour
/// intrinsics the colour image is assumed to cover the same field of view (pure scaling).
/// Depth pixels whose ray falls outside the colour image get black.
///
/// # Shapes
/// Returns `depth.width * depth.height` pixels, row-major.
pub fn register_color(color: &ColorImage, depth: &Intrinsics, color_intrinsics: Option<&Intrinsics>) -> Vec<[u8; 3]> {
    if color_intrinsics.is_none() && color.width == depth.width && color.height == depth.height {
        return color.pixels.clone();
    }
    let ck = match color_intrinsics {
        Some(k) => *k,
        None => depth.scaled(color.width, color.height),
    };
    let (cw, ch) = (color.width as usize, color.height as usize);
    let mut out = vec![[0u8; 3]; depth.pixel_count()];
    if cw == 0 || ch == 0 {
        return out;
    }
    out.par_chunks_mut(depth.width as usize).enumerate().for_each(|(v, row)| {
        let y = (v as f32 - depth.cy) / depth.fy;
        let vc = ck.fy * y + ck.cy;
        for (u, px) in row.iter_mut().enumerate() {
            let x = (u as f32 - depth.cx) / depth.fx;
            let uc = ck.fx * x + ck.cx;
            if uc < -0.5 || vc < -0.5 || uc > cw as f32 - 0.5 || vc > ch as f32 - 0.5 {
                continue;
            }
            // Bilinear between the four nearest pixel centres, clamped at the border.
            let (fu, fv) = (uc.clamp(0.0, (cw - 1) as f32), vc.clamp(0.0, (ch - 1) as f32));
            let (u0, v0) = (fu.floor() as usize, fv.floor() as usize);
            let (u1, v1) = ((u0 + 1).min(cw - 1), (v0 + 1).min(ch - 1));
            let (au, av) = (fu - u0 as f32, fv - v0 as f32);
            let at = |uu: usize, vv: usize| color.pixels[vv * cw + uu];
            let (p00, p10, p01, p11) = (at(u0, v0), at(u1, v0), at(u0, v1), at(u1, v1));
            for c in 0..3 {
                let top = p00[c] as f32 * (1.0 - au) + p10[c] as f32 * au;
                let bottom = p01[c] as f32 * (1.0 - au) + p11[c] as f32 * au;
                px[c] = (top * (1.0 - av) + bottom * av).round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    out
}

/// Writes depth in metres as a 16-bit PNG of `round(depth * units_per_metre)`, atomically.
/// Pixels that are not a positive finite depth, or whose value would not fit below 65535
/// (the invalid marker of 7-Scenes), are written as 0.
///
/// # Shapes
/// `depth` is row-major, `width * height` long.
pub fn write_depth_png(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    depth: &[f32],
    units_per_metre: f32,
) -> Result<()> {
    let path = path.as_ref();
    check_len(path, width, height, depth.len())?;
    let raw: Vec<u16> = depth
        .iter()
        .map(|&d| {
            let v = (d * units_per_metre).round();
            if d > 0.0 && v.is_finite() && v < 65535.0 {
                v as u16
            } else {
                0
            }
        })
        .collect();
    let buf = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(width, height, raw)
        .ok_or_else(|| DataError::image(path, "depth buffer does not match its size"))?;
    write_png(path, DynamicImage::ImageLuma16(buf))
}

/// Writes an 8-bit RGB PNG, atomically.
///
/// # Shapes
/// `pixels` is row-major, `width * height` long.
pub fn write_color_png(path: impl AsRef<Path>, width: u32, height: u32, pixels: &[[u8; 3]]) -> Result<()> {
    let path = path.as_ref();
    check_len(path, width, height, pixels.len())?;
    let raw: Vec<u8> = pixels.iter().flatten().copied().collect();
    let buf = image::RgbImage::from_raw(width, height, raw)
        .ok_or_else(|| DataError::image(path, "colour buffer does not match its size"))?;
    write_png(path, DynamicImage::ImageRgb8(buf))
}

/// Writes an 8-bit single-channel label PNG, atomically.
///
/// # Shapes
/// `labels` is row-major, `width * height` long.
pub fn write_label_png(path: impl AsRef<Path>, width: u32, height: u32, labels: &[u8]) -> Result<()> {
    let path = path.as_ref();
    check_len(path, width, height, labels.len())?;
    let buf = image::GrayImage::from_raw(width, height, labels.to_vec())
        .ok_or_else(|| DataError::image(path, "label buffer does not match its size"))?;
    write_png(path, DynamicImage::ImageLuma8(buf))
}

fn check_len(path: &Path, width: u32, height: u32, len: usize) -> Result<()> {
    if width as usize * height as usize != len {
        return Err(DataError::InvalidArgument(format!(
            "{}: buffer of {len} pixels cannot be a {width}x{height} image",
            path.display()
        )));
    }
    Ok(())
}

fn write_png(path: &Path, image: DynamicImage) -> Result<()> {
    let mut bytes = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
        .map_err(|e| DataError::image(path, format!("cannot encode PNG: {e}")))?;
    write_atomic(path, &bytes)
}

/// Decodes an image by its content (not its extension), naming the file on failure.
fn decode(path: &Path, bytes: &[u8]) -> Result<(DynamicImage, Option<ImageFormat>)> {
    let reader =
        image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| DataError::io(path, e))?;
    let format = reader.format();
    if format.is_none() {
        return Err(DataError::image(path, "not an image in a supported format (PNG, JPEG, PNM)"));
    }
    let image =
        reader.decode().map_err(|e| DataError::image(path, format!("cannot decode {}: {e}", format_name(format))))?;
    Ok((image, format))
}

fn format_name(format: Option<ImageFormat>) -> &'static str {
    match format {
        Some(ImageFormat::Png) => "PNG",
        Some(ImageFormat::Jpeg) => "JPEG",
        Some(ImageFormat::Pnm) => "PGM/PPM",
        _ => "image",
    }
}

/// The maxval of a binary PNM header (`P5 w h maxval`, `#` comments allowed).
fn pnm_maxval(bytes: &[u8]) -> Option<u32> {
    let mut tokens = Vec::with_capacity(4);
    let mut i = 0;
    while tokens.len() < 4 && i < bytes.len() {
        match bytes[i] {
            b'#' => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            c if c.is_ascii_whitespace() => i += 1,
            _ => {
                let start = i;
                while i < bytes.len() && !bytes[i].is_ascii_whitespace() && bytes[i] != b'#' {
                    i += 1;
                }
                tokens.push(&bytes[start..i]);
            }
        }
    }
    if tokens.len() < 4 || tokens[0] != b"P5" {
        return None;
    }
    std::str::from_utf8(tokens[3]).ok()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_png_round_trip_with_invalid_values() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("d.png");
        let depth = vec![0.0, 1.0, 2.5, -1.0, f32::NAN, 70.0];
        write_depth_png(&path, 3, 2, &depth, 1000.0).expect("write");
        let back = load_depth(&path, 1000.0, &[65535, 2500]).expect("read");
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.depth, vec![0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn eight_bit_png_is_not_depth() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("d.png");
        write_label_png(&path, 2, 2, &[1, 2, 3, 4]).expect("write");
        let e = load_depth(&path, 1000.0, &[]).expect_err("8-bit");
        assert!(e.to_string().contains("8-bit PNG, expected 16-bit depth"), "{e}");
        assert!(e.to_string().contains("d.png"), "{e}");
        let l = load_labels(&path).expect("labels");
        assert_eq!(l.labels, vec![1, 2, 3, 4]);
        let c = load_color(&path).expect("gray as colour");
        assert_eq!(c.pixels[3], [4, 4, 4]);
    }

    #[test]
    fn pgm_with_small_maxval_keeps_raw_units() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("d.pgm");
        let mut bytes = b"P5\n# comment\n2 1\n4095\n".to_vec();
        for v in [1234u16, 4095] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        std::fs::write(&path, bytes).expect("write");
        let d = load_depth(&path, 1000.0, &[]).expect("read");
        assert_eq!(d.depth, vec![1.234, 4.095]);
    }

    #[test]
    fn corrupt_bytes_are_an_image_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("bad.png");
        let mut bytes = Vec::new();
        DynamicImage::ImageLuma16(image::ImageBuffer::from_raw(4, 4, vec![7u16; 16]).expect("buf"))
            .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
            .expect("encode");
        bytes.truncate(bytes.len() / 2);
        std::fs::write(&path, &bytes).expect("write");
        let e = load_depth(&path, 1000.0, &[]).expect_err("truncated");
        assert!(e.to_string().contains("bad.png"), "{e}");
        std::fs::write(&path, b"hello").expect("write");
        let e = load_color(&path).expect_err("not an image");
        assert!(e.to_string().contains("not an image"), "{e}");
    }

    #[test]
    fn registration_by_scaling_matches_reference() {
        // A 4x2 colour image seen by a 2x1 depth camera with the same field of view: each
        // depth pixel centre lies between two colour pixel centres in x and in y.
        let color = ColorImage {
            width: 4,
            height: 2,
            pixels: vec![[0; 3], [10; 3], [20; 3], [30; 3], [40; 3], [50; 3], [60; 3], [70; 3]],
        };
        let k = Intrinsics::new(2, 1, 1.0, 1.0, 0.5, 0.0).expect("valid");
        let out = register_color(&color, &k, None);
        // Depth pixel u=0 maps to colour x=0.5, y=0.5: mean of 0,10,40,50 = 25.
        assert_eq!(out, vec![[25; 3], [45; 3]]);
    }

    #[test]
    fn registration_through_intrinsics_crops_the_wider_colour_view() {
        let (w, h) = (40u32, 30u32);
        let pixels = (0..h).flat_map(|v| (0..w).map(move |u| [u as u8, v as u8, 0])).collect();
        let color = ColorImage { width: w, height: h, pixels };
        let ck = Intrinsics::new(w, h, 20.0, 20.0, 19.5, 14.5).expect("valid");
        // A depth camera with a narrower view (longer focal length) at half resolution.
        let dk = Intrinsics::new(10, 8, 20.0, 20.0, 4.5, 3.5).expect("valid");
        let out = register_color(&color, &dk, Some(&ck));
        for v in 0..8 {
            for u in 0..10 {
                let uc = (u as f32 - 4.5) + 19.5;
                let vc = (v as f32 - 3.5) + 14.5;
                assert_eq!(out[v * 10 + u], [uc.round() as u8, vc.round() as u8, 0]);
            }
        }
    }
}
