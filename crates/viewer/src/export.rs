//! `semrecon export-viewer`: the viewer as static files that work from a file:// URL, for
//! sharing a result without running a server. The API answers are computed once and put in
//! `data.js` (the mesh as base64 of the same binary layout); there is no physics in the
//! browser, so a set of throws is simulated here and the page replays, on a click, the one
//! that lands nearest the clicked point.

use std::path::{Path, PathBuf};

use semrecon_data::atomic_file::write_atomic;
use semrecon_data::DataError;
use serde_json::json;

use crate::error::Result;
use crate::folder::ViewerFolder;
use crate::{assets, base64, routes};

/// Throws precomputed by default.
pub const DEFAULT_EXPORT_THROWS: usize = 8;

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSummary {
    /// The page to open.
    pub index: PathBuf,
    /// Precomputed throws embedded.
    pub throws: usize,
    /// Total bytes written.
    pub bytes: usize,
}

/// Writes `out/index.html`, `out/data.js` and `out/three-LICENSE.txt` for `folder`, with
/// `throws` precomputed throws (see [`routes::precomputed_throws`]).
pub fn export_static(folder: &ViewerFolder, out: &Path, throws: usize) -> Result<ExportSummary> {
    std::fs::create_dir_all(out).map_err(|e| DataError::io(out, e))?;
    let precomputed: Vec<_> = routes::precomputed_throws(folder, throws)
        .into_iter()
        .map(|(request, throw)| json!({ "request": request, "throw": throw }))
        .collect();
    let mut info = routes::info_json(folder);
    info["static"] = json!(true);
    let data = json!({
        "info": info,
        "materials": routes::materials_json(&folder.materials),
        "trajectory": routes::trajectory_json(folder),
        "throws": precomputed,
        "scene": base64::encode(&crate::scene_binary::encode_mesh(&folder.display)),
    });
    let data_js = format!("window.SEMRECON_STATIC = {data};\n");
    let page = assets::static_page("data.js");
    let index = out.join("index.html");
    write_atomic(&out.join("data.js"), data_js.as_bytes())?;
    write_atomic(&out.join("three-LICENSE.txt"), assets::three_license())?;
    write_atomic(&index, page.as_bytes())?;
    Ok(ExportSummary {
        index,
        throws: precomputed.len(),
        bytes: data_js.len() + page.len() + assets::three_license().len(),
    })
}
