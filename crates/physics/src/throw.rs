//! The entry point of `semrecon throw`: load a labelled PLY mesh and optional materials
//! file, throw one ball, return its trajectory. Every user input is checked here or in
//! [`ArScene`], so bad input is an error and never a panic.

use std::path::Path;

use glam::Vec3;
use semrecon_data::{read_ply_with_gravity, LabeledMesh};

use crate::error::{PhysicsError, Result};
use crate::materials::MaterialTable;
use crate::scene::{ArScene, SceneConfig, Throw};

/// Throws one ball into the mesh of `mesh_path` from `from` along `dir` at `speed` m/s and
/// simulates `seconds`, with the materials of `materials_path` (defaults when `None`).
/// A mesh without labels works with the unlabelled material; the result then carries a
/// warning. Gravity pulls against the up direction the file records (a reconstruction's
/// mesh, in its dataset's frame), +z when it records none; a floor height it records puts a
/// ground plane under the scan's holes ([`SceneConfig::floor_height`]).
pub fn throw_from_ply(
    mesh_path: &Path,
    materials_path: Option<&Path>,
    from: Vec3,
    dir: Vec3,
    speed: f32,
    seconds: f32,
) -> Result<Throw> {
    let materials = match materials_path {
        Some(p) => MaterialTable::load(p)?,
        None => MaterialTable::defaults(),
    };
    let (mesh, gravity) = read_ply_with_gravity(mesh_path)?;
    if mesh.triangles.is_empty() {
        return Err(PhysicsError::Mesh(format!("{}: the mesh has no triangles", mesh_path.display())));
    }
    throw_into_mesh(&mesh, materials, SceneConfig::default().with_gravity(gravity), from, dir, speed, seconds)
}

/// [`throw_from_ply`] for a mesh in memory, with explicit settings.
pub fn throw_into_mesh(
    mesh: &LabeledMesh,
    materials: MaterialTable,
    config: SceneConfig,
    from: Vec3,
    dir: Vec3,
    speed: f32,
    seconds: f32,
) -> Result<Throw> {
    let mut scene = ArScene::with_mesh(mesh, materials, config)?;
    // Check the throw before paying for the simulation.
    let ball = scene.throw_ball(from, dir, speed)?;
    let throws = scene.simulate(seconds)?;
    throws.into_iter().nth(ball.0).ok_or_else(|| PhysicsError::InvalidArgument("the ball was lost".into()))
}
