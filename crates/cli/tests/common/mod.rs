//! What the end-to-end tests of the `semrecon` binary share: running the built binary and
//! reading what it printed. Each test file includes it with `mod common;` and uses a part.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// Runs the built `semrecon` binary with `args` and waits for it.
pub fn semrecon(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_semrecon")).args(args).output().expect("run semrecon")
}

/// What the run printed on stdout.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// What the run printed on stderr.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A temporary path as an argument (temporary paths are UTF-8 here).
pub fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 temp path")
}
