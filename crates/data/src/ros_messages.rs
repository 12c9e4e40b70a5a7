//! The few ROS 1 messages a RealSense recording holds that semrecon reads, decoded from ROS 1
//! serialisation (little-endian; strings and variable arrays prefixed by a `u32` length; fixed
//! arrays without one): `sensor_msgs/Image`, `sensor_msgs/CameraInfo` and `std_msgs/Float32`.
//! Every read is bounds-checked: a short or damaged message is an error, never a panic.

/// A message that ends before its fields do, or holds impossible values.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message} message: {what}")]
pub struct MessageError {
    /// The message type.
    pub message: &'static str,
    /// What is wrong.
    pub what: String,
}

/// A bounds-checked reader over one serialised message.
struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    message: &'static str,
}

impl<'a> Reader<'a> {
    fn new(data: &'a [u8], message: &'static str) -> Self {
        Self { data, pos: 0, message }
    }

    fn error(&self, what: impl Into<String>) -> MessageError {
        MessageError { message: self.message, what: what.into() }
    }

    fn bytes(&mut self, n: usize, field: &str) -> Result<&'a [u8], MessageError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len()).ok_or_else(|| {
            self.error(format!(
                "ends inside `{field}` ({n} bytes needed at byte {}, {} in the message)",
                self.pos,
                self.data.len()
            ))
        })?;
        let out = &self.data[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], MessageError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(N, field)?);
        Ok(out)
    }

    fn u8(&mut self, field: &str) -> Result<u8, MessageError> {
        Ok(self.array::<1>(field)?[0])
    }

    fn u32(&mut self, field: &str) -> Result<u32, MessageError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    fn f32(&mut self, field: &str) -> Result<f32, MessageError> {
        Ok(f32::from_le_bytes(self.array(field)?))
    }

    fn f64(&mut self, field: &str) -> Result<f64, MessageError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    fn string(&mut self, field: &str) -> Result<String, MessageError> {
        let n = self.u32(field)? as usize;
        Ok(String::from_utf8_lossy(self.bytes(n, field)?).into_owned())
    }

    fn f64s(&mut self, n: usize, field: &str) -> Result<Vec<f64>, MessageError> {
        (0..n).map(|_| self.f64(field)).collect()
    }

    /// `std_msgs/Header`: seq, stamp (seconds, nanoseconds), frame_id; the stamp in seconds.
    fn header(&mut self) -> Result<f64, MessageError> {
        self.u32("header.seq")?;
        let secs = self.u32("header.stamp")?;
        let nsecs = self.u32("header.stamp")?;
        self.string("header.frame_id")?;
        Ok(secs as f64 + nsecs as f64 * 1e-9)
    }
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<'a> {
    /// Header stamp, seconds.
    pub stamp: f64,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`mono16`, `16UC1`, `rgb8`, `bgr8`, ...).
    pub encoding: String,
    /// Whether multi-byte pixels are big-endian.
    pub big_endian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixels, `step * height` bytes.
    pub data: &'a [u8],
}

impl<'a> Image<'a> {
    /// Decodes a serialised image, checking that the pixels fill `step * height` bytes.
    pub fn decode(bytes: &'a [u8]) -> Result<Self, MessageError> {
        let mut r = Reader::new(bytes, "sensor_msgs/Image");
        let stamp = r.header()?;
        let height = r.u32("height")?;
        let width = r.u32("width")?;
        let encoding = r.string("encoding")?;
        let big_endian = r.u8("is_bigendian")? != 0;
        let step = r.u32("step")?;
        let n = r.u32("data")? as usize;
        let data = r.bytes(n, "data")?;
        let needed = step as u64 * height as u64;
        if (n as u64) < needed {
            return Err(r.error(format!("{n} bytes of pixels for {height} rows of {step} bytes")));
        }
        Ok(Self { stamp, height, width, encoding, big_endian, step, data })
    }

    /// Row `y`'s first `len` bytes (within the checked data).
    pub fn row(&self, y: usize, len: usize) -> Option<&'a [u8]> {
        let start = y.checked_mul(self.step as usize)?;
        self.data.get(start..start.checked_add(len)?)
    }
}

