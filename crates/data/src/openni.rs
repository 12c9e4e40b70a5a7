//! OpenNI2 cameras and `.oni` recordings, through OpenNI2's C API (`OniCAPI.h`) loaded at run
//! time with `libloading`: nothing is linked, so building semrecon and running everything else
//! never needs OpenNI2; opening a camera without it says how to install it ([`INSTALL_HINT`]).
//!
//! [`OniCamera`] opens a device (the first one, or by URI) or a recording (OpenNI opens a file
//! path as a device; it is played on demand, a frame per read), starts depth and colour together (a recording's streams share one
//! playback timeline: reading one to its end first leaves nothing of the other), asks the device
//! to register depth to colour where it can, and reads frames as they arrive: depth in metres,
//! the latest colour frame resampled to the depth grid, timestamps in seconds. Mirrored streams
//! (OpenNI's default, and what old recordings hold) are flipped back, so that the scene keeps its
//! handedness.
//!
//! The library is `libOpenNI2.so.0` (Debian's `libopenni2-0`), or the file named by
//! [`LIBRARY_ENV`]. It is loaded and initialised once per process and never unloaded.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::path::Path;
use std::sync::OnceLock;

use crate::camera::Intrinsics;
use crate::depth_image::{register_color, ColorImage};
use crate::frame::Frame;

/// Environment variable naming the OpenNI2 library file to load instead of searching for it.
pub const LIBRARY_ENV: &str = "SEMRECON_OPENNI2_LIB";

/// How to get OpenNI2, for messages.
pub const INSTALL_HINT: &str = "install OpenNI2 (Debian/Ubuntu: `sudo apt-get install libopenni2-0`, which brings the \
     drivers for PrimeSense, Kinect v1 and Asus Xtion cameras and for .oni recordings), or set \
     SEMRECON_OPENNI2_LIB to the path of libOpenNI2.so";

/// Library names tried in order when [`LIBRARY_ENV`] is not set.
const LIBRARY_NAMES: &[&str] = &["libOpenNI2.so.0", "libOpenNI2.so", "libOpenNI2.dylib", "OpenNI2.dll"];

/// The C API version asked for (`ONI_API_VERSION` of OpenNI 2.2).
const API_VERSION: c_int = 2 * 1000 + 2;

/// How long [`OniCamera::next_frame`] waits for a live device before taking it as gone.
pub const DEVICE_TIMEOUT_MS: c_int = 3000;

/// Everything that can go wrong with OpenNI2.
#[derive(Debug, Clone, thiserror::Error)]
pub enum OpenNiError {
    /// The library is not installed (or not where [`LIBRARY_ENV`] says).
    #[error("OpenNI2 is not available ({why}); {INSTALL_HINT}")]
    Missing {
        /// What the loader said.
        why: String,
    },
    /// A library was found but cannot be used: a missing function, the wrong version, a
    /// failed initialisation.
    #[error("OpenNI2 library {library} cannot be used: {why}")]
    Unusable {
        /// The file loaded.
        library: String,
        /// What is wrong with it.
        why: String,
    },
    /// A device or recording that cannot be opened or read.
    #[error("{name}: {message}")]
    Device {
        /// The device URI or recording path.
        name: String,
        /// What went wrong.
        message: String,
    },
}

impl OpenNiError {
    fn device(name: &str, message: impl Into<String>) -> Self {
        Self::Device { name: name.to_owned(), message: message.into() }
    }
}

// ---- the C API's types (OniCTypes.h, OniCEnums.h, OniCProperties.h) ----

type OniStatus = c_int;
type DeviceHandle = *mut c_void;
type StreamHandle = *mut c_void;

