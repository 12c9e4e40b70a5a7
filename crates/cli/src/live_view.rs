//! The live viewer of `run --serve` and `live --serve`: the viewer of `semrecon view` served on
//! 127.0.0.1, following a run; the mesh and trajectory are pushed to it at keyframes, at most
//! once per [`LIVE_PUSH_INTERVAL`] of wall time.

use std::time::{Duration, Instant};

use crate::reconstruction::output_gravity;
use anyhow::Context;
use semrecon_data::{LabeledMesh, Trajectory};
use semrecon_pipeline::Pipeline;
use semrecon_viewer::{LiveScene, ViewerServer};

/// Shortest wall time between two pushes to the live viewer: building the whole mesh and
/// its collision geometry costs far more than a keyframe's incremental meshing.
pub const LIVE_PUSH_INTERVAL: Duration = Duration::from_secs(1);

/// The live-viewer flags of `run` and `live`.
#[derive(clap::Args, Debug, Clone)]
pub struct ServeArgs {
    /// Show the growing map live in the viewer on 127.0.0.1 (open the printed URL), and keep
    /// serving the final result after the run or session until Ctrl-C.
    #[arg(long)]
    pub serve: bool,
    /// Port of the live viewer (a free port by default).
    #[arg(long, requires = "serve")]
    pub port: Option<u16>,
    /// Stop the live viewer when the run or session ends instead of serving on (for scripts
    /// and tests).
    #[arg(long, requires = "serve")]
    pub serve_exit: bool,
}

/// The live viewer of `--serve`.
pub struct LiveView {
    /// The HTTP server.
    pub server: ViewerServer,
    scene: LiveScene,
    /// Fused frame count at the last push (the map has not changed while it is the same).
    pushed_at: Option<usize>,
    last_push: Option<Instant>,
}

impl LiveView {
    /// Starts the server (on `port`, or a free one).
    pub fn start(port: Option<u16>) -> anyhow::Result<Self> {
        let (server, scene) = ViewerServer::start_live(port).context("starting the live viewer")?;
        Ok(Self { server, scene, pushed_at: None, last_push: None })
    }

    /// For `--serve`: starts the viewer and prints its address (`what` follows: "the run", "the
    /// session"); `None` without `--serve`.
    pub fn serve(args: &ServeArgs, what: &str) -> anyhow::Result<Option<Self>> {
        if !args.serve {
            return Ok(None);
        }
        let live = Self::start(args.port)?;
        println!("live viewer at {} (follows {what}; open it in a browser)", live.server.url());
        Ok(Some(live))
    }

    /// Whether the map changed since the last push and the push interval has passed.
    pub fn due(&self, fused: usize) -> bool {
        self.pushed_at != Some(fused) && self.last_push.is_none_or(|t| t.elapsed() >= LIVE_PUSH_INTERVAL)
    }

    /// Shows `mesh` and `trajectory` in a map frame whose gravity is `gravity` (when known);
    /// an empty mesh (nothing surfaced yet) is skipped.
    pub fn push(
        &mut self,
        fused: usize,
        mesh: &LabeledMesh,
        trajectory: &Trajectory,
        gravity: Option<semrecon_data::MeshGravity>,
    ) -> Result<(), String> {
        if mesh.triangles.is_empty() {
            return Ok(());
        }
        self.scene.update(mesh, trajectory, gravity).map_err(|e| format!("live viewer not updated: {e}"))?;
        self.pushed_at = Some(fused);
        self.last_push = Some(Instant::now());
        Ok(())
    }

    /// At a keyframe (where the incremental mesh was just brought up to date) and when a push
    /// is due, shows the pipeline's mesh; how long that took, `None` when nothing was pushed.
    pub fn push_at_keyframe(&mut self, pipeline: &Pipeline, keyframe_every: usize) -> Result<Option<Duration>, String> {
        let fused = pipeline.frame_counts().1;
        if fused == 0 || !fused.is_multiple_of(keyframe_every.max(1)) || !self.due(fused) {
            return Ok(None);
        }
        let t = Instant::now();
        let mesh = pipeline.mesh();
        self.push(fused, &mesh, pipeline.trajectory(), output_gravity(pipeline, &mesh))?;
        Ok(Some(t.elapsed()))
    }
}
