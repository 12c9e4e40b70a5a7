//! The viewer's HTTP server end to end: a small labelled room in a temporary folder, the
//! server on a free port in this process, requests over plain TCP. Checks every route, the
//! 4xx answers to bad requests, and that the server keeps answering after them.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::time::Duration;

use glam::{Affine3A, Quat, Vec3};
use semrecon_data::{write_ply, LabeledMesh, PlyEncoding, Trajectory};
use semrecon_viewer::{export_static, ViewerFolder, ViewerServer};
use serde_json::Value;

/// A closed 4 x 4 x 2.5 m box: floor (class 1), walls (2) and ceiling (0), facing inwards.
fn room(labelled: bool) -> LabeledMesh {
    let mut m = LabeledMesh::default();
    let mut quad = |corners: [Vec3; 4], label: u8| {
        let base = m.positions.len() as u32;
        m.positions.extend(corners);
        m.colors.extend([[200, 180, 150]; 4]);
        m.triangles.push([base, base + 1, base + 2]);
        m.triangles.push([base, base + 2, base + 3]);
        m.triangle_labels.extend([label, label]);
    };
    let (x, y, z) = (4.0, 4.0, 2.5);
    let v = Vec3::new;
    quad([v(0., 0., 0.), v(x, 0., 0.), v(x, y, 0.), v(0., y, 0.)], 1);
    quad([v(0., 0., z), v(0., y, z), v(x, y, z), v(x, 0., z)], 0);
    quad([v(0., 0., 0.), v(0., 0., z), v(x, 0., z), v(x, 0., 0.)], 2);
    quad([v(0., y, 0.), v(x, y, 0.), v(x, y, z), v(0., y, z)], 2);
    quad([v(0., 0., 0.), v(0., y, 0.), v(0., y, z), v(0., 0., z)], 2);
    quad([v(x, 0., 0.), v(x, 0., z), v(x, y, z), v(x, y, 0.)], 2);
    if !labelled {
        m.triangle_labels.clear();
    }
    m
}

fn write_folder(dir: &Path, labelled: bool) {
    write_ply(dir.join("mesh.ply"), &room(labelled), PlyEncoding::BinaryLittleEndian).expect("write mesh");
    let mut t = Trajectory::default();
    for i in 0..5 {
        let position = Vec3::new(1.0 + 0.4 * i as f32, 2.0, 1.5);
        // Camera looking along +x (camera z), y down.
        let rotation = Quat::from_mat3(&glam::Mat3::from_cols(-Vec3::Y, -Vec3::Z, Vec3::X));
        t.push(i as f64 * 0.1, Affine3A::from_rotation_translation(rotation, position));
    }
    t.write_tum(dir.join("trajectory.txt")).expect("write trajectory");
}

fn start(labelled: bool) -> (tempfile::TempDir, ViewerServer) {
    let dir = tempfile::tempdir().expect("tempdir");
    write_folder(dir.path(), labelled);
    let folder = ViewerFolder::load(dir.path(), None).expect("load folder");
    let server = ViewerServer::start(folder, None).expect("start server");
    (dir, server)
}

/// Sends raw bytes, returns status and body.
fn raw(addr: SocketAddr, request: &[u8]) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(20))).expect("timeout");
    // The server may answer and close before reading an oversized body: ignore write errors.
    let _ = s.write_all(request);
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let text_end = out.windows(4).position(|w| w == b"\r\n\r\n").expect("response head");
    let head = String::from_utf8_lossy(&out[..text_end]).to_string();
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).expect("status code");
    (status, out[text_end + 4..].to_vec())
}

