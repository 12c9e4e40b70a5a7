//! The page and its JavaScript, compiled into the binary so that `semrecon view` and
//! `semrecon export-viewer` need no files and no network at run time. three.js (MIT, see
//! `assets/three/LICENSE`) comes from npm and is copied here by `assets/update_three.sh`.
//!
//! `index.html` has two placeholders: `<!--IMPORTMAP-->` (where the bare `three` imports
//! resolve) and `<!--SCRIPTS-->` (how the page's module is loaded). The served page points
//! them at `/assets/...`; the static page embeds everything, because browsers refuse to
//! load module files from file:// URLs but do accept inline modules and `data:` imports.

use crate::base64;

const INDEX_HTML: &str = include_str!("../assets/index.html");
const VIEWER_JS: &str = include_str!("../assets/viewer.js");
const THREE_JS: &[u8] = include_bytes!("../assets/three/three.module.min.js");
const ORBIT_CONTROLS_JS: &[u8] = include_bytes!("../assets/three/OrbitControls.js");
const THREE_LICENSE: &[u8] = include_bytes!("../assets/three/LICENSE");

/// A static asset by name (the part after `/assets/`): MIME type and bytes.
pub fn asset(name: &str) -> Option<(&'static str, &'static [u8])> {
    const JS: &str = "text/javascript; charset=utf-8";
    match name {
        "viewer.js" => Some((JS, VIEWER_JS.as_bytes())),
        "three.module.min.js" => Some((JS, THREE_JS)),
        "OrbitControls.js" => Some((JS, ORBIT_CONTROLS_JS)),
        "three-LICENSE.txt" => Some(("text/plain; charset=utf-8", THREE_LICENSE)),
        _ => None,
    }
}

/// The page as the server sends it.
pub fn served_page() -> String {
    let map = r#"<script type="importmap">{"imports": {"three": "/assets/three.module.min.js", "three/addons/OrbitControls.js": "/assets/OrbitControls.js"}}</script>"#;
    INDEX_HTML
        .replace("<!--IMPORTMAP-->", map)
        .replace("<!--SCRIPTS-->", r#"<script type="module" src="/assets/viewer.js"></script>"#)
}

/// The self-contained page of the static export; `data_script` is the file name of the
/// classic script that sets `window.SEMRECON_STATIC` (loaded before the module runs).
pub fn static_page(data_script: &str) -> String {
    let data_url = |bytes: &[u8]| format!("data:text/javascript;base64,{}", base64::encode(bytes));
    let map = format!(
        r#"<script type="importmap">{{"imports": {{"three": "{}", "three/addons/OrbitControls.js": "{}"}}}}</script>"#,
        data_url(THREE_JS),
        data_url(ORBIT_CONTROLS_JS)
    );
    // viewer.js never contains "</script", so it can be inlined as is.
    let scripts = format!(
        "<script src=\"{data_script}\"></script>\n<script type=\"module\">\n{}\n</script>",
        VIEWER_JS.replace("</script", "<\\/script")
    );
    INDEX_HTML.replace("<!--IMPORTMAP-->", &map).replace("<!--SCRIPTS-->", &scripts)
}

/// The three.js licence text, written beside exports.
pub fn three_license() -> &'static [u8] {
    THREE_LICENSE
}
