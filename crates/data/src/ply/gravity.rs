//! Where gravity points in a mesh's frame, recorded in its PLY header.
//!
//! A reconstruction keeps the frame of its dataset or first camera, where up is rarely +z
//! (7-Scenes' world is nearly y down), and its floor has holes where the scan saw none.
//! Physics, the viewer and `snapshot` need both: which way balls fall, and the height of a
//! ground plane that catches them where the scanned floor is missing. The header carries them
//! as comments, `semrecon up X Y Z` and `semrecon floor H`, which other PLY readers ignore.

use std::path::Path;

use glam::Vec3;

use super::{mesh_from_ply, PlyEncoding, PlyFile};
use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;

/// The comment keyword of the up direction.
const UP_KEYWORD: &str = "semrecon up";
/// The comment keyword of the floor height.
const FLOOR_KEYWORD: &str = "semrecon floor";

/// Gravity in a mesh's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshGravity {
    /// Unit up direction (gravity pulls against it).
    pub up: Vec3,
    /// Height of the floor along `up`, metres (`position.dot(up)` of a floor point), when known.
    pub floor_height: Option<f32>,
}

impl MeshGravity {
    /// Up only, no floor.
    pub fn up(up: Vec3) -> Self {
        Self { up, floor_height: None }
    }

    /// The header comments that record it; `up` is normalised.
    ///
    /// # Errors
    /// A zero or non-finite `up`, a non-finite floor height.
    pub fn comments(&self) -> std::result::Result<Vec<String>, String> {
        let Some(u) = self.up.try_normalize() else {
            return Err(format!("up direction {} is not a direction", self.up));
        };
        let mut out = vec![format!("{UP_KEYWORD} {} {} {}", u.x, u.y, u.z)];
        if let Some(h) = self.floor_height {
            if !h.is_finite() {
                return Err(format!("floor height {h} is not finite"));
            }
            out.push(format!("{FLOOR_KEYWORD} {h}"));
        }
        Ok(out)
    }

    /// What `ply`'s comments record: `None` without an up comment (a floor without one is
    /// ignored: its height means nothing without the direction); `path` names the file in
    /// errors.
    ///
    /// # Errors
    /// An up comment that is not three finite numbers, not all zero; a floor comment that is
    /// not one finite number.
    pub fn of(ply: &PlyFile, path: &Path) -> Result<Option<Self>> {
        let numbers = |text: &str| -> Option<Vec<f32>> {
            text.split_whitespace().map(|v| v.parse::<f32>().ok().filter(|x| x.is_finite())).collect()
        };
        let Some(text) = ply.comments.iter().find_map(|c| c.strip_prefix(UP_KEYWORD)) else { return Ok(None) };
        let up = match numbers(text).as_deref() {
            Some(&[x, y, z]) => Vec3::new(x, y, z).try_normalize(),
            _ => None,
        };
        let Some(up) = up else {
            return Err(DataError::parse(
                path,
                None,
                format!("comment '{UP_KEYWORD}{text}' is not an up direction (three finite numbers, not all zero)"),
            ));
        };
        let floor_height = match ply.comments.iter().find_map(|c| c.strip_prefix(FLOOR_KEYWORD)) {
            None => None,
            Some(text) => match numbers(text).as_deref() {
                Some(&[h]) => Some(h),
                _ => {
                    return Err(DataError::parse(
                        path,
                        None,
                        format!("comment '{FLOOR_KEYWORD}{text}' is not a floor height (one finite number)"),
                    ))
                }
            },
        };
        Ok(Some(Self { up, floor_height }))
    }
}

/// Writes `mesh` as PLY, atomically, its header recording `gravity` (see
/// [`super::write_ply`] for the layout).
///
/// # Errors
/// As [`super::write_ply`]; a gravity that [`MeshGravity::comments`] refuses.
pub fn write_ply_with_gravity(
    path: impl AsRef<Path>,
    mesh: &LabeledMesh,
    encoding: PlyEncoding,
    gravity: &MeshGravity,
) -> Result<()> {
    super::mesh::write_mesh_file(path.as_ref(), mesh, None, encoding, Some(gravity))
}

/// Reads a PLY mesh or point cloud and the gravity its header records (see the module
/// documentation), `None` when it records none.
///
/// # Errors
/// As [`super::read_ply`]; gravity comments that do not parse ([`MeshGravity::of`]).
pub fn read_ply_with_gravity(path: impl AsRef<Path>) -> Result<(LabeledMesh, Option<MeshGravity>)> {
    let path = path.as_ref();
    let ply = PlyFile::read(path)?;
    let gravity = MeshGravity::of(&ply, path)?;
    Ok((mesh_from_ply(&ply, path)?, gravity))
}