const STATUS_OK: OniStatus = 0;
const STATUS_TIME_OUT: OniStatus = 102;
const SENSOR_COLOR: c_int = 2;
const SENSOR_DEPTH: c_int = 3;
const PIXEL_DEPTH_1_MM: c_int = 100;
const PIXEL_DEPTH_100_UM: c_int = 101;
const PIXEL_RGB888: c_int = 200;
const DEVICE_PROPERTY_IMAGE_REGISTRATION: c_int = 5;
const DEVICE_PROPERTY_PLAYBACK_SPEED: c_int = 100;
const DEVICE_PROPERTY_PLAYBACK_REPEAT_ENABLED: c_int = 101;
const STREAM_PROPERTY_HORIZONTAL_FOV: c_int = 1;
const STREAM_PROPERTY_VERTICAL_FOV: c_int = 2;
const STREAM_PROPERTY_VIDEO_MODE: c_int = 3;
const STREAM_PROPERTY_MIRRORING: c_int = 7;
const STREAM_PROPERTY_NUMBER_OF_FRAMES: c_int = 8;
const IMAGE_REGISTRATION_DEPTH_TO_COLOR: c_int = 1;
const MAX_STR: usize = 256;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
struct OniVersion {
    major: c_int,
    minor: c_int,
    maintenance: c_int,
    build: c_int,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct VideoMode {
    pixel_format: c_int,
    width: c_int,
    height: c_int,
    fps: c_int,
}

#[repr(C)]
struct DeviceInfoRaw {
    uri: [c_char; MAX_STR],
    vendor: [c_char; MAX_STR],
    name: [c_char; MAX_STR],
    usb_vendor_id: u16,
    usb_product_id: u16,
}

#[repr(C)]
struct OniFrame {
    data_size: c_int,
    data: *mut c_void,
    sensor_type: c_int,
    timestamp: u64,
    frame_index: c_int,
    width: c_int,
    height: c_int,
    video_mode: VideoMode,
    cropping_enabled: c_int,
    crop_origin_x: c_int,
    crop_origin_y: c_int,
    stride: c_int,
}

/// The functions of the C API semrecon uses, resolved from the loaded library.
struct Api {
    version: OniVersion,
    get_extended_error: unsafe extern "C" fn() -> *const c_char,
    get_device_list: unsafe extern "C" fn(*mut *mut DeviceInfoRaw, *mut c_int) -> OniStatus,
    release_device_list: unsafe extern "C" fn(*mut DeviceInfoRaw) -> OniStatus,
    device_open: unsafe extern "C" fn(*const c_char, *mut DeviceHandle) -> OniStatus,
    device_close: unsafe extern "C" fn(DeviceHandle) -> OniStatus,
    device_get_sensor_info: unsafe extern "C" fn(DeviceHandle, c_int) -> *const c_void,
    device_create_stream: unsafe extern "C" fn(DeviceHandle, c_int, *mut StreamHandle) -> OniStatus,
    device_set_property: unsafe extern "C" fn(DeviceHandle, c_int, *const c_void, c_int) -> OniStatus,
    device_registration_supported: unsafe extern "C" fn(DeviceHandle, c_int) -> c_int,
    stream_start: unsafe extern "C" fn(StreamHandle) -> OniStatus,
    stream_stop: unsafe extern "C" fn(StreamHandle),
    stream_read_frame: unsafe extern "C" fn(StreamHandle, *mut *mut OniFrame) -> OniStatus,
    stream_set_property: unsafe extern "C" fn(StreamHandle, c_int, *const c_void, c_int) -> OniStatus,
    stream_get_property: unsafe extern "C" fn(StreamHandle, c_int, *mut c_void, *mut c_int) -> OniStatus,
    wait_for_any_stream: unsafe extern "C" fn(*mut StreamHandle, c_int, *mut c_int, c_int) -> OniStatus,
    frame_release: unsafe extern "C" fn(*mut OniFrame),
    /// Keeps the functions above valid; never dropped (the process-wide instance is static).
    _library: libloading::Library,
}

static API: OnceLock<Result<Api, OpenNiError>> = OnceLock::new();

/// Held while a device is opened, set up or closed: OpenNI2's device list and driver state are
/// not safe to change from two threads at once (two recordings opened together crash it).
static DEVICE_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn device_lock() -> std::sync::MutexGuard<'static, ()> {
    DEVICE_LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Loads and initialises OpenNI2 (once per process).
fn api() -> Result<&'static Api, OpenNiError> {
    API.get_or_init(load).as_ref().map_err(Clone::clone)
}

/// Whether OpenNI2 can be loaded here, and if not, why (the message says how to install it).
pub fn availability() -> Result<String, OpenNiError> {
    let api = api()?;
    let v = api.version;
    Ok(format!("OpenNI {}.{}.{}.{}", v.major, v.minor, v.maintenance, v.build))
}