/// `sensor_msgs/CameraInfo`: the parts that make a pinhole camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Distortion model name.
    pub distortion_model: String,
    /// Distortion coefficients.
    pub distortion: Vec<f64>,
    /// The 3x3 camera matrix, row-major: `fx 0 cx / 0 fy cy / 0 0 1`.
    pub k: [f64; 9],
}

impl CameraInfo {
    /// Decodes a serialised camera info (the rectification and projection that follow the
    /// camera matrix are not needed and not read).
    pub fn decode(bytes: &[u8]) -> Result<Self, MessageError> {
        let mut r = Reader::new(bytes, "sensor_msgs/CameraInfo");
        r.header()?;
        let height = r.u32("height")?;
        let width = r.u32("width")?;
        let distortion_model = r.string("distortion_model")?;
        let n = r.u32("D")? as usize;
        if n > 64 {
            return Err(r.error(format!("{n} distortion coefficients")));
        }
        let distortion = r.f64s(n, "D")?;
        let mut k = [0.0; 9];
        k.copy_from_slice(&r.f64s(9, "K")?);
        Ok(Self { height, width, distortion_model, distortion, k })
    }
}

/// `std_msgs/Float32`.
pub fn decode_f32(bytes: &[u8]) -> Result<f32, MessageError> {
    Reader::new(bytes, "std_msgs/Float32").f32("data")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(out: &mut Vec<u8>, secs: u32, nsecs: u32) {
        out.extend(7u32.to_le_bytes());
        out.extend(secs.to_le_bytes());
        out.extend(nsecs.to_le_bytes());
        out.extend(3u32.to_le_bytes());
        out.extend(b"cam");
    }

    fn image(width: u32, height: u32, step: u32, pixels: &[u8]) -> Vec<u8> {
        let mut m = Vec::new();
        header(&mut m, 12, 500_000_000);
        m.extend(height.to_le_bytes());
        m.extend(width.to_le_bytes());
        m.extend(6u32.to_le_bytes());
        m.extend(b"mono16");
        m.push(0);
        m.extend(step.to_le_bytes());
        m.extend((pixels.len() as u32).to_le_bytes());
        m.extend(pixels);
        m
    }

    #[test]
    fn an_image_decodes_and_every_truncation_is_an_error() {
        let pixels: Vec<u8> = (0..24).collect();
        let bytes = image(3, 4, 6, &pixels);
        let im = Image::decode(&bytes).expect("valid");
        assert_eq!((im.width, im.height, im.step, im.encoding.as_str()), (3, 4, 6, "mono16"));
        assert!((im.stamp - 12.5).abs() < 1e-9);
        assert_eq!(im.row(3, 6), Some(&pixels[18..24]));
        for cut in 0..bytes.len() {
            assert!(Image::decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let short = image(3, 4, 6, &pixels[..20]);
        let e = Image::decode(&short).expect_err("too few pixels");
        assert!(e.to_string().contains("20 bytes of pixels for 4 rows of 6 bytes"), "{e}");
    }

    #[test]
    fn camera_info_and_float_decode() {
        let mut m = Vec::new();
        header(&mut m, 1, 0);
        m.extend(480u32.to_le_bytes());
        m.extend(640u32.to_le_bytes());
        m.extend(11u32.to_le_bytes());
        m.extend(b"Brown Conra");
        m.extend(5u32.to_le_bytes());
        for d in [0.1f64, 0.0, 0.0, 0.0, 0.0] {
            m.extend(d.to_le_bytes());
        }
        for k in [600.0f64, 0.0, 320.0, 0.0, 601.0, 240.0, 0.0, 0.0, 1.0] {
            m.extend(k.to_le_bytes());
        }
        let info = CameraInfo::decode(&m).expect("valid");
        assert_eq!((info.width, info.height, info.distortion.len()), (640, 480, 5));
        assert_eq!(info.k[0], 600.0);
        assert!(CameraInfo::decode(&m[..m.len() - 1]).is_err());
        assert_eq!(decode_f32(&0.001f32.to_le_bytes()), Ok(0.001));
        assert!(decode_f32(&[0, 0]).is_err());
    }
}
