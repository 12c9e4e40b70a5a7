//! `semrecon run --serve`: the live viewer starts, is announced on 127.0.0.1, and with
//! `--serve-exit` stops when the run ends (without it the run would serve until Ctrl-C).

use std::process::Command;

#[test]
fn run_serve_announces_a_local_url_and_exits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = Command::new(env!("CARGO_BIN_EXE_semrecon"))
        .args([
            "run",
            "--dataset",
            "synth:3",
            "--frames",
            "0..4",
            "--voxel",
            "0.02",
            "--serve",
            "--serve-exit",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .expect("the binary runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "run --serve failed: {stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let url = stdout.split_whitespace().find(|w| w.starts_with("http://127.0.0.1:"));
    let port = url.and_then(|u| u.trim_start_matches("http://127.0.0.1:").trim_end_matches('/').parse::<u16>().ok());
    assert!(port.is_some_and(|p| p > 0), "no 127.0.0.1 URL printed: {stdout}");
    assert!(dir.path().join("mesh.ply").is_file(), "the run still writes its outputs");
    assert!(!stdout.contains("Ctrl-C"), "--serve-exit must not wait for Ctrl-C: {stdout}");
}

#[test]
fn serve_options_need_serve() {
    let out = Command::new(env!("CARGO_BIN_EXE_semrecon"))
        .args(["run", "--dataset", "synth:3", "--frames", "0..2", "--serve-exit", "--out", "unused"])
        .output()
        .expect("the binary runs");
    assert!(!out.status.success(), "--serve-exit without --serve must be refused");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--serve"));
}
