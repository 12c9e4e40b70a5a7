//! The viewer's HTTP API, independent of the transport so that the server, the static
//! export and the tests share it: one request (method, path, body) in, one [`Response`]
//! out. Bad input never panics: it is a 4xx with a JSON `{"error": "..."}` message.
//!
//! | route | answer |
//! |---|---|
//! | `GET /` | the page |
//! | `GET /assets/NAME` | the page's JavaScript (three.js is compiled into the binary) |
//! | `GET /api/version` | `{version, live, ready}`: the scene's version (0 for a fixed one) |
//! | `GET /api/info` | mesh file, counts, labelled or not, notes, class palette, bounds, version |
//! | `GET /api/scene` | the mesh in the binary layout of [`crate::scene_binary`] |
//! | `GET /api/trajectory` | camera positions and viewing directions, or 404 when there is none |
//! | `GET /api/materials` | restitution and friction per class |
//! | `POST /api/throw` | `{"from": [x,y,z], "dir": [x,y,z], "speed": v, "seconds"?: s}` to a throw |

use glam::Vec3;
use semrecon_data::SemanticClass;
use semrecon_physics::{ArScene, MaterialTable, PhysicsError, Throw};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use crate::assets;
use crate::folder::{file_name, ViewerFolder};

/// Largest accepted request body; a throw request is about 100 bytes.
pub const MAX_BODY_BYTES: usize = 16 * 1024;
/// Largest coordinate of a throw's start, metres (rooms are far smaller).
pub const MAX_THROW_COORDINATE: f64 = 1000.0;
/// Largest throw speed, m/s.
pub const MAX_THROW_SPEED: f64 = 50.0;
/// Longest simulated throw, seconds (bounds the server's work per request).
pub const MAX_THROW_SECONDS: f64 = 10.0;
/// Simulated time of a throw that does not say.
pub const DEFAULT_THROW_SECONDS: f64 = 4.0;

/// An HTTP answer.
#[derive(Debug, Clone, PartialEq)]
pub struct Response {
    /// Status code.
    pub status: u16,
    /// MIME type of `body`.
    pub content_type: &'static str,
    /// The body.
    pub body: Vec<u8>,
}

impl Response {
    fn json(status: u16, value: &Value) -> Self {
        Self { status, content_type: "application/json", body: value.to_string().into_bytes() }
    }

    /// An error answer `{"error": message}`.
    pub fn error(status: u16, message: impl Into<String>) -> Self {
        Self::json(status, &json!({ "error": message.into() }))
    }
}

/// One throw as the page asks for it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThrowRequest {
    /// Start of the ball's centre, world frame, metres.
    pub from: [f64; 3],
    /// Direction (any length > 0).
    pub dir: [f64; 3],
    /// Speed, m/s.
    pub speed: f64,
    /// Simulated time, seconds ([`DEFAULT_THROW_SECONDS`] when absent).
    #[serde(default)]
    pub seconds: Option<f64>,
}

/// Answers one request against the server's current scene: `folder` (none while a live
/// scene has no mesh yet; its data routes then answer 503), at `version`, `live` when it
/// can change. Adds `GET /api/version` and the `version`/`live` fields of `/api/info` to
/// [`handle`].
pub fn handle_scene(
    folder: Option<&ViewerFolder>,
    version: u64,
    live: bool,
    method: &str,
    path: &str,
    body: &[u8],
) -> Response {
    let route = path.split('?').next().unwrap_or(path);
    let get_only =
        |r: Response| if method == "GET" || method == "HEAD" { r } else { method_not_allowed(method, route) };
    match (route, folder) {
        ("/api/version", _) => {
            get_only(Response::json(200, &json!({ "version": version, "live": live, "ready": folder.is_some() })))
        }
        ("/api/info", Some(folder)) => {
            let mut info = info_json(folder);
            info["version"] = json!(version);
            info["live"] = json!(live);
            get_only(Response::json(200, &info))
        }
        (_, Some(folder)) => handle(folder, method, path, body),
        (_, None) if route.starts_with("/api/") => {
            Response::error(503, "the live reconstruction has no mesh yet: poll /api/version until ready")
        }
        (_, None) => {
            page_or_asset(route).map(get_only).unwrap_or_else(|| Response::error(404, format!("no route {route}")))
        }
    }
}

/// The page and its assets, which need no scene.
fn page_or_asset(path: &str) -> Option<Response> {
    match path {
        "/" | "/index.html" => Some(Response {
            status: 200,
            content_type: "text/html; charset=utf-8",
            body: assets::served_page().into_bytes(),
        }),
        _ => path.strip_prefix("/assets/").and_then(assets::asset).map(|(content_type, bytes)| Response {
            status: 200,
            content_type,
            body: bytes.to_vec(),
        }),
    }
}

