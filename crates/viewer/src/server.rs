//! The local HTTP/1.1 server of `semrecon view`, on `tiny_http` (small, synchronous, builds
//! in seconds; an async stack would be far more than a single-user page needs). It listens
//! on 127.0.0.1 only: the page can make the machine simulate, so it must not be reachable
//! from the network. A few worker threads share the listener so that a throw being
//! simulated does not stall the page's other requests.
//!
//! The server shows either a folder's fixed scene ([`ViewerServer::start`]) or a live one
//! that a running reconstruction replaces as it goes ([`ViewerServer::start_live`]).

use std::io::Read;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::error::{Result, ViewerError};
use crate::folder::ViewerFolder;
use crate::live::{LiveScene, SceneSlot};
use crate::routes::{handle_scene, Response, MAX_BODY_BYTES};

/// Worker threads answering requests.
const WORKERS: usize = 4;

/// A running viewer server; [`ViewerServer::stop`] ends it (dropping it leaves it running
/// until the process exits).
pub struct ViewerServer {
    server: Arc<tiny_http::Server>,
    addr: SocketAddr,
    stopping: Arc<AtomicBool>,
    workers: Vec<JoinHandle<()>>,
}

impl ViewerServer {
    /// Serves `folder` on 127.0.0.1 at `port`, or at a free port when `None`.
    pub fn start(folder: ViewerFolder, port: Option<u16>) -> Result<Self> {
        Self::start_slot(Arc::new(SceneSlot::fixed(folder)), port)
    }

    /// Serves a live scene on 127.0.0.1 at `port` (a free port when `None`): nothing until
    /// the first [`LiveScene::update`] (the page waits), then each update's mesh and
    /// trajectory. The page polls `GET /api/version` and reloads on a change.
    pub fn start_live(port: Option<u16>) -> Result<(Self, LiveScene)> {
        let slot = Arc::new(SceneSlot::live());
        let server = Self::start_slot(slot.clone(), port)?;
        Ok((server, LiveScene::new(slot)))
    }

    fn start_slot(slot: Arc<SceneSlot>, port: Option<u16>) -> Result<Self> {
        let wanted = format!("127.0.0.1:{}", port.unwrap_or(0));
        let bind_err = |message: String| ViewerError::Bind { addr: wanted.clone(), message };
        let server = tiny_http::Server::http(wanted.as_str()).map_err(|e| bind_err(e.to_string()))?;
        let addr = server.server_addr().to_ip().ok_or_else(|| bind_err("not an IP address".into()))?;
        let server = Arc::new(server);
        let stopping = Arc::new(AtomicBool::new(false));
        let workers = (0..WORKERS)
            .map(|_| {
                let (server, slot, stopping) = (server.clone(), slot.clone(), stopping.clone());
                std::thread::spawn(move || loop {
                    match server.recv() {
                        Ok(request) => answer(&slot, request),
                        // Errors are failed accepts (a client gone); only a stop ends the loop.
                        Err(_) if stopping.load(Ordering::SeqCst) => break,
                        Err(_) => continue,
                    }
                })
            })
            .collect();
        Ok(Self { server, addr, stopping, workers })
    }

    /// The address listened on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's address, `http://127.0.0.1:PORT/`.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Blocks until the server stops (in practice until the process is interrupted).
    pub fn wait(self) {
        for w in self.workers {
            let _ = w.join();
        }
    }

    /// Stops accepting requests and waits for the workers to finish their current request.
    pub fn stop(self) {
        self.stopping.store(true, Ordering::SeqCst);
        for _ in &self.workers {
            self.server.unblock();
        }
        self.wait();
    }
}

/// Loads `dir` (see [`ViewerFolder::load`]), starts the server on 127.0.0.1 (at `port`, or a
/// free port) and prints its address. The caller waits on or stops the returned server.
pub fn serve(dir: &Path, port: Option<u16>) -> Result<ViewerServer> {
    let folder = ViewerFolder::load(dir, None)?;
    print_summary(&folder);
    let server = ViewerServer::start(folder, port)?;
    println!("semrecon viewer at {} (Ctrl-C to stop)", server.url());
    Ok(server)
}

/// Prints what the viewer shows and its notes.
pub fn print_summary(folder: &ViewerFolder) {
    println!(
        "mesh {} ({} triangles{}), trajectory {}",
        folder.mesh_path.display(),
        folder.source_triangles,
        if folder.labelled { ", labelled" } else { ", no labels" },
        folder
            .trajectory
            .as_ref()
            .map(|(p, t)| format!("{} ({} poses)", p.display(), t.len()))
            .unwrap_or("none".into())
    );
    for n in &folder.notes {
        println!("note: {n}");
    }
}

fn answer(slot: &SceneSlot, mut request: tiny_http::Request) {
    let method = request.method().as_str().to_string();
    let url = request.url().to_string();
    let host = request.headers().iter().find(|h| h.field.equiv("Host")).map(|h| h.value.as_str().to_string());
    let response = if !host.as_deref().is_none_or(is_local_host) {
        Response::error(403, "the viewer only answers pages on 127.0.0.1 or localhost")
    } else if request.body_length().is_some_and(|n| n > MAX_BODY_BYTES) {
        Response::error(413, format!("request body over {MAX_BODY_BYTES} bytes"))
    } else {
        // Bodies without a length (chunked) are read up to the limit plus one byte, enough
        // to tell an oversized one.
        let mut body = Vec::new();
        match request.as_reader().take(MAX_BODY_BYTES as u64 + 1).read_to_end(&mut body) {
            Ok(_) if body.len() > MAX_BODY_BYTES => {
                Response::error(413, format!("request body over {MAX_BODY_BYTES} bytes"))
            }
            Ok(_) => {
                let (folder, version) = slot.current();
                handle_scene(folder.as_deref(), version, slot.is_live(), &method, &url, &body)
            }
            Err(e) => Response::error(400, format!("cannot read the request body: {e}")),
        }
    };
    let mut r = tiny_http::Response::from_data(response.body).with_status_code(response.status);
    for (k, v) in [("Content-Type", response.content_type), ("Cache-Control", "no-store")] {
        if let Ok(h) = tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()) {
            r.add_header(h);
        }
    }
    // A client that hung up is not the server's problem.
    let _ = request.respond(r);
}

/// Whether a `Host` header names this machine. Binding to 127.0.0.1 keeps other machines
/// out, but a web site could still reach the server through DNS rebinding (its own name
/// resolving to 127.0.0.1); such requests carry the site's name as `Host` and are refused.
fn is_local_host(host: &str) -> bool {
    let name = match host.rsplit_once(':') {
        Some((name, port)) if port.chars().all(|c| c.is_ascii_digit()) => name,
        _ => host,
    };
    matches!(name.to_ascii_lowercase().as_str(), "127.0.0.1" | "localhost" | "[::1]")
}

#[cfg(test)]
mod tests {
    #[test]
    fn local_hosts() {
        for h in ["127.0.0.1:8080", "localhost", "LOCALHOST:1", "[::1]:80", "127.0.0.1"] {
            assert!(super::is_local_host(h), "{h}");
        }
        for h in ["evil.example", "evil.example:8080", "127.0.0.1.evil.example", "10.0.0.1:80", ""] {
            assert!(!super::is_local_host(h), "{h}");
        }
    }
}
