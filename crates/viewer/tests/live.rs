//! The live server of `semrecon run --serve` end to end: no scene before the first update
//! (the page waits), then each update bumps the version and changes what is served.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use glam::{Affine3A, Vec3};
use semrecon_data::{LabeledMesh, Trajectory};
use semrecon_viewer::ViewerServer;
use serde_json::Value;

/// `n` separate floor squares of 2 triangles each, 1 m apart along x.
fn floor_tiles(n: usize) -> LabeledMesh {
    let mut m = LabeledMesh::default();
    for i in 0..n {
        let x = i as f32;
        let base = m.positions.len() as u32;
        m.positions.extend([
            Vec3::new(x, 0., 0.),
            Vec3::new(x + 0.9, 0., 0.),
            Vec3::new(x + 0.9, 0.9, 0.),
            Vec3::new(x, 0.9, 0.),
        ]);
        m.colors.extend([[200, 180, 150]; 4]);
        m.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        m.triangle_labels.extend([1, 1]);
    }
    m
}

fn path(poses: usize) -> Trajectory {
    let mut t = Trajectory::default();
    for i in 0..poses {
        t.push(i as f64 * 0.1, Affine3A::from_translation(Vec3::new(0.1 * i as f32, 0.5, 1.5)));
    }
    t
}

fn get(addr: SocketAddr, path: &str) -> (u16, Value) {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(20))).expect("timeout");
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n").as_bytes())
        .expect("send");
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let end = out.windows(4).position(|w| w == b"\r\n\r\n").expect("response head");
    let head = String::from_utf8_lossy(&out[..end]).to_string();
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).expect("status code");
    (status, serde_json::from_slice(&out[end + 4..]).expect("JSON body"))
}

#[test]
fn live_updates_bump_the_version_and_change_the_scene() {
    let (server, live) = ViewerServer::start_live(None).expect("start live server");
    let addr = server.addr();

    let (status, v) = get(addr, "/api/version");
    assert_eq!(status, 200);
    assert_eq!((v["version"].as_u64(), v["live"].as_bool(), v["ready"].as_bool()), (Some(0), Some(true), Some(false)));
    assert_eq!(get(addr, "/api/info").0, 503, "no scene before the first update");
    assert!(live.update(&LabeledMesh::default(), &path(1), None).is_err(), "an empty mesh is refused");
    assert_eq!(live.version(), 0);

    assert_eq!(live.update(&floor_tiles(3), &path(4), None).expect("first update"), 1);
    let (_, v) = get(addr, "/api/version");
    assert_eq!((v["version"].as_u64(), v["ready"].as_bool()), (Some(1), Some(true)));
    let (status, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    assert_eq!((info["triangles"].as_u64(), info["version"].as_u64()), (Some(6), Some(1)));
    assert_eq!(info["live"].as_bool(), Some(true));
    assert_eq!(info["has_trajectory"].as_bool(), Some(true));
    let (_, t) = get(addr, "/api/trajectory");
    assert_eq!(t["positions"].as_array().map(Vec::len), Some(4));

    assert_eq!(live.update(&floor_tiles(5), &path(9), None).expect("second update"), 2);
    let (_, v) = get(addr, "/api/version");
    assert_eq!(v["version"].as_u64(), Some(2));
    let (_, info) = get(addr, "/api/info");
    assert_eq!((info["triangles"].as_u64(), info["version"].as_u64()), (Some(10), Some(2)));
    let (_, t) = get(addr, "/api/trajectory");
    assert_eq!(t["positions"].as_array().map(Vec::len), Some(9));
    server.stop();
}

#[test]
fn a_fixed_scene_reports_version_zero_and_not_live() {
    let (server, live) = ViewerServer::start_live(None).expect("start live server");
    live.update(&floor_tiles(1), &path(2), None).expect("update");
    let folder = semrecon_viewer::ViewerFolder::live("tiles", &floor_tiles(2), &path(2), None).expect("folder");
    server.stop();
    let server = ViewerServer::start(folder, None).expect("start");
    let (status, v) = get(server.addr(), "/api/version");
    assert_eq!(status, 200);
    assert_eq!((v["version"].as_u64(), v["live"].as_bool(), v["ready"].as_bool()), (Some(0), Some(false), Some(true)));
    let (_, info) = get(server.addr(), "/api/info");
    assert_eq!((info["triangles"].as_u64(), info["live"].as_bool()), (Some(4), Some(false)));
    server.stop();
}
