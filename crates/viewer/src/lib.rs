//! The interactive viewer of semrecon: a local web page showing a labelled mesh (in its
//! colours, its semantic classes or plain shading), the camera trajectory, the class legend
//! and the material table; a click throws a ball that the server simulates with the same
//! Rust physics as `semrecon throw` and the page animates.
//!
//! - [`folder`]: what is shown, read from an output folder (`run`, `demo`, `synth`, any PLY).
//! - [`routes`]: the HTTP API, transport-independent; bad requests are 4xx JSON errors.
//! - [`server`]: the 127.0.0.1-only HTTP server of `semrecon view`.
//! - [`live`]: the scene of `semrecon run --serve`, replaced as the map grows.
//! - [`export`]: the static page of `semrecon export-viewer` (works from file://).
//! - [`scene_binary`]: the mesh's binary wire layout; [`decimate`]: simplification of huge meshes.
//! - [`ar`]: the AR view of `semrecon ar`, balls drawn over a scan's RGB frames (PNG + GIF).
#![warn(missing_docs)]

pub mod ar;
mod assets;
mod base64;
pub mod decimate;
pub mod error;
pub mod export;
pub mod folder;
mod gif;
pub mod live;
pub mod routes;
pub mod scene_binary;
pub mod server;

pub use error::{Result, ViewerError};
pub use export::{export_static, ExportSummary, DEFAULT_EXPORT_THROWS};
pub use folder::ViewerFolder;
pub use live::LiveScene;
pub use server::{serve, ViewerServer};