/// Answers one request against `folder`.
pub fn handle(folder: &ViewerFolder, method: &str, path: &str, body: &[u8]) -> Response {
    // Query strings only serve to defeat caches.
    let path = path.split('?').next().unwrap_or(path);
    let get_only = |r: Response| if method == "GET" || method == "HEAD" { r } else { method_not_allowed(method, path) };
    match path {
        "/api/info" => get_only(Response::json(200, &info_json(folder))),
        "/api/scene" => get_only(Response {
            status: 200,
            content_type: "application/octet-stream",
            body: crate::scene_binary::encode_mesh(&folder.display),
        }),
        "/api/materials" => get_only(Response::json(200, &materials_json(&folder.materials))),
        "/api/trajectory" => get_only(match trajectory_json(folder) {
            Some(v) => Response::json(200, &v),
            None => Response::error(404, "this folder has no trajectory (trajectory.txt or groundtruth.txt)"),
        }),
        "/api/throw" => {
            if method != "POST" {
                return method_not_allowed(method, path);
            }
            if body.len() > MAX_BODY_BYTES {
                return Response::error(413, format!("request body of {} bytes; at most {MAX_BODY_BYTES}", body.len()));
            }
            match parse_throw_request(body).and_then(|r| simulate(folder, &r)) {
                Ok(t) => match serde_json::to_value(&t) {
                    Ok(v) => Response::json(200, &v),
                    Err(e) => Response::error(500, e.to_string()),
                },
                Err((status, message)) => Response::error(status, message),
            }
        }
        _ => match page_or_asset(path) {
            Some(r) => get_only(r),
            None => Response::error(404, format!("no route {path}")),
        },
    }
}

fn method_not_allowed(method: &str, path: &str) -> Response {
    Response::error(405, format!("{method} is not allowed on {path}"))
}

/// Parses and checks a throw request body; the error is an HTTP status and a message.
pub fn parse_throw_request(body: &[u8]) -> Result<ThrowRequest, (u16, String)> {
    // JSON has no NaN or infinity, so serde_json already rejects them (and numbers that
    // overflow f64); the ranges are checked here.
    let r: ThrowRequest = serde_json::from_slice(body).map_err(|e| (400, format!("malformed throw request: {e}")))?;
    let bad = |m: String| Err((400, m));
    if r.from.iter().any(|x| !x.is_finite() || x.abs() > MAX_THROW_COORDINATE) {
        return bad(format!("from {:?} must be finite with |coordinates| <= {MAX_THROW_COORDINATE} m", r.from));
    }
    let len = r.dir.iter().map(|x| x * x).sum::<f64>().sqrt();
    if r.dir.iter().any(|x| !x.is_finite()) || !(len.is_finite() && len > 1e-9) {
        return bad(format!("dir {:?} must be finite and not zero", r.dir));
    }
    if !(r.speed.is_finite() && (0.0..=MAX_THROW_SPEED).contains(&r.speed)) {
        return bad(format!("speed {} must be within 0..={MAX_THROW_SPEED} m/s", r.speed));
    }
    if let Some(s) = r.seconds {
        if !(s.is_finite() && s > 0.0 && s <= MAX_THROW_SECONDS) {
            return bad(format!("seconds {s} must be within 0..={MAX_THROW_SECONDS}"));
        }
    }
    Ok(r)
}

/// Simulates one throw against the folder's collision mesh with the same physics as
/// `semrecon throw`.
pub fn simulate(folder: &ViewerFolder, r: &ThrowRequest) -> Result<Throw, (u16, String)> {
    let physics = |e: PhysicsError| match e {
        PhysicsError::InvalidArgument(m) => (400, m),
        other => (500, other.to_string()),
    };
    let v = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let mut scene = ArScene::new(folder.materials.clone(), folder.config).map_err(physics)?;
    scene.replace_collision_mesh(folder.collision.clone()).map_err(physics)?;
    let ball = scene.throw_ball(v(r.from), v(r.dir), r.speed as f32).map_err(physics)?;
    let throws = scene.simulate(r.seconds.unwrap_or(DEFAULT_THROW_SECONDS) as f32).map_err(physics)?;
    throws.into_iter().nth(ball.0).ok_or((500, "the ball was lost".to_string()))
}

/// The class palette: `[{id, name, color: [r, g, b]}]` in class order.
pub fn palette_json() -> Value {
    Value::Array(
        SemanticClass::ALL.iter().map(|c| json!({ "id": c.id(), "name": c.name(), "color": c.color() })).collect(),
    )
}

