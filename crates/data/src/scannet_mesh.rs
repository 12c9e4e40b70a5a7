//! ScanNet labelled meshes (`SCENE/SCENE_vh_clean_2.labels.ply`): binary PLY with vertex
//! `x y z` float, `red green blue alpha` uchar and `label` ushort holding an NYU-40 class
//! id, plus faces. Read through [`crate::ply`] and relabelled to the 13 S3DIS classes with
//! [`nyu40_to_class`], so ScanNet scenes can train and test the same network as S3DIS.

use std::path::{Path, PathBuf};

use crate::class::{SemanticClass, UNLABELED};
use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;
use crate::ply::{mesh_from_ply, PlyFile, PropertyData};

/// Maps an NYU-40 class id (as in ScanNet's `label` property) to one of the 13 classes.
///
/// | NYU-40 id and name | class |
/// |---|---|
/// | 0 (unannotated) | `None` (unlabelled) |
/// | 1 wall | wall |
/// | 2 floor, 20 floor mat | floor (a mat is part of the walkable floor surface) |
/// | 22 ceiling | ceiling |
/// | 8 door | door |
/// | 9 window, 13 blinds, 16 curtain | window (they cover windows; S3DIS window annotations include what hangs in them) |
/// | 5 chair | chair |
/// | 6 sofa | sofa |
/// | 7 table, 12 counter, 14 desk | table |
/// | 10 bookshelf, 15 shelves | bookcase |
/// | 30 whiteboard | board |
/// | 11 picture | clutter (S3DIS `board` means writing boards; framed pictures and posters are clutter there) |
/// | every other id 3..=40 (cabinet, bed, ..., otherstructure, otherfurniture, otherprop) | clutter |
/// | above 40 | `None`: not an NYU-40 id |
///
/// ScanNet has no beam or column annotations, so those classes never appear.
pub fn nyu40_to_class(id: u16) -> Option<SemanticClass> {
    use SemanticClass::*;
    Some(match id {
        1 => Wall,
        2 | 20 => Floor,
        22 => Ceiling,
        8 => Door,
        9 | 13 | 16 => Window,
        5 => Chair,
        6 => Sofa,
        7 | 12 | 14 => Table,
        10 | 15 => Bookcase,
        30 => Board,
        3..=40 => Clutter,
        _ => return None,
    })
}

/// The labelled mesh of a ScanNet scene folder `SCENE/` (`SCENE/SCENE_vh_clean_2.labels.ply`).
pub fn scannet_labels_path(scene: &Path) -> PathBuf {
    let name = scene.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    scene.join(format!("{name}_vh_clean_2.labels.ply"))
}

/// Reads a ScanNet labelled mesh, given the `.labels.ply` file or its scene folder, into a
/// [`LabeledMesh`] whose vertex labels are class ids ([`UNLABELED`] for NYU-40 id 0).
/// A `label` value above 40 is an error (the file is not an NYU-40 labelled mesh).
pub fn read_scannet_mesh(path: impl AsRef<Path>) -> Result<LabeledMesh> {
    let given = path.as_ref();
    let path = if given.is_dir() { scannet_labels_path(given) } else { given.to_path_buf() };
    let mut ply = PlyFile::read(&path)?;
    let vertex =
        ply.element_mut("vertex").ok_or_else(|| DataError::parse(&path, None, "PLY file has no 'vertex' element"))?;
    let label = vertex
        .remove_property("label")
        .ok_or_else(|| DataError::parse(&path, None, "vertex element has no 'label' property (NYU-40 ids)"))?;
    let PropertyData::Scalar(column) = label.data else {
        return Err(DataError::parse(&path, None, "vertex 'label' is a list, expected an integer scalar"));
    };
    if !column.scalar_type().is_integer() {
        return Err(DataError::parse(&path, None, "vertex 'label' is not of an integer type"));
    }
    let mut labels = Vec::with_capacity(column.len());
    for i in 0..column.len() {
        let id = column.get_i64(i).unwrap_or(-1);
        labels.push(match id {
            0 => UNLABELED,
            1..=40 => nyu40_to_class(id as u16).map_or(UNLABELED, |c| c.id()),
            _ => {
                return Err(DataError::parse(
                    &path,
                    None,
                    format!("vertex {i} has label {id}, not an NYU-40 id (0..=40): is this a *_vh_clean_2.labels.ply?"),
                ))
            }
        });
    }
    let mut mesh = mesh_from_ply(&ply, &path)?;
    mesh.vertex_labels = labels;
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_covers_every_id() {
        assert_eq!(nyu40_to_class(0), None);
        assert_eq!(nyu40_to_class(41), None);
        assert_eq!(nyu40_to_class(1), Some(SemanticClass::Wall));
        assert_eq!(nyu40_to_class(14), Some(SemanticClass::Table));
        assert_eq!(nyu40_to_class(30), Some(SemanticClass::Board));
        assert_eq!(nyu40_to_class(40), Some(SemanticClass::Clutter));
        let produced: std::collections::BTreeSet<_> = (1..=40).filter_map(nyu40_to_class).collect();
        assert_eq!(produced.len(), 11, "all classes but beam and column: {produced:?}");
    }

    #[test]
    fn scene_folder_resolves_to_labels_file() {
        assert_eq!(
            scannet_labels_path(Path::new("/d/scene0000_00")),
            Path::new("/d/scene0000_00/scene0000_00_vh_clean_2.labels.ply")
        );
    }
}
