//! Where the real evaluation data lives: `../shared/data` beside the workspace (RGB-D
//! sequences and scanned meshes captured by others, never copied into the repository).
//! Tests, benchmarks and evaluations use it when it is there and skip with a message when it
//! is not, because a user's fresh clone does not have it.

use std::path::{Path, PathBuf};

/// Environment variable that points at the shared data folder explicitly (for checkouts
/// that do not sit beside it).
pub const SHARED_DATA_ENV: &str = "SEMRECON_SHARED_DATA";

/// The shared data folder: `$SEMRECON_SHARED_DATA`, else `<workspace root>/../shared/data`,
/// else `<workspace root>/../../shared/data` (a git worktree one level further down).
/// `None` when none exists.
pub fn shared_data_dir() -> Option<PathBuf> {
    if let Some(dir) = std::env::var_os(SHARED_DATA_ENV) {
        let dir = PathBuf::from(dir);
        return dir.is_dir().then_some(dir);
    }
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    ["../shared/data", "../../shared/data"].iter().map(|rel| workspace.join(rel)).find(|p| p.is_dir())
}

/// `shared_data_dir()/rel` when it exists; otherwise prints `skipping: ../shared/data/REL not
/// found` (the message tests show when they skip) and returns `None`.
pub fn shared_data_path(rel: &str) -> Option<PathBuf> {
    let found = shared_data_dir().map(|d| d.join(rel)).filter(|p| p.exists());
    if found.is_none() {
        println!("skipping: ../shared/data/{rel} not found");
    }
    found
}
