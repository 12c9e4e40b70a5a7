//! `bag:FILE`: a librealsense recording (a ROS 1 bag, v2.0, chunks lz4- or un-compressed, read
//! with the `rosbag` crate) as a dataset: depth (`mono16` / `16UC1` scaled by the recorded depth
//! units), colour (`rgb8`, `bgr8`, `rgba8`, `bgra8`) resampled to the depth grid through both
//! cameras' intrinsics, and the depth camera's intrinsics from its `camera_info`.
//!
//! librealsense's topic layout: `/device_0/sensor_S/Depth_0/image/data` (images),
//! `.../Depth_0/info/camera_info` (intrinsics), `.../Depth_0/info` (frame rate),
//! `/device_0/sensor_S/option/Depth Units/value` (metres per depth unit); colour the same under
//! `Color_0`. The first depth stream is read; each depth frame takes the colour frame nearest
//! in time.
//!
//! Opening reads the bag's index and every chunk once (to list the frames and read the camera
//! description); a frame is decoded when asked for. A truncated bag (its index lost) or one that
//! is not a bag is refused at open with what is wrong; a damaged chunk ends the frame list
//! before it, with a note.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use rosbag::{ChunkRecord, IndexRecord, MessageRecord, RosBag};

use crate::camera::Intrinsics;
use crate::depth_image::{register_color, ColorImage};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::ros_messages::{decode_f32, CameraInfo, Image};

/// The version line every ROS 1 bag v2.0 starts with.
const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

/// Where one message lies: the chunk's position in the file, and which message of its
/// connection it is within the chunk.
#[derive(Debug, Clone, Copy)]
struct MessageRef {
    chunk_pos: u64,
    conn: u32,
    nth: usize,
}

/// One frame: its depth image, the colour image nearest in time, the depth image's stamp.
#[derive(Debug, Clone, Copy)]
struct FrameEntry {
    depth: MessageRef,
    color: Option<MessageRef>,
    stamp: f64,
}

/// A RealSense `.bag` recording read as a dataset.
pub struct RealSenseBag {
    path: PathBuf,
    bag: RosBag,
    intrinsics: Intrinsics,
    color_intrinsics: Option<Intrinsics>,
    depth_unit_m: f32,
    frame_rate: f64,
    frames: Vec<FrameEntry>,
    notes: Vec<String>,
}

impl std::fmt::Debug for RealSenseBag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RealSenseBag").field("path", &self.path).field("frames", &self.frames.len()).finish()
    }
}

/// The topics of one librealsense stream (`/device_0/sensor_0/Depth_0`).
struct StreamTopics {
    image: String,
    camera_info: String,
    info: String,
    depth_units: String,
}

impl StreamTopics {
    /// The stream whose image topic is `image` (ending in `/image/data`).
    fn of(image: &str) -> Option<Self> {
        let stream = image.strip_suffix("/image/data")?;
        let sensor = &stream[..stream.rfind('/')?];
        Some(Self {
            image: image.to_owned(),
            camera_info: format!("{stream}/info/camera_info"),
            info: format!("{stream}/info"),
            depth_units: format!("{sensor}/option/Depth Units/value"),
        })
    }
}

/// What one pass over the chunks gathers.
#[derive(Default)]
struct Scan {
    depth: Vec<(MessageRef, f64)>,
    color: Vec<(MessageRef, f64)>,
    depth_info: Option<CameraInfo>,
    color_info: Option<CameraInfo>,
    depth_units: Option<f32>,
    fps: Option<u32>,
    damaged: Option<String>,
}

impl RealSenseBag {
    /// Opens `path`, lists its frames and reads the depth camera's description.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let bad = |message: String| DataError::dataset(&path, message);
        if !path.is_file() {
            return Err(bad(if path.exists() {
                "not a file; expected a RealSense .bag recording".into()
            } else {
                "file does not exist".into()
            }));
        }
        check_header(&path)?;
        let bag = RosBag::new(&path).map_err(|e| DataError::io(&path, e))?;