fn load() -> Result<Api, OpenNiError> {
    let candidates: Vec<String> = match std::env::var_os(LIBRARY_ENV) {
        Some(path) => vec![path.to_string_lossy().into_owned()],
        None => LIBRARY_NAMES.iter().map(|s| s.to_string()).collect(),
    };
    let mut why = Vec::new();
    for name in &candidates {
        // SAFETY: loading OpenNI2 runs its initialisers, which only set up its own state.
        match unsafe { libloading::Library::new(name) } {
            Ok(library) => return resolve(library, name),
            Err(e) => why.push(e.to_string()),
        }
    }
    Err(OpenNiError::Missing { why: why.join("; ") })
}

/// Resolves the functions of `library` and initialises it.
fn resolve(library: libloading::Library, name: &str) -> Result<Api, OpenNiError> {
    let unusable = |why: String| OpenNiError::Unusable { library: name.to_owned(), why };
    macro_rules! symbol {
        ($name:literal) => {
            // SAFETY: the type written at each use is the function's C signature in OniCAPI.h.
            *unsafe { library.get(concat!($name, "\0").as_bytes()) }
                .map_err(|e| unusable(format!("no function {} ({e}); is it OpenNI 2?", $name)))?
        };
    }
    let initialize: unsafe extern "C" fn(c_int) -> OniStatus = symbol!("oniInitialize");
    let get_version: unsafe extern "C" fn() -> OniVersion = symbol!("oniGetVersion");
    let get_extended_error: unsafe extern "C" fn() -> *const c_char = symbol!("oniGetExtendedError");
    // SAFETY: plain C calls without arguments that point anywhere.
    let version = unsafe { get_version() };
    if version.major != 2 {
        return Err(unusable(format!(
            "version {}.{}.{} found, OpenNI 2.x needed",
            version.major, version.minor, version.maintenance
        )));
    }
    // SAFETY: as above.
    let status = unsafe { initialize(API_VERSION) };
    if status != STATUS_OK {
        // SAFETY: OpenNI returns a NUL-terminated string it owns (or null).
        let detail = unsafe { c_string(get_extended_error()) };
        return Err(unusable(format!("oniInitialize failed (status {status}): {detail}")));
    }
    Ok(Api {
        version,
        get_extended_error,
        get_device_list: symbol!("oniGetDeviceList"),
        release_device_list: symbol!("oniReleaseDeviceList"),
        device_open: symbol!("oniDeviceOpen"),
        device_close: symbol!("oniDeviceClose"),
        device_get_sensor_info: symbol!("oniDeviceGetSensorInfo"),
        device_create_stream: symbol!("oniDeviceCreateStream"),
        device_set_property: symbol!("oniDeviceSetProperty"),
        device_registration_supported: symbol!("oniDeviceIsImageRegistrationModeSupported"),
        stream_start: symbol!("oniStreamStart"),
        stream_stop: symbol!("oniStreamStop"),
        stream_read_frame: symbol!("oniStreamReadFrame"),
        stream_set_property: symbol!("oniStreamSetProperty"),
        stream_get_property: symbol!("oniStreamGetProperty"),
        wait_for_any_stream: symbol!("oniWaitForAnyStream"),
        frame_release: symbol!("oniFrameRelease"),
        _library: library,
    })
}

/// A C string owned by OpenNI, copied (empty for null).
///
/// # Safety
/// `p` is null or points at a NUL-terminated string.
unsafe fn c_string(p: *const c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: the caller's promise.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().trim().to_owned()
    }
}

impl Api {
    /// OpenNI's explanation of the last failure, or `fallback`.
    fn last_error(&self, fallback: &str) -> String {
        // SAFETY: OpenNI returns a NUL-terminated string it owns (or null).
        let detail = unsafe { c_string((self.get_extended_error)()) };
        if detail.is_empty() {
            fallback.to_owned()
        } else {
            detail
        }
    }

    fn stream_int(&self, stream: StreamHandle, property: c_int) -> Option<c_int> {
        let mut value: c_int = 0;
        let mut size = std::mem::size_of::<c_int>() as c_int;
        // SAFETY: `value` has room for the int the property holds.
        let status = unsafe { (self.stream_get_property)(stream, property, (&raw mut value).cast(), &mut size) };
        (status == STATUS_OK).then_some(value)
    }

    fn stream_float(&self, stream: StreamHandle, property: c_int) -> Option<f32> {
        let mut value: f32 = 0.0;
        let mut size = std::mem::size_of::<f32>() as c_int;
        // SAFETY: `value` has room for the float the property holds.
        let status = unsafe { (self.stream_get_property)(stream, property, (&raw mut value).cast(), &mut size) };
        (status == STATUS_OK && value.is_finite()).then_some(value)
    }

