//! A voxelised, labelled room: the unit that training, evaluation and the data pipeline pass
//! around. A labelled point cloud (surface samples of a synthetic room, an S3DIS room, a
//! reconstruction) becomes sorted sparse voxels with mean colour features and the majority
//! label of their points, which is what the network sees and what its loss compares with.

use semrecon_data::class::UNLABELED;
use semrecon_data::{LabeledPointCloud, SemanticClass};
use semrecon_sparse::voxelize::voxelize;
use semrecon_sparse::Coord;

use crate::error::Result;
use crate::inference::color_features;

/// Sparse voxels with features and labels.
///
/// # Shapes
/// `coords`: `[n]` (Z-order, batch 0); `features`: `[n, channels]` row-major; `labels`:
/// `[n]` class ids, [`UNLABELED`] where no labelled point fell (ignored by losses and metrics).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VoxelSample {
    /// Integer voxel coordinates `[x, y, z, batch]`.
    pub coords: Vec<Coord>,
    /// Per-voxel input features.
    pub features: Vec<f32>,
    /// Input channels per voxel.
    pub channels: usize,
    /// Per-voxel class ids.
    pub labels: Vec<u8>,
}

impl VoxelSample {
    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.coords.len()
    }

    /// Whether there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    /// Voxelises `cloud` at `voxel_size` metres: mean colour features
    /// ([`color_features`]) and the most frequent label among the voxel's labelled points
    /// (ties to the smaller class id, so the result does not depend on point order).
    ///
    /// # Errors
    /// Non-finite points or coordinates out of the key range (see
    /// [`semrecon_sparse::voxelize::voxelize`]).
    pub fn from_cloud(cloud: &LabeledPointCloud, voxel_size: f32) -> Result<Self> {
        let points: Vec<[f32; 3]> = cloud.positions.iter().map(|p| p.to_array()).collect();
        let v = voxelize(&points, &color_features(&cloud.colors), 3, voxel_size, 0)?;
        let n = v.tensor.len();
        let mut votes = vec![[0u32; SemanticClass::COUNT]; n];
        for (&voxel, &label) in v.point_to_voxel.iter().zip(&cloud.labels) {
            if (label as usize) < SemanticClass::COUNT {
                votes[voxel as usize][label as usize] += 1;
            }
        }
        let labels = votes
            .iter()
            .map(|row| {
                let (best, count) =
                    row.iter().enumerate().fold((0, 0), |acc, (c, &k)| if k > acc.1 { (c, k) } else { acc });
                if count == 0 {
                    UNLABELED
                } else {
                    best as u8
                }
            })
            .collect();
        let (coords, features) = v.tensor.into_parts();
        Ok(Self { coords, features, channels: 3, labels })
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    #[test]
    fn majority_label_and_mean_colour() {
        let cloud = LabeledPointCloud {
            positions: vec![
                Vec3::new(0.01, 0.01, 0.01),
                Vec3::new(0.02, 0.02, 0.02),
                Vec3::new(0.03, 0.01, 0.0),
                Vec3::new(0.2, 0.0, 0.0),
            ],
            colors: vec![[255, 0, 0], [255, 0, 0], [0, 0, 0], [9, 9, 9]],
            labels: vec![4, 4, 2, UNLABELED],
        };
        let s = VoxelSample::from_cloud(&cloud, 0.05).expect("voxelised");
        assert_eq!(s.len(), 2);
        let first = s.coords.iter().position(|c| c[0] == 0).expect("the voxel at the origin");
        assert_eq!(s.labels[first], 4);
        assert_eq!(s.labels[1 - first], UNLABELED);
        assert_eq!(s.features.len(), 6);
    }
}
