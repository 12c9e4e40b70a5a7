//! The scene of a running reconstruction (`semrecon run --serve`): the server answers from
//! whatever scene is current, and the reconstruction swaps in a newer one as the map grows.
//! Each swap bumps a version number that the page polls (`GET /api/version`), so the page
//! downloads the mesh again only when there is a new one. Requests take a reference to the
//! current scene and release the lock at once, so a slow download never holds up an update.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, RwLock};

use semrecon_data::{LabeledMesh, Trajectory};

use crate::error::Result;
use crate::folder::ViewerFolder;

/// Name shown by the page in place of a mesh file name.
pub const LIVE_MESH_NAME: &str = "live reconstruction";

/// What the server shows, shared between its workers and (when live) a [`LiveScene`].
#[derive(Debug)]
pub(crate) struct SceneSlot {
    folder: RwLock<Option<Arc<ViewerFolder>>>,
    version: AtomicU64,
    live: bool,
}

impl SceneSlot {
    /// A fixed scene (`semrecon view`): version 0, never changes.
    pub(crate) fn fixed(folder: ViewerFolder) -> Self {
        Self { folder: RwLock::new(Some(Arc::new(folder))), version: AtomicU64::new(0), live: false }
    }

    /// A live slot with no scene yet (version 0).
    pub(crate) fn live() -> Self {
        Self { folder: RwLock::new(None), version: AtomicU64::new(0), live: true }
    }

    /// The current scene (none before the first live update) and its version.
    pub(crate) fn current(&self) -> (Option<Arc<ViewerFolder>>, u64) {
        // A poisoned lock only means a writer panicked mid-swap; the Arc inside is whole.
        let guard = self.folder.read().unwrap_or_else(|e| e.into_inner());
        (guard.clone(), self.version.load(Ordering::SeqCst))
    }

    /// Whether the scene can change (the page then polls the version).
    pub(crate) fn is_live(&self) -> bool {
        self.live
    }

    fn replace(&self, folder: ViewerFolder) -> u64 {
        let mut guard = self.folder.write().unwrap_or_else(|e| e.into_inner());
        *guard = Some(Arc::new(folder));
        // Bumped under the lock so that a version read with the scene never runs ahead of it.
        self.version.fetch_add(1, Ordering::SeqCst) + 1
    }
}

/// The handle a reconstruction updates the live viewer through (see
/// [`crate::ViewerServer::start_live`]). Cloning it gives another handle to the same scene.
#[derive(Debug, Clone)]
pub struct LiveScene {
    slot: Arc<SceneSlot>,
}

impl LiveScene {
    pub(crate) fn new(slot: Arc<SceneSlot>) -> Self {
        Self { slot }
    }

    /// Shows `mesh` and `trajectory` (camera poses so far) from now on and returns the new
    /// version. The mesh is decimated for display and its collision geometry built here, on
    /// the caller's thread, so the cost (tens of milliseconds for a room) is the caller's to
    /// schedule. `gravity` is the map's up direction and floor when known (the viewer's and
    /// the throws' up; +z otherwise). An empty mesh is an error and leaves the scene as it was.
    pub fn update(
        &self,
        mesh: &LabeledMesh,
        trajectory: &Trajectory,
        gravity: Option<semrecon_data::MeshGravity>,
    ) -> Result<u64> {
        let folder = ViewerFolder::live(LIVE_MESH_NAME, mesh, trajectory, gravity)?;
        Ok(self.slot.replace(folder))
    }

    /// The version shown now: 0 before the first update, then one more per update.
    pub fn version(&self) -> u64 {
        self.slot.current().1
    }
}