    fn video_mode(&self, stream: StreamHandle) -> Option<VideoMode> {
        let mut mode = VideoMode::default();
        let mut size = std::mem::size_of::<VideoMode>() as c_int;
        // SAFETY: `mode` is the OniVideoMode the property holds.
        let status = unsafe {
            (self.stream_get_property)(stream, STREAM_PROPERTY_VIDEO_MODE, (&raw mut mode).cast(), &mut size)
        };
        (status == STATUS_OK).then_some(mode)
    }

    fn set_video_mode(&self, stream: StreamHandle, mode: VideoMode) -> bool {
        let size = std::mem::size_of::<VideoMode>() as c_int;
        // SAFETY: `mode` is an OniVideoMode.
        let status =
            unsafe { (self.stream_set_property)(stream, STREAM_PROPERTY_VIDEO_MODE, (&raw const mode).cast(), size) };
        status == STATUS_OK
    }
}

/// One OpenNI device as listed by the library.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// URI to open it with.
    pub uri: String,
    /// Vendor name.
    pub vendor: String,
    /// Device name.
    pub name: String,
}

/// The devices OpenNI2 sees (cameras plugged in; recordings are not listed).
pub fn devices() -> Result<Vec<DeviceInfo>, OpenNiError> {
    let api = api()?;
    let _serial = device_lock();
    let mut list: *mut DeviceInfoRaw = std::ptr::null_mut();
    let mut count: c_int = 0;
    // SAFETY: OpenNI fills `list` with `count` entries it owns until released below.
    let status = unsafe { (api.get_device_list)(&mut list, &mut count) };
    if status != STATUS_OK {
        return Err(OpenNiError::device("OpenNI2", api.last_error("cannot list the devices")));
    }
    let mut out = Vec::new();
    if !list.is_null() {
        for i in 0..count.max(0) as usize {
            // SAFETY: `i < count`, the entries OpenNI returned; the strings are NUL-terminated
            // within their 256 bytes.
            let info = unsafe { &*list.add(i) };
            let text = |s: &[c_char; MAX_STR]| unsafe { c_string(s.as_ptr()) };
            out.push(DeviceInfo { uri: text(&info.uri), vendor: text(&info.vendor), name: text(&info.name) });
        }
        // SAFETY: the list OpenNI returned, released once.
        unsafe { (api.release_device_list)(list) };
    }
    Ok(out)
}

/// An open OpenNI device or recording with its depth (and, where it has one, colour) stream
/// started.
pub struct OniCamera {
    api: &'static Api,
    name: String,
    device: DeviceHandle,
    /// Depth first, then colour when there is one.
    streams: Vec<StreamHandle>,
    depth_mode: VideoMode,
    color_mode: Option<VideoMode>,
    depth_mirrored: bool,
    color_mirrored: bool,
    registered: bool,
    intrinsics: Intrinsics,
    /// Frames in a recording (depth stream).
    recorded_frames: Option<usize>,
    /// Depth frames read so far.
    depth_read: usize,
    /// The latest colour frame, on the depth grid.
    latest_color: Option<Vec<[u8; 3]>>,
    first_timestamp_us: Option<u64>,
    notes: Vec<String>,
}

// SAFETY: the handles are only used through `&mut self` (one thread at a time); OpenNI's
// devices and streams are not tied to the thread that opened them.
unsafe impl Send for OniCamera {}

impl std::fmt::Debug for OniCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OniCamera").field("name", &self.name).field("intrinsics", &self.intrinsics).finish()
    }
}

impl OniCamera {
    /// Opens a camera: the first device OpenNI sees, or the one with `uri`.
    pub fn open_device(uri: Option<&str>) -> Result<Self, OpenNiError> {
        let uri = match uri {
            Some(u) => u.to_owned(),
            None => {
                let list = devices()?;
                let Some(first) = list.into_iter().next() else {
                    return Err(OpenNiError::device(
                        "OpenNI2",
                        "no camera found (is it plugged in, and may this user open it? Debian's \
                         libopenni2-0 installs udev rules for PrimeSense, Kinect v1 and Xtion)",
                    ));
                };
                first.uri
            }
        };
        Self::open(&uri, &uri)
    }