        let mut topics: HashMap<u32, String> = HashMap::new();
        let mut chunks = Vec::new();
        for record in bag.index_records() {
            let record = record.map_err(|e| {
                bad(format!(
                    "the index at the end of the file is cut short or damaged ({}): a truncated copy?",
                    rosbag_error(&e)
                ))
            })?;
            match record {
                IndexRecord::Connection(c) => {
                    topics.insert(c.id, c.topic.to_owned());
                }
                IndexRecord::ChunkInfo(info) => chunks.push(info.chunk_pos),
                IndexRecord::IndexData(_) => {}
            }
        }
        chunks.sort_unstable();
        let first_image = |kind: &str| {
            let mut found: Vec<(u32, &String)> = topics
                .iter()
                .filter(|(_, t)| t.ends_with("/image/data") && t.contains(&format!("/{kind}_")))
                .map(|(id, t)| (*id, t))
                .collect();
            found.sort();
            found.first().and_then(|(id, t)| StreamTopics::of(t).map(|s| (*id, s)))
        };
        let Some((depth_conn, depth_topics)) = first_image("Depth") else {
            let mut names: Vec<&String> = topics.values().collect();
            names.sort();
            return Err(bad(format!(
                "no depth stream (no `/device_*/sensor_*/Depth_*/image/data` topic among {} topics{})",
                names.len(),
                names.first().map(|t| format!(", e.g. `{t}`")).unwrap_or_default()
            )));
        };
        let color = first_image("Color");
        let conn_of = |topic: &str| topics.iter().find(|(_, t)| t.as_str() == topic).map(|(id, _)| *id);
        let depth_info_conn = conn_of(&depth_topics.camera_info);
        let color_info_conn = color.as_ref().and_then(|(_, c)| conn_of(&c.camera_info));
        let units_conn = conn_of(&depth_topics.depth_units);
        let stream_info_conn = conn_of(&depth_topics.info);
        let color_conn = color.as_ref().map(|(id, _)| *id);

