//! A labelled, coloured point cloud: the training and evaluation sample of the semantic
//! network (S3DIS rooms are point clouds; labelled meshes become one point per vertex).

use glam::Vec3;

use crate::class::{SemanticClass, UNLABELED};
use crate::mesh::LabeledMesh;

/// Points with a colour and a class id each.
///
/// Invariants (checked by [`LabeledPointCloud::validate`]): the three vectors have the
/// same length; positions are finite; labels are class ids (0..13) or [`UNLABELED`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabeledPointCloud {
    /// Positions, metres.
    pub positions: Vec<Vec3>,
    /// Colours, sRGB.
    pub colors: Vec<[u8; 3]>,
    /// Class ids (0..13) or [`UNLABELED`].
    pub labels: Vec<u8>,
}

impl LabeledPointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there is no point.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks the invariants listed on the type; the message says which one fails.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.positions.len();
        if self.colors.len() != n || self.labels.len() != n {
            return Err(format!("{n} positions, {} colours and {} labels", self.colors.len(), self.labels.len()));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(format!("point {i} has a non-finite position"));
        }
        if let Some(i) = self.labels.iter().position(|&l| l != UNLABELED && SemanticClass::from_id(l).is_none()) {
            return Err(format!("point {i} has label {}, not a class id or UNLABELED", self.labels[i]));
        }
        Ok(())
    }

    /// One point per vertex of `mesh`, labelled by its vertex labels or else by the label of
    /// the first triangle using the vertex ([`LabeledMesh::vertex_labels_or_from_triangles`]);
    /// vertices without a label, or with a label that is not a class id, are [`UNLABELED`].
    pub fn from_mesh(mesh: &LabeledMesh) -> Self {
        let labels = mesh
            .vertex_labels_or_from_triangles()
            .into_iter()
            .map(|l| if SemanticClass::from_id(l).is_some() { l } else { UNLABELED })
            .collect();
        Self { positions: mesh.positions.clone(), colors: mesh.colors.clone(), labels }
    }

    /// A mesh without triangles holding the points as vertices with vertex labels (for
    /// writing the cloud with [`crate::ply::write_ply`]).
    pub fn to_mesh(&self) -> LabeledMesh {
        LabeledMesh {
            positions: self.positions.clone(),
            colors: self.colors.clone(),
            vertex_labels: self.labels.clone(),
            ..Default::default()
        }
    }
}

impl From<&LabeledMesh> for LabeledPointCloud {
    fn from(mesh: &LabeledMesh) -> Self {
        Self::from_mesh(mesh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_mesh_uses_triangle_labels_and_round_trips() {
        let mesh = LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            colors: vec![[1, 2, 3]; 4],
            triangles: vec![[0, 1, 2]],
            triangle_labels: vec![SemanticClass::Chair.id()],
            ..Default::default()
        };
        let cloud = LabeledPointCloud::from(&mesh);
        cloud.validate().expect("valid");
        assert_eq!(cloud.labels, vec![7, 7, 7, UNLABELED]);
        assert_eq!(LabeledPointCloud::from_mesh(&cloud.to_mesh()), cloud);
    }

    #[test]
    fn validate_rejects_bad_clouds() {
        let mut c = LabeledPointCloud { positions: vec![Vec3::ZERO], colors: vec![[0; 3]], labels: vec![13] };
        assert!(c.validate().expect_err("invalid").contains("label 13"));
        c.labels = vec![];
        assert!(c.validate().is_err());
        c.labels = vec![0];
        c.positions[0].x = f32::NAN;
        assert!(c.validate().expect_err("invalid").contains("non-finite"));
    }
}