/// `GET /api/info`.
pub fn info_json(folder: &ViewerFolder) -> Value {
    let bounds = folder.display.bounds().map(|(lo, hi)| json!({ "min": lo.to_array(), "max": hi.to_array() }));
    json!({
        "mesh": file_name(&folder.mesh_path),
        "triangles": folder.source_triangles,
        "display_triangles": folder.display.triangles.len(),
        "display_vertices": folder.display.positions.len(),
        "labelled": folder.labelled,
        "notes": folder.notes,
        "palette": palette_json(),
        "bounds": bounds,
        "has_trajectory": folder.trajectory.is_some(),
        "ball_radius": folder.config.ball_radius,
        "up": folder.config.up.to_array(),
        "floor_height": folder.config.floor_height,
        "floor_plane_drop": semrecon_physics::FLOOR_PLANE_DROP,
    })
}

/// `GET /api/materials`: `{unlabelled: {restitution, friction}, classes: [{id, name, color, restitution, friction}]}`.
pub fn materials_json(materials: &MaterialTable) -> Value {
    let classes: Vec<Value> = SemanticClass::ALL
        .iter()
        .map(|&c| {
            let m = materials.class(c);
            json!({ "id": c.id(), "name": c.name(), "color": c.color(), "restitution": m.restitution, "friction": m.friction })
        })
        .collect();
    let u = materials.unlabelled();
    json!({ "unlabelled": { "restitution": u.restitution, "friction": u.friction }, "classes": classes })
}

/// `GET /api/trajectory`: `{file, timestamps, positions: [[x,y,z]], forward: [[x,y,z]]}`
/// (camera centres and optical axes, world frame), or `None` without a trajectory.
pub fn trajectory_json(folder: &ViewerFolder) -> Option<Value> {
    let (path, t) = folder.trajectory.as_ref()?;
    let positions: Vec<[f32; 3]> = t.poses.iter().map(|p| Vec3::from(p.translation).to_array()).collect();
    let forward: Vec<[f32; 3]> = t.poses.iter().map(|p| camera_forward(p).to_array()).collect();
    Some(json!({ "file": file_name(path), "timestamps": t.timestamps, "positions": positions, "forward": forward }))
}

/// The optical axis (camera +z) of a `world_from_camera` pose, in the world frame.
fn camera_forward(world_from_camera: &glam::Affine3A) -> Vec3 {
    Vec3::from(world_from_camera.matrix3.z_axis).normalize_or_zero()
}

/// `count` throws for the static export, replayed on click: from evenly spaced poses of the
/// trajectory along the camera's view (tossed slightly upwards), or, without a trajectory
/// (or one shorter than 1 m), from the middle of the room in evenly spaced directions.
pub fn precomputed_throws(folder: &ViewerFolder, count: usize) -> Vec<(ThrowRequest, Throw)> {
    let speed = 4.0;
    let up = folder.config.up;
    // A camera that barely moved would give the same throw `count` times.
    let path_length = |t: &semrecon_data::Trajectory| -> f32 {
        t.poses.windows(2).map(|w| Vec3::from(w[1].translation).distance(Vec3::from(w[0].translation))).sum()
    };
    let requests: Vec<ThrowRequest> = match &folder.trajectory {
        Some((_, t)) if !t.is_empty() && path_length(t) >= 1.0 => (0..count)
            .map(|k| {
                let i = if count > 1 { k * (t.len() - 1) / (count - 1) } else { 0 };
                let forward = camera_forward(&t.poses[i]);
                let from = Vec3::from(t.poses[i].translation) + forward * 0.1;
                let dir = (forward + up * 0.25).normalize_or(up);
                request(from, dir, speed)
            })
            .collect(),
        _ => {
            let (lo, hi) = folder.display.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
            // Heights along up of the box's corners: the room's floor and ceiling when the
            // mesh frame is tilted.
            let heights: Vec<f32> = (0..8)
                .map(|c| Vec3::new([lo.x, hi.x][c & 1], [lo.y, hi.y][(c >> 1) & 1], [lo.z, hi.z][c >> 2]).dot(up))
                .collect();
            let (low, high) =
                heights.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &h| (a.min(h), b.max(h)));
            let mid = (lo + hi) * 0.5;
            let centre = mid + up * (low + (high - low).min(2.5) * 0.6 - mid.dot(up));
            let (e1, e2) = up.any_orthonormal_pair();
            (0..count)
                .map(|k| {
                    let a = k as f32 / count.max(1) as f32 * std::f32::consts::TAU;
                    request(centre, (e1 * a.cos() + e2 * a.sin() + up * 0.3).normalize(), speed)
                })
                .collect()
        }
    };
    requests.into_iter().filter_map(|r| simulate(folder, &r).ok().map(|t| (r, t))).collect()
}

fn request(from: Vec3, dir: Vec3, speed: f64) -> ThrowRequest {
    let d = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
    ThrowRequest { from: d(from), dir: d(dir), speed, seconds: Some(DEFAULT_THROW_SECONDS) }
}
