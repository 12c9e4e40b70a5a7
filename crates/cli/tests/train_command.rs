//! `semrecon train` from the command line: it answers `--help` in every build; without the
//! `train` feature it fails cleanly and says how to build with it; bad data sources are
//! named errors. (Training itself is tested in crates/net/tests/train_end_to_end.rs.)
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::semrecon;

#[test]
fn train_has_help_and_explains_the_feature_or_rejects_bad_sources() {
    let help = semrecon(&["train", "--help"]);
    assert!(help.status.success());
    assert!(String::from_utf8_lossy(&help.stdout).contains("--data"));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = semrecon(&["train", "--config", "s20", "--data", "nonsense:1", "--out", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success());
    assert!(!err.contains("panicked"), "{err}");
    if cfg!(feature = "train") {
        assert!(err.contains("nonsense:1"), "{err}");
    } else {
        assert!(err.contains("--features train"), "{err}");
    }
}