        let mut scan = Scan::default();
        for &pos in &chunks {
            let mut records = bag.chunk_records();
            let chunk = match records.seek(pos).map(|_| records.next()) {
                Ok(Some(Ok(ChunkRecord::Chunk(chunk)))) => chunk,
                Ok(Some(Err(e))) | Err(e) => {
                    scan.damaged = Some(format!("chunk at byte {pos}: {}", rosbag_error(&e)));
                    break;
                }
                Ok(_) => {
                    scan.damaged = Some(format!("no chunk at byte {pos}, where the index says"));
                    break;
                }
            };
            let mut nth: HashMap<u32, usize> = HashMap::new();
            for message in chunk.messages() {
                let message = match message {
                    Ok(MessageRecord::MessageData(m)) => m,
                    Ok(MessageRecord::Connection(_)) => continue,
                    Err(e) => {
                        scan.damaged = Some(format!("chunk at byte {pos}: {}", rosbag_error(&e)));
                        break;
                    }
                };
                let counter = nth.entry(message.conn_id).or_default();
                let at = MessageRef { chunk_pos: pos, conn: message.conn_id, nth: *counter };
                *counter += 1;
                let c = Some(message.conn_id);
                let context = |what: &str, e: &dyn std::fmt::Display| bad(format!("{what} (chunk at byte {pos}): {e}"));
                if c == Some(depth_conn) || c == color_conn {
                    let image = Image::decode(message.data).map_err(|e| context("an image", &e))?;
                    let list = if c == Some(depth_conn) { &mut scan.depth } else { &mut scan.color };
                    list.push((at, image.stamp));
                } else if c == depth_info_conn && scan.depth_info.is_none() {
                    scan.depth_info = Some(CameraInfo::decode(message.data).map_err(|e| context("depth", &e))?);
                } else if c == color_info_conn && scan.color_info.is_none() {
                    scan.color_info = Some(CameraInfo::decode(message.data).map_err(|e| context("colour", &e))?);
                } else if c == units_conn && scan.depth_units.is_none() {
                    scan.depth_units = Some(decode_f32(message.data).map_err(|e| context("depth units", &e))?);
                } else if c == stream_info_conn && scan.fps.is_none() {
                    // realsense_msgs/StreamInfo: uint32 fps, string encoding, bool is_recommended.
                    scan.fps = message.data.get(..4).and_then(|b| b.try_into().ok()).map(u32::from_le_bytes);
                }
            }
            if scan.damaged.is_some() {
                break;
            }
        }
        Self::assemble(path, bag, depth_topics, scan)
    }

    fn assemble(path: PathBuf, bag: RosBag, depth_topics: StreamTopics, scan: Scan) -> Result<Self> {
        let bad = |message: String| DataError::dataset(&path, message);
        let mut notes = Vec::new();
        if let Some(why) = &scan.damaged {
            notes.push(format!("damaged from the {why}: the frames after it are left out"));
        }
        if scan.depth.is_empty() {
            return Err(bad(format!(
                "no depth frame on `{}`{}",
                depth_topics.image,
                scan.damaged.map(|d| format!(" before the damaged {d}")).unwrap_or_default()
            )));
        }
        let Some(info) = scan.depth_info else {
            return Err(bad(format!("no depth intrinsics (`{}` holds no message)", depth_topics.camera_info)));
        };
        let to_intrinsics = |info: &CameraInfo| {
            Intrinsics::new(
                info.width,
                info.height,
                info.k[0] as f32,
                info.k[4] as f32,
                info.k[2] as f32,
                info.k[5] as f32,
            )
        };
        let intrinsics = to_intrinsics(&info).map_err(|e| bad(format!("depth `camera_info`: {e}")))?;
        if info.distortion.iter().any(|d| d.abs() > 1e-6) {
            notes.push(format!("depth distortion ({}) not corrected", info.distortion_model));
        }
        let depth_unit_m = match scan.depth_units {
            Some(u) if u.is_finite() && u > 0.0 && u < 1.0 => u,
            Some(u) => return Err(bad(format!("depth units of {u} m are not a depth unit"))),
            None => {
                notes.push(format!("no `{}`: depth units taken as 1 mm", depth_topics.depth_units));
                0.001
            }
        };
        notes.insert(0, format!("depth units {depth_unit_m} m"));
        let color_intrinsics = scan.color_info.as_ref().and_then(|c| to_intrinsics(c).ok());
        if scan.color.is_empty() {
            notes.push("no colour frames: frames have no colour".into());
        } else {
            notes.push(format!(
                "{} colour frames for {} depth frames, each depth frame with the nearest in time; colour resampled through both intrinsics (no extrinsics)",
                scan.color.len(),
                scan.depth.len()
            ));
        }
        let frames = scan
            .depth
            .iter()
            .map(|&(depth, stamp)| {
                let color = scan
                    .color
                    .iter()
                    .min_by(|a, b| (a.1 - stamp).abs().total_cmp(&(b.1 - stamp).abs()))
                    .map(|(at, _)| *at);
                FrameEntry { depth, color, stamp }
            })
            .collect();
        let frame_rate = scan.fps.filter(|f| (1..=1000).contains(f)).map_or(30.0, f64::from);
        Ok(Self { path, bag, intrinsics, color_intrinsics, depth_unit_m, frame_rate, frames, notes })
    }

    /// Metres per depth unit (from the recording's `Depth Units` option).
    pub fn depth_unit_m(&self) -> f32 {
        self.depth_unit_m
    }

    /// Intrinsics of the colour camera, when the recording has them.
    pub fn color_intrinsics(&self) -> Option<Intrinsics> {
        self.color_intrinsics
    }

    /// Runs `f` on the bytes of the message at `at`.
    fn with_message<T>(&self, at: MessageRef, f: impl FnOnce(&[u8]) -> Result<T>) -> Result<T> {
        let bad = |message: String| DataError::dataset(&self.path, message);
        let mut records = self.bag.chunk_records();
        records.seek(at.chunk_pos).map_err(|e| bad(rosbag_error(&e)))?;
        let chunk = match records.next() {
            Some(Ok(ChunkRecord::Chunk(chunk))) => chunk,
            Some(Err(e)) => return Err(bad(format!("chunk at byte {}: {}", at.chunk_pos, rosbag_error(&e)))),
            _ => return Err(bad(format!("no chunk at byte {}", at.chunk_pos))),
        };
        let mut n = 0;
        for message in chunk.messages() {
            if let MessageRecord::MessageData(m) =
                message.map_err(|e| bad(format!("chunk at byte {}: {}", at.chunk_pos, rosbag_error(&e))))?
            {
                if m.conn_id == at.conn {
                    if n == at.nth {
                        return f(m.data);
                    }
                    n += 1;
                }
            }
        }
        Err(bad(format!(
            "message {} of connection {} missing from the chunk at byte {}",
            at.nth, at.conn, at.chunk_pos
        )))
    }

    fn depth(&self, index: usize, bytes: &[u8]) -> Result<Vec<f32>> {
        let bad = |message: String| DataError::dataset(&self.path, format!("depth frame {index}: {message}"));
        let image = Image::decode(bytes).map_err(|e| bad(e.to_string()))?;
        let k = &self.intrinsics;
        if (image.width, image.height) != (k.width, k.height) {
            return Err(bad(format!("{}x{}, the depth camera is {}x{}", image.width, image.height, k.width, k.height)));
        }
        if !matches!(image.encoding.as_str(), "mono16" | "16UC1" | "z16") {
            return Err(bad(format!("encoding `{}`; mono16 or 16UC1 expected", image.encoding)));
        }
        let (w, h) = (image.width as usize, image.height as usize);
        let mut depth = Vec::with_capacity(w * h);
        for y in 0..h {
            let row = image.row(y, w * 2).ok_or_else(|| bad(format!("row {y} is short")))?;
            depth.extend(row.chunks_exact(2).map(|p| {
                let raw =
                    if image.big_endian { u16::from_be_bytes([p[0], p[1]]) } else { u16::from_le_bytes([p[0], p[1]]) };
                raw as f32 * self.depth_unit_m
            }));
        }
        Ok(depth)
    }

    fn color(&self, index: usize, bytes: &[u8]) -> Result<Vec<[u8; 3]>> {
        let bad = |message: String| DataError::dataset(&self.path, format!("colour of frame {index}: {message}"));
        let image = Image::decode(bytes).map_err(|e| bad(e.to_string()))?;
        let (channels, bgr) = match image.encoding.as_str() {
            "rgb8" => (3, false),
            "bgr8" => (3, true),
            "rgba8" => (4, false),
            "bgra8" => (4, true),
            other => return Err(bad(format!("encoding `{other}`; rgb8, bgr8, rgba8 or bgra8 expected"))),
        };
        let (w, h) = (image.width as usize, image.height as usize);
        let mut pixels = Vec::with_capacity(w * h);
        for y in 0..h {
            let row = image.row(y, w * channels).ok_or_else(|| bad(format!("row {y} is short")))?;
            pixels
                .extend(row.chunks_exact(channels).map(|p| if bgr { [p[2], p[1], p[0]] } else { [p[0], p[1], p[2]] }));
        }
        let ck = self.color_intrinsics.filter(|c| (c.width, c.height) == (image.width, image.height));
        let image = ColorImage { width: image.width, height: image.height, pixels };
        Ok(register_color(&image, &self.intrinsics, ck.as_ref()))
    }
}

