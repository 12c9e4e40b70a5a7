//! What the viewer shows, read from one folder: the mesh (picked by name, see
//! [`find_mesh`]), the camera trajectory if there is one, and the material table. The
//! collision geometry is built once here so that each throw only pays for the simulation.

use std::path::{Path, PathBuf};

use semrecon_data::{read_ply_with_gravity, LabeledMesh, MeshGravity, Trajectory};
use semrecon_physics::{CollisionMesh, MaterialTable, SceneConfig};

use crate::decimate::{decimate_for_display, MAX_DISPLAY_TRIANGLES};
use crate::error::{Result, ViewerError};

/// Mesh file names tried in order: the reconstruction of `run`/`demo`, the scene of
/// `semrecon synth`, the ground truth of `demo`. Any other `*.ply` comes after these, by name.
pub const MESH_NAMES: [&str; 3] = ["mesh.ply", "scene.ply", "ground_truth.ply"];

/// Trajectory file names tried in order: the estimated path of `run`/`demo`, then the
/// ground truth of a `synth` or TUM dataset folder.
pub const TRAJECTORY_NAMES: [&str; 2] = ["trajectory.txt", "groundtruth.txt"];

/// The contents of a viewer folder, ready to serve.
#[derive(Debug, Clone)]
pub struct ViewerFolder {
    /// The mesh file shown.
    pub mesh_path: PathBuf,
    /// The mesh sent to the browser (decimated when the file is very large).
    pub display: LabeledMesh,
    /// Triangles of the mesh file before decimation.
    pub source_triangles: usize,
    /// Whether the mesh has semantic labels (per vertex or per triangle).
    pub labelled: bool,
    /// The trajectory file and its poses, when the folder has one.
    pub trajectory: Option<(PathBuf, Trajectory)>,
    /// Contact materials per class.
    pub materials: MaterialTable,
    /// Simulation settings of every throw.
    pub config: SceneConfig,
    /// Collision geometry of the full-resolution mesh.
    pub collision: CollisionMesh,
    /// Things the page should tell the user (no labels, decimated, unreadable trajectory).
    pub notes: Vec<String>,
}

/// The mesh file of `dir`: the first of [`MESH_NAMES`] present, else the first `*.ply` by name.
/// `dir` may also be a PLY file itself.
pub fn find_mesh(dir: &Path) -> Result<PathBuf> {
    if dir.is_file() {
        return Ok(dir.to_path_buf());
    }
    if !dir.is_dir() {
        return Err(ViewerError::NoMesh { dir: dir.to_path_buf(), message: "no such folder".into() });
    }
    if let Some(p) = MESH_NAMES.iter().map(|n| dir.join(n)).find(|p| p.is_file()) {
        return Ok(p);
    }
    let entries = std::fs::read_dir(dir).map_err(|e| semrecon_data::DataError::io(dir, e))?;
    let mut plys: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")))
        .collect();
    plys.sort();
    plys.into_iter().next().ok_or_else(|| ViewerError::NoMesh {
        dir: dir.to_path_buf(),
        message: format!("no mesh: expected one of {} or another *.ply file", MESH_NAMES.join(", ")),
    })
}

impl ViewerFolder {
    /// Reads `dir` (an output folder of `run`/`demo`, a `synth` dataset, any folder with a
    /// PLY mesh, or a PLY file) with the materials of `materials` (defaults when `None`).
    /// The trajectory is the first of [`TRAJECTORY_NAMES`] in the folder (the PLY file's
    /// folder when a file is given).
    pub fn load(dir: &Path, materials: Option<&Path>) -> Result<Self> {
        let mesh_path = find_mesh(dir)?;
        let (mesh, gravity) = read_ply_with_gravity(&mesh_path)?;
        if mesh.triangles.is_empty() {
            return Err(ViewerError::NoMesh {
                dir: mesh_path.clone(),
                message: "the mesh has no triangles (a point cloud cannot be viewed or collided with)".into(),
            });
        }
        let materials = match materials {
            Some(p) => MaterialTable::load(p)?,
            None => MaterialTable::defaults(),
        };
        Self::from_mesh(mesh_path, mesh, materials, dir, gravity)
    }

    /// As [`ViewerFolder::load`] for a mesh already in memory; the trajectory is looked for
    /// in `dir`, or in its parent folder when `dir` is a file. `gravity` is the mesh frame's
    /// up direction and floor (+z and no ground plane when `None`).
    pub fn from_mesh(
        mesh_path: PathBuf,
        mesh: LabeledMesh,
        materials: MaterialTable,
        dir: &Path,
        gravity: Option<MeshGravity>,
    ) -> Result<Self> {
        let config = SceneConfig::default().with_gravity(gravity);
        let collision = CollisionMesh::build(&mesh, &config.collision)?;
        let labelled = !mesh.vertex_labels.is_empty() || !mesh.triangle_labels.is_empty();
        let mut notes = Vec::new();
        if !labelled {
            notes.push(format!(
                "{} has no semantic labels: every surface uses the unlabelled material",
                file_name(&mesh_path)
            ));
        }
        let source_triangles = mesh.triangles.len();
        let display = decimate_for_display(&mesh, MAX_DISPLAY_TRIANGLES);
        if display.triangles.len() < source_triangles {
            notes.push(format!(
                "the mesh has {source_triangles} triangles: the browser shows a simplified copy of {} (throws use the full mesh)",
                display.triangles.len()
            ));
        }
        let mut trajectory = None;
        // For a PLY file given directly, its folder holds the trajectory.
        let traj_dir = if dir.is_dir() { Some(dir) } else { dir.parent() };
        if let Some(traj_dir) = traj_dir {
            if let Some(p) = TRAJECTORY_NAMES.iter().map(|n| traj_dir.join(n)).find(|p| p.is_file()) {
                match Trajectory::read_any(&p) {
                    Ok(t) if !t.is_empty() => trajectory = Some((p, t)),
                    Ok(_) => notes.push(format!("{} has no poses", file_name(&p))),
                    Err(e) => notes.push(format!("trajectory not shown: {e}")),
                }
            }
        }
        Ok(Self { mesh_path, display, source_triangles, labelled, trajectory, materials, config, collision, notes })
    }
}

impl ViewerFolder {
    /// The scene of a live reconstruction: `mesh` as it stands (decimated for display like a
    /// file's mesh) and the camera path so far, with default materials. `name` is what the
    /// page shows in place of a file name; `gravity` the map's up direction and floor when
    /// known. An empty mesh is an error (nothing to collide with).
    pub fn live(name: &str, mesh: &LabeledMesh, trajectory: &Trajectory, gravity: Option<MeshGravity>) -> Result<Self> {
        if mesh.triangles.is_empty() {
            return Err(ViewerError::NoMesh {
                dir: PathBuf::from(name),
                message: "the live mesh has no triangles yet".into(),
            });
        }
        // No folder: from_mesh then finds no trajectory file, and the live poses go in instead.
        let mut folder =
            Self::from_mesh(PathBuf::from(name), mesh.clone(), MaterialTable::defaults(), Path::new(""), gravity)?;
        if !trajectory.is_empty() {
            folder.trajectory = Some((PathBuf::from("trajectory (live)"), trajectory.clone()));
        }
        Ok(folder)
    }
}

pub(crate) fn file_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| p.display().to_string())
}