fn get(addr: SocketAddr, path: &str) -> (u16, Vec<u8>) {
    raw(addr, format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n").as_bytes())
}

fn post(addr: SocketAddr, path: &str, body: &str) -> (u16, Value) {
    let req = format!(
        "POST {path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let (status, body) = raw(addr, req.as_bytes());
    (status, serde_json::from_slice(&body).unwrap_or(Value::Null))
}

fn json(body: &[u8]) -> Value {
    serde_json::from_slice(body).expect("JSON body")
}

#[test]
fn routes_answer_and_bad_requests_get_4xx_while_the_server_stays_up() {
    let (_dir, server) = start(true);
    let addr = server.addr();
    assert!(addr.ip().is_loopback(), "listens on 127.0.0.1 only: {addr}");

    let (status, page) = get(addr, "/");
    assert_eq!(status, 200);
    let page = String::from_utf8_lossy(&page);
    assert!(page.contains("importmap") && page.contains("/assets/viewer.js"));
    for asset in ["viewer.js", "three.module.min.js", "OrbitControls.js"] {
        let (status, body) = get(addr, &format!("/assets/{asset}"));
        assert_eq!(status, 200, "{asset}");
        assert!(body.len() > 1000, "{asset}");
    }

    let (status, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    let info = json(&info);
    assert_eq!(info["labelled"], true);
    assert_eq!(info["mesh"], "mesh.ply");
    assert_eq!(info["triangles"], 12);
    assert_eq!(info["palette"].as_array().map(|a| a.len()), Some(13));
    assert_eq!(info["palette"][1]["name"], "floor");

    let (status, scene) = get(addr, "/api/scene");
    assert_eq!(status, 200);
    assert_eq!(&scene[..4], b"SRM1");

    let (status, traj) = get(addr, "/api/trajectory");
    assert_eq!(status, 200);
    let traj = json(&traj);
    assert_eq!(traj["positions"].as_array().map(|a| a.len()), Some(5));
    let fwd = &traj["forward"][0];
    assert!((fwd[0].as_f64().unwrap_or(0.0) - 1.0).abs() < 1e-4, "camera looks along +x: {fwd}");

    let (status, materials) = get(addr, "/api/materials");
    assert_eq!(status, 200);
    let materials = json(&materials);
    assert_eq!(materials["classes"].as_array().map(|a| a.len()), Some(13));
    assert!(materials["unlabelled"]["restitution"].is_number());

    // A throw across the room, tossed up: it bounces on the floor and hits walls.
    let (status, t) = post(addr, "/api/throw", r#"{"from": [2, 2, 1.5], "dir": [1, 0.3, 0.5], "speed": 5}"#);
    assert_eq!(status, 200, "{t}");
    let contacts = t["contacts"].as_array().expect("contacts");
    assert!(contacts.iter().any(|c| c["class"] == "floor"), "{t}");
    assert!(contacts.iter().any(|c| c["class"] == "wall"), "{t}");
    let positions = t["positions"].as_array().expect("positions");
    assert!(positions.len() > 100 && positions.len() == t["times"].as_array().map_or(0, |a| a.len()));
    for p in positions {
        let p: Vec<f64> = p.as_array().expect("xyz").iter().filter_map(|x| x.as_f64()).collect();
        assert!(p.iter().all(|x| (-0.1..=4.1).contains(x)), "the ball stays in the room: {p:?}");
    }

    // Bad requests: a 4xx with a JSON message each.
    let bad_bodies = [
        ("malformed", r#"{"from": [1, 1, 1], "dir": [1, 0"#),
        ("NaN", r#"{"from": [1, 1, NaN], "dir": [1, 0, 0], "speed": 3}"#),
        ("overflow", r#"{"from": [1, 1, 1e999], "dir": [1, 0, 0], "speed": 3}"#),
        ("huge", r#"{"from": [1, 1, 1e300], "dir": [1, 0, 0], "speed": 3}"#),
        ("zero direction", r#"{"from": [1, 1, 1], "dir": [0, 0, 0], "speed": 3}"#),
        ("fast", r#"{"from": [1, 1, 1], "dir": [1, 0, 0], "speed": 1e9}"#),
        ("negative speed", r#"{"from": [1, 1, 1], "dir": [1, 0, 0], "speed": -1}"#),
        ("long", r#"{"from": [1, 1, 1], "dir": [1, 0, 0], "speed": 3, "seconds": 1e6}"#),
        ("unknown field", r#"{"from": [1, 1, 1], "dir": [1, 0, 0], "speed": 3, "mass": 2}"#),
        ("wrong type", r#"{"from": "here", "dir": [1, 0, 0], "speed": 3}"#),
        ("two coordinates", r#"{"from": [1, 1], "dir": [1, 0, 0], "speed": 3}"#),
        ("empty", ""),
        ("not JSON", "\u{0}\u{1}binary"),
    ];
    for (what, body) in bad_bodies {
        let (status, v) = post(addr, "/api/throw", body);
        assert_eq!(status, 400, "{what}: {v}");
        assert!(v["error"].as_str().is_some_and(|m| !m.is_empty()), "{what}: {v}");
    }
    let big = format!(r#"{{"from": [1, 1, 1], "dir": [1, 0, 0], "speed": 3, "pad": "{}"}}"#, "x".repeat(100_000));
    let (status, v) = post(addr, "/api/throw", &big);
    assert_eq!(status, 413, "{v}");
    let (status, body) = get(addr, "/api/throw");
    assert_eq!(status, 405, "{}", String::from_utf8_lossy(&body));
    let (status, body) = get(addr, "/no/such/route");
    assert_eq!(status, 404);
    assert!(json(&body)["error"].is_string());
    let (status, _) = get(addr, "/assets/../Cargo.toml");
    assert_eq!(status, 404);
    let (status, _) =
        raw(addr, b"POST /api/info HTTP/1.1\r\nHost: localhost\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
    assert_eq!(status, 405);
    // DNS rebinding: a page of another site reaching 127.0.0.1 under its own name.
    let (status, _) = raw(addr, b"GET /api/info HTTP/1.1\r\nHost: evil.example:80\r\nConnection: close\r\n\r\n");
    assert_eq!(status, 403);
    // Not HTTP at all: the connection is dropped or answered 400, the server lives on.
    if let Ok(mut s) = TcpStream::connect(addr) {
        let _ = s.write_all(b"\x16\x03\x01 garbage\r\n\r\n");
        let _ = s.set_read_timeout(Some(Duration::from_secs(2)));
        let _ = s.read_to_end(&mut Vec::new());
    }

    // Still up and answering.
    let (status, t) = post(addr, "/api/throw", r#"{"from": [2, 2, 1], "dir": [0, 0, -1], "speed": 1, "seconds": 0.5}"#);
    assert_eq!(status, 200, "{t}");
    assert_eq!(t["contacts"][0]["class"], "floor");
    server.stop();
}

#[test]
fn unlabelled_mesh_uses_the_default_material_and_says_so() {
    let (_dir, server) = start(false);
    let addr = server.addr();
    let info = json(&get(addr, "/api/info").1);
    assert_eq!(info["labelled"], false);
    let notes = info["notes"].to_string();
    assert!(notes.contains("no semantic labels"), "{notes}");
    let (status, t) = post(addr, "/api/throw", r#"{"from": [2, 2, 1], "dir": [0, 0, -1], "speed": 1, "seconds": 0.5}"#);
    assert_eq!(status, 200, "{t}");
    assert_eq!(t["contacts"][0]["class"], "unlabelled");
    assert!(t["warnings"].to_string().contains("no semantic labels"), "{t}");
    server.stop();
}

#[test]
fn two_servers_get_different_free_ports_and_a_taken_port_is_an_error() {
    let (_d1, a) = start(true);
    let (_d2, b) = start(true);
    assert_ne!(a.addr().port(), b.addr().port());
    let dir = tempfile::tempdir().expect("tempdir");
    write_folder(dir.path(), true);
    let folder = ViewerFolder::load(dir.path(), None).expect("load");
    let err = ViewerServer::start(folder, Some(a.addr().port())).err().expect("port in use");
    assert!(err.to_string().contains(&a.addr().port().to_string()), "{err}");
    a.stop();
    b.stop();
}

#[test]
fn folder_picks_the_reconstruction_first_and_reports_missing_meshes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path();
    write_ply(p.join("ground_truth.ply"), &room(true), PlyEncoding::Ascii).expect("write");
    assert!(semrecon_viewer::folder::find_mesh(p).expect("found").ends_with("ground_truth.ply"));
    write_ply(p.join("mesh.ply"), &room(false), PlyEncoding::Ascii).expect("write");
    assert!(semrecon_viewer::folder::find_mesh(p).expect("found").ends_with("mesh.ply"));
    let empty = tempfile::tempdir().expect("tempdir");
    let err = ViewerFolder::load(empty.path(), None).expect_err("no mesh");
    assert!(err.to_string().contains("mesh.ply"), "{err}");
    let err = ViewerFolder::load(&p.join("missing"), None).expect_err("no folder");
    assert!(err.to_string().contains("missing"), "{err}");
}

#[test]
fn static_export_embeds_data_and_precomputed_throws() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_folder(dir.path(), true);
    let folder = ViewerFolder::load(dir.path(), None).expect("load");
    let out = dir.path().join("export");
    let summary = export_static(&folder, &out, 4).expect("export");
    assert_eq!(summary.throws, 4);
    let page = std::fs::read_to_string(out.join("index.html")).expect("index.html");
    assert!(page.contains("data:text/javascript;base64,") && page.contains("data.js"));
    assert!(!page.contains("/assets/"), "the static page must not fetch from a server");
    let data = std::fs::read_to_string(out.join("data.js")).expect("data.js");
    let json_text =
        data.trim().strip_prefix("window.SEMRECON_STATIC = ").and_then(|s| s.strip_suffix(';')).expect("assignment");
    let v: Value = serde_json::from_str(json_text).expect("data JSON");
    assert_eq!(v["throws"].as_array().map(|a| a.len()), Some(4));
    assert_eq!(v["info"]["static"], true);
    assert!(v["scene"].as_str().is_some_and(|s| s.starts_with("U1JNM")), "base64 of SRM1");
    assert!(out.join("three-LICENSE.txt").is_file());
}