/// Checks the version line and that the header's index position lies inside the file (a bag
/// cut short loses its index, which sits at the end).
fn check_header(path: &Path) -> Result<()> {
    let bad = |message: String| DataError::dataset(path, message);
    let file_len = std::fs::metadata(path).map_err(|e| DataError::io(path, e))?.len();
    let mut head = Vec::new();
    std::fs::File::open(path).and_then(|f| f.take(4096).read_to_end(&mut head)).map_err(|e| DataError::io(path, e))?;
    let Some(rest) = head.strip_prefix(MAGIC) else {
        return Err(bad("not a ROS bag v2.0 (no `#ROSBAG V2.0` line): expected a RealSense .bag recording".into()));
    };
    let header_len = rest.get(..4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
    let Some(mut fields) = header_len.and_then(|n| rest.get(4..4 + n)) else {
        return Err(bad("the bag header is cut short".into()));
    };
    let mut index_pos = None;
    while fields.len() >= 4 {
        let n = u32::from_le_bytes([fields[0], fields[1], fields[2], fields[3]]) as usize;
        let Some(field) = fields.get(4..4 + n) else { break };
        if let Some(v) = field.strip_prefix(b"index_pos=") {
            index_pos = v.try_into().ok().map(u64::from_le_bytes);
        }
        fields = &fields[4 + n..];
    }
    match index_pos {
        None => Err(bad("the bag header has no index position".into())),
        Some(0) => {
            Err(bad("the recording was not closed (its bag has no index); `rosbag reindex` can repair it".into()))
        }
        Some(p) if p > file_len => Err(bad(format!(
            "truncated: the index should start at byte {p} but the file has {file_len} bytes (a copy cut short?)"
        ))),
        Some(p) if p < (MAGIC.len() + 4 + header_len.unwrap_or(0)) as u64 => {
            Err(bad(format!("damaged header: index position {p} lies inside the header")))
        }
        Some(_) => Ok(()),
    }
}

/// A rosbag error without the crate's `rosbag::Error:` prefix.
fn rosbag_error(e: &rosbag::Error) -> String {
    let text = e.to_string();
    text.strip_prefix("rosbag::Error: ").unwrap_or(&text).to_owned()
}

impl FrameSource for RealSenseBag {
    fn name(&self) -> String {
        format!("bag:{}", self.path.display())
    }

    fn len(&self) -> usize {
        self.frames.len()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_ground_truth(&self) -> bool {
        false
    }

    fn frame_rate(&self) -> f64 {
        self.frame_rate
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let entry = *super::frame_entry(&self.frames, index, self)?;
        let depth = self.with_message(entry.depth, |bytes| self.depth(index, bytes))?;
        let color = match entry.color {
            Some(at) => self.with_message(at, |bytes| self.color(index, bytes))?,
            None => vec![[0; 3]; depth.len()],
        };
        let t0 = self.frames.first().map_or(entry.stamp, |f| f.stamp);
        let frame = Frame {
            index,
            timestamp: entry.stamp - t0,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera: None,
            labels: None,
        };
        super::validated(frame, &self.path)
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }
}