    /// Opens a `.oni` recording. It plays on demand: each read takes the next frame at once
    /// ([`crate::live::Replay`] paces it as a camera; OpenNI 2.2's own real-time playback
    /// crashed its player thread when the recording was closed).
    pub fn open_recording(path: &Path) -> Result<Self, OpenNiError> {
        let name = path.display().to_string();
        let mut magic = [0u8; 4];
        let read = std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic));
        match read {
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                return Err(OpenNiError::device(&name, "not an OpenNI recording: the file is shorter than its header"))
            }
            Err(e) => return Err(OpenNiError::device(&name, e.to_string())),
            Ok(()) if &magic != b"NI10" => {
                return Err(OpenNiError::device(&name, "not an OpenNI recording (no `NI10` header)"))
            }
            Ok(()) => {}
        }
        let uri = path.to_str().ok_or_else(|| OpenNiError::device(&name, "the path is not UTF-8"))?;
        Self::open(uri, &name)
    }

    fn open(uri: &str, name: &str) -> Result<Self, OpenNiError> {
        let api = api()?;
        let serial = device_lock();
        let c_uri = CString::new(uri).map_err(|_| OpenNiError::device(name, "the URI holds a NUL byte"))?;
        let mut device: DeviceHandle = std::ptr::null_mut();
        // SAFETY: a NUL-terminated URI and a handle to fill.
        let status = unsafe { (api.device_open)(c_uri.as_ptr(), &mut device) };
        if status != STATUS_OK || device.is_null() {
            let why = api.last_error("");
            let message = if why.is_empty() {
                let what = if Path::new(uri).is_file() {
                    "a truncated or damaged recording"
                } else {
                    "a camera unplugged or in use by another program"
                };
                format!("OpenNI2 cannot open it (status {status}): {what}")
            } else {
                format!("OpenNI2 cannot open it: {why}")
            };
            return Err(OpenNiError::device(name, message));
        }
        let mut camera = Self {
            api,
            name: name.to_owned(),
            device,
            streams: Vec::new(),
            depth_mode: VideoMode::default(),
            color_mode: None,
            depth_mirrored: false,
            color_mirrored: false,
            registered: false,
            intrinsics: Intrinsics { width: 1, height: 1, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0 },
            recorded_frames: None,
            depth_read: 0,
            latest_color: None,
            first_timestamp_us: None,
            notes: Vec::new(),
        };
        // From here on `Drop` closes what was opened (taking the lock: release it first).
        let set_up = camera.set_up();
        drop(serial);
        set_up.map(|()| camera)
    }

    fn set_up(&mut self) -> Result<(), OpenNiError> {
        let api = self.api;
        let is_recording = self.play_on_demand();
        // SAFETY: the open device; a sensor type of the enum.
        let has = |sensor| !unsafe { (api.device_get_sensor_info)(self.device, sensor) }.is_null();
        if !has(SENSOR_DEPTH) {
            return Err(OpenNiError::device(&self.name, "no depth stream"));
        }
        let depth = self.create_stream(SENSOR_DEPTH, "depth")?;
        self.streams.push(depth);
        let mut mode = api.video_mode(depth).ok_or_else(|| self.failure("cannot read the depth video mode"))?;
        if !matches!(mode.pixel_format, PIXEL_DEPTH_1_MM | PIXEL_DEPTH_100_UM) && !is_recording {
            // A live camera may offer millimetres in another mode.
            let wanted = VideoMode { pixel_format: PIXEL_DEPTH_1_MM, ..mode };
            if api.set_video_mode(depth, wanted) {
                mode = wanted;
            }
        }
        if !matches!(mode.pixel_format, PIXEL_DEPTH_1_MM | PIXEL_DEPTH_100_UM) {
            return Err(OpenNiError::device(
                &self.name,
                format!("depth pixel format {} is not supported (1 mm or 100 um depth needed)", mode.pixel_format),
            ));
        }
        if mode.width <= 0 || mode.height <= 0 {
            return Err(OpenNiError::device(&self.name, format!("depth size {}x{}", mode.width, mode.height)));
        }
        self.depth_mode = mode;
        self.depth_mirrored = self.unmirror(depth);
        if has(SENSOR_COLOR) {
            let color = self.create_stream(SENSOR_COLOR, "colour")?;
            self.streams.push(color);
            let mut cmode = api.video_mode(color).ok_or_else(|| self.failure("cannot read the colour video mode"))?;
            if cmode.pixel_format != PIXEL_RGB888 {
                let wanted = VideoMode { pixel_format: PIXEL_RGB888, ..cmode };
                if api.set_video_mode(color, wanted) {
                    cmode = wanted;
                }
            }
            if cmode.pixel_format == PIXEL_RGB888 {
                self.color_mode = Some(cmode);
                self.color_mirrored = self.unmirror(color);
            } else {
                self.notes.push(format!("colour format {} not supported: frames have no colour", cmode.pixel_format));
                self.streams.pop();
            }
        } else {
            self.notes.push("no colour stream: frames have no colour".into());
        }
        if self.color_mode.is_some() {
            // SAFETY: the open device; a registration mode of the enum.
            let supported =
                unsafe { (api.device_registration_supported)(self.device, IMAGE_REGISTRATION_DEPTH_TO_COLOR) } != 0;
            let mode = IMAGE_REGISTRATION_DEPTH_TO_COLOR;
            let size = std::mem::size_of::<c_int>() as c_int;
            // SAFETY: the property holds an OniImageRegistrationMode (an int).
            self.registered = supported
                && unsafe {
                    (api.device_set_property)(
                        self.device,
                        DEVICE_PROPERTY_IMAGE_REGISTRATION,
                        (&raw const mode).cast(),
                        size,
                    )
                } == STATUS_OK;
            if !self.registered {
                self.notes
                    .push("depth not registered to colour by the device: colour resampled by field of view".into());
            }
        }
        // Intrinsics from the depth stream's field of view (OpenNI gives no more), centred.
        let (w, h) = (self.depth_mode.width as u32, self.depth_mode.height as u32);
        let hfov = api.stream_float(depth, STREAM_PROPERTY_HORIZONTAL_FOV).filter(|f| *f > 0.1 && *f < 3.0);
        let vfov = api.stream_float(depth, STREAM_PROPERTY_VERTICAL_FOV).filter(|f| *f > 0.1 && *f < 3.0);
        let (Some(hfov), Some(vfov)) = (hfov, vfov) else {
            return Err(self.failure("the depth stream reports no field of view"));
        };
        let fx = w as f32 / 2.0 / (hfov / 2.0).tan();
        let fy = h as f32 / 2.0 / (vfov / 2.0).tan();
        self.intrinsics = Intrinsics::new(w, h, fx, fy, (w as f32 - 1.0) / 2.0, (h as f32 - 1.0) / 2.0)
            .map_err(|e| OpenNiError::device(&self.name, e.to_string()))?;
        if is_recording {
            let n = api.stream_int(depth, STREAM_PROPERTY_NUMBER_OF_FRAMES).unwrap_or(0);
            if n <= 0 {
                return Err(OpenNiError::device(&self.name, "the recording holds no depth frame"));
            }
            self.recorded_frames = Some(n as usize);
        }
        for &stream in &self.streams {
            // SAFETY: a stream of this device.
            if unsafe { (api.stream_start)(stream) } != STATUS_OK {
                return Err(self.failure("cannot start the streams"));
            }
        }
        Ok(())
    }

    /// Sets a recording to play on demand (a frame per read, OpenNI's speed -1) without repeat;
    /// whether the device is a recording (live devices refuse the property).
    fn play_on_demand(&self) -> bool {
        let speed: f32 = -1.0;
        let size = std::mem::size_of::<f32>() as c_int;
        // SAFETY: the property holds a float.
        let ok = unsafe {
            (self.api.device_set_property)(self.device, DEVICE_PROPERTY_PLAYBACK_SPEED, (&raw const speed).cast(), size)
        } == STATUS_OK;
        if ok {
            let no: c_int = 0;
            // SAFETY: the property holds an OniBool (an int).
            unsafe {
                (self.api.device_set_property)(
                    self.device,
                    DEVICE_PROPERTY_PLAYBACK_REPEAT_ENABLED,
                    (&raw const no).cast(),
                    size,
                )
            };
        }
        ok
    }

    fn create_stream(&self, sensor: c_int, what: &str) -> Result<StreamHandle, OpenNiError> {
        let mut stream: StreamHandle = std::ptr::null_mut();
        // SAFETY: the open device and a handle to fill.
        let status = unsafe { (self.api.device_create_stream)(self.device, sensor, &mut stream) };
        if status != STATUS_OK || stream.is_null() {
            return Err(self.failure(&format!("cannot open the {what} stream")));
        }
        Ok(stream)
    }

    /// Turns mirroring off where the stream allows; whether frames still come mirrored.
    fn unmirror(&self, stream: StreamHandle) -> bool {
        let off: c_int = 0;
        let size = std::mem::size_of::<c_int>() as c_int;
        // SAFETY: the property holds an OniBool (an int).
        unsafe { (self.api.stream_set_property)(stream, STREAM_PROPERTY_MIRRORING, (&raw const off).cast(), size) };
        self.api.stream_int(stream, STREAM_PROPERTY_MIRRORING).is_some_and(|m| m != 0)
    }

    fn failure(&self, what: &str) -> OpenNiError {
        OpenNiError::device(&self.name, format!("{what}: {}", self.api.last_error("no detail from OpenNI2")))
    }

    /// The device URI or recording path.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Intrinsics of the depth frames (from the depth stream's field of view).
    pub fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    /// Frames per second of the depth stream.
    pub fn frame_rate(&self) -> f64 {
        if self.depth_mode.fps > 0 {
            self.depth_mode.fps as f64
        } else {
            30.0
        }
    }

    /// Depth frames in a recording; `None` for a live camera.
    pub fn recorded_frames(&self) -> Option<usize> {
        self.recorded_frames
    }

    /// Depth units in metres.
    pub fn depth_unit_m(&self) -> f64 {
        if self.depth_mode.pixel_format == PIXEL_DEPTH_100_UM {
            1e-4
        } else {
            1e-3
        }
    }

    /// Whether colour frames arrive (RGB).
    pub fn has_color(&self) -> bool {
        self.color_mode.is_some()
    }

    /// What a user should know about this source (format, registration, mirroring, library).
    pub fn notes(&self) -> Vec<String> {
        let mut notes = Vec::new();
        let v = self.api.version;
        notes.push(format!("read by OpenNI {}.{}.{}.{}", v.major, v.minor, v.maintenance, v.build));
        if self.depth_mirrored || self.color_mirrored {
            notes.push("the streams are mirrored: frames are flipped back".into());
        }
        if self.registered {
            notes.push("depth registered to colour by the device".into());
        }
        notes.extend(self.notes.iter().cloned());
        notes
    }

    /// Depth frames read so far.
    pub fn frames_read(&self) -> usize {
        self.depth_read
    }

    /// The next depth frame (with the latest colour frame), waiting for it to arrive;
    /// `Ok(None)` at the end of a recording. A live camera that delivers nothing for
    /// [`DEVICE_TIMEOUT_MS`] (unplugged) is an error, as is a frame of the wrong size.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, OpenNiError> {
        let api = self.api;
        loop {
            if self.recorded_frames.is_some_and(|n| self.depth_read >= n) {
                return Ok(None);
            }
            let mut index: c_int = -1;
            // A recording played on demand has its next frame at once; waiting longer means
            // it ended early.
            let timeout = if self.recorded_frames.is_some() { 1000 } else { DEVICE_TIMEOUT_MS };
            // SAFETY: the started streams of this device; OpenNI writes the ready one's index.
            let status = unsafe {
                (api.wait_for_any_stream)(self.streams.as_mut_ptr(), self.streams.len() as c_int, &mut index, timeout)
            };
            if status == STATUS_TIME_OUT {
                return match self.recorded_frames {
                    Some(n) => Err(OpenNiError::device(
                        &self.name,
                        format!("the recording ended after {} of its {n} depth frames", self.depth_read),
                    )),
                    None => Err(OpenNiError::device(
                        &self.name,
                        format!("no frame for {} s: the camera stopped (unplugged?)", DEVICE_TIMEOUT_MS / 1000),
                    )),
                };
            }
            if status != STATUS_OK {
                return Err(self.failure("waiting for a frame failed"));
            }
            let Some(&stream) = usize::try_from(index).ok().and_then(|i| self.streams.get(i)) else {
                return Err(OpenNiError::device(&self.name, format!("OpenNI2 named stream {index}")));
            };
            let mut raw: *mut OniFrame = std::ptr::null_mut();
            // SAFETY: a started stream; OpenNI hands out a frame we release below.
            let status = unsafe { (api.stream_read_frame)(stream, &mut raw) };
            if status != STATUS_OK || raw.is_null() {
                return Err(self.failure("reading a frame failed"));
            }
            // SAFETY: `raw` is a valid frame until released; its `data` holds `data_size` bytes.
            let result = unsafe { self.take(&*raw, index == 0) };
            // SAFETY: the frame read above, released once.
            unsafe { (api.frame_release)(raw) };
            if let Some(frame) = result? {
                return Ok(Some(frame));
            }
        }
    }

    /// Copies a frame out of OpenNI's buffer: a depth frame becomes a [`Frame`] with the latest
    /// colour; a colour frame is kept for the next depth frame.
    ///
    /// # Safety
    /// `f.data` points at `f.data_size` readable bytes.
    unsafe fn take(&mut self, f: &OniFrame, is_depth: bool) -> Result<Option<Frame>, OpenNiError> {
        // A depth frame counts as read even when it turns out damaged: the next one keeps its
        // index.
        let index = self.depth_read;
        if is_depth {
            self.depth_read += 1;
        }
        let expected = if is_depth { self.depth_mode } else { self.color_mode.unwrap_or_default() };
        let what = if is_depth { "depth" } else { "colour" };
        let bytes_per_pixel: usize = if is_depth { 2 } else { 3 };
        let (w, h) = (f.width.max(0) as usize, f.height.max(0) as usize);
        let stride = if f.stride > 0 { f.stride as usize } else { w * bytes_per_pixel };
        if f.width != expected.width || f.height != expected.height || f.data.is_null() {
            return Err(OpenNiError::device(
                &self.name,
                format!(
                    "{what} frame {} is {}x{}, the stream is {}x{}",
                    f.frame_index, f.width, f.height, expected.width, expected.height
                ),
            ));
        }
        let needed = stride * (h.max(1) - 1) + w * bytes_per_pixel;
        if stride < w * bytes_per_pixel || (f.data_size.max(0) as usize) < needed {
            return Err(OpenNiError::device(
                &self.name,
                format!("{what} frame {} holds {} bytes, {needed} needed for {w}x{h}", f.frame_index, f.data_size),
            ));
        }
        // SAFETY: checked above against the size OpenNI reports; the caller's promise.
        let data = unsafe { std::slice::from_raw_parts(f.data as *const u8, needed) };
        if !is_depth {
            let mirrored = self.color_mirrored;
            let mut pixels = Vec::with_capacity(w * h);
            for y in 0..h {
                let row = &data[y * stride..y * stride + w * 3];
                let start = pixels.len();
                pixels.extend(row.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
                if mirrored {
                    pixels[start..].reverse();
                }
            }
            let image = ColorImage { width: w as u32, height: h as u32, pixels };
            self.latest_color = Some(register_color(&image, &self.intrinsics, None));
            return Ok(None);
        }
        let unit = self.depth_unit_m() as f32;
        let mut depth = Vec::with_capacity(w * h);
        for y in 0..h {
            let row = &data[y * stride..y * stride + w * 2];
            let start = depth.len();
            depth.extend(row.chunks_exact(2).map(|p| u16::from_le_bytes([p[0], p[1]]) as f32 * unit));
            if self.depth_mirrored {
                depth[start..].reverse();
            }
        }
        let t0 = *self.first_timestamp_us.get_or_insert(f.timestamp);
        let color = self.latest_color.clone().unwrap_or_else(|| vec![[0; 3]; w * h]);
        let frame = Frame {
            index,
            timestamp: f.timestamp.saturating_sub(t0) as f64 * 1e-6,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera: None,
            labels: None,
        };
        frame.validate().map_err(|m| OpenNiError::device(&self.name, format!("frame {index}: {m}")))?;
        Ok(Some(frame))
    }
}

impl Drop for OniCamera {
    fn drop(&mut self) {
        let api = self.api;
        let _serial = device_lock();
        // A recording's player thread may still be handing over a frame it read on its own
        // (at the streams' start, or ahead of a read): OpenNI 2.2's file driver crashed in that
        // thread when `device_close` joined it mid-frame (about one close in ten under load).
        // Giving it a few frame periods to come to rest first costs a recording's close 0.1 s.
        if self.recorded_frames.is_some() {
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        // The streams are stopped and the device closed, but the streams are not destroyed:
        // destroying a recording's streams raced its player thread in OpenNI 2.2 (a crash about
        // one close in ten under load). Closing the device stops and joins that thread; the
        // streams' few kilobytes stay allocated until the process ends.
        for &stream in &self.streams {
            // SAFETY: streams of this device, stopped once.
            unsafe { (api.stream_stop)(stream) };
        }
        // SAFETY: the device opened in `open`, closed once.
        unsafe { (api.device_close)(self.device) };
    }
}
