//! Voxelisation of a point cloud into a [`SparseTensor`]: every point falls into the voxel
//! `floor(p / voxel_size)`, voxel features are the mean of their points' features, and the
//! point-to-voxel map is kept so that per-voxel predictions (labels) can be sent back to every
//! point. The voxels come out in Z-order, the layout the chunked kernel likes best.

use crate::error::{Result, SparseError};
use crate::hash_map::VoxelHashMap;
use crate::key::{pack_key, Coord};
use crate::morton::morton_order;
use crate::tensor::{check_row_count, check_rows, SparseTensor};

/// A voxelised point cloud.
#[derive(Debug, Clone)]
pub struct Voxelization {
    /// The voxels, in Z-order, with averaged features.
    pub tensor: SparseTensor,
    /// For every input point, the row of its voxel in `tensor`. Shape `[n_points]`.
    pub point_to_voxel: Vec<u32>,
}

/// Voxelises points with per-point features into batch `batch`.
///
/// # Shapes
/// `points`: `[n]` (metres); `features`: `[n, channels]` row-major.
///
/// # Errors
/// [`SparseError::InvalidArgument`] for a voxel size that is not positive and finite or a
/// non-finite point, [`SparseError::FeatureShape`] when the features do not match the points,
/// [`SparseError::CoordOutOfRange`] when a voxel falls outside the key range.
pub fn voxelize(
    points: &[[f32; 3]],
    features: &[f32],
    channels: usize,
    voxel_size: f32,
    batch: i32,
) -> Result<Voxelization> {
    if !(voxel_size.is_finite() && voxel_size > 0.0) {
        return Err(SparseError::InvalidArgument(format!("voxel size {voxel_size} must be positive and finite")));
    }
    check_rows("features", features, points.len(), channels)?;
    check_row_count(points.len())?;
    let inv = 1.0 / f64::from(voxel_size);
    let mut index = VoxelHashMap::with_capacity(points.len() / 4 + 16);
    let mut coords: Vec<Coord> = Vec::new();
    let mut point_voxel = Vec::with_capacity(points.len());
    for (row, p) in points.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(SparseError::InvalidArgument(format!("point {row} is not finite: {p:?}")));
        }
        let q = p.map(|v| (f64::from(v) * inv).floor());
        if q.iter().any(|v| v.abs() > f64::from(i32::MAX / 2)) {
            return Err(SparseError::CoordOutOfRange {
                row,
                coord: [q[0] as i64, q[1] as i64, q[2] as i64, i64::from(batch)],
            });
        }
        let c = [q[0] as i32, q[1] as i32, q[2] as i32, batch];
        let k = pack_key(c, row)?;
        let v = coords.len() as u32;
        match index.insert_or_get(k, v) {
            None => {
                coords.push(c);
                point_voxel.push(v);
            }
            Some(u) => point_voxel.push(u),
        }
    }
    let order = morton_order(&coords)?;
    let mut new_row = vec![0u32; coords.len()];
    for (i, &r) in order.iter().enumerate() {
        new_row[r as usize] = i as u32;
    }
    let sorted: Vec<Coord> = order.iter().map(|&r| coords[r as usize]).collect();
    let point_to_voxel: Vec<u32> = point_voxel.iter().map(|&v| new_row[v as usize]).collect();
    let mut sums = vec![0f64; sorted.len() * channels];
    let mut counts = vec![0u32; sorted.len()];
    for (p, &v) in point_to_voxel.iter().enumerate() {
        let v = v as usize;
        counts[v] += 1;
        for ch in 0..channels {
            sums[v * channels + ch] += f64::from(features[p * channels + ch]);
        }
    }
    let mut feats = Vec::with_capacity(sums.len());
    for (v, &n) in counts.iter().enumerate() {
        for ch in 0..channels {
            feats.push((sums[v * channels + ch] / f64::from(n)) as f32);
        }
    }
    Ok(Voxelization { tensor: SparseTensor::new(sorted, feats, channels)?, point_to_voxel })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn features_are_averaged_and_points_map_back() {
        let pts = [[0.01, 0.01, 0.01], [0.04, 0.02, 0.03], [-0.01, 0.0, 0.0], [0.12, 0.0, 0.0]];
        let f = [1.0, 3.0, 5.0, 7.0];
        let v = voxelize(&pts, &f, 1, 0.05, 0).unwrap();
        assert_eq!(v.tensor.len(), 3);
        let t = &v.tensor;
        let r0 = v.point_to_voxel[0] as usize;
        assert_eq!(v.point_to_voxel[1] as usize, r0);
        assert_eq!(t.coords()[r0], [0, 0, 0, 0]);
        assert_eq!(t.features()[r0], 2.0);
        assert_eq!(t.coords()[v.point_to_voxel[2] as usize], [-1, 0, 0, 0]);
        assert_eq!(t.coords()[v.point_to_voxel[3] as usize], [2, 0, 0, 0]);
        assert_eq!(t.features()[v.point_to_voxel[3] as usize], 7.0);
    }

    #[test]
    fn bad_input_is_an_error() {
        assert!(voxelize(&[[0.0; 3]], &[], 1, 0.05, 0).is_err());
        assert!(voxelize(&[[0.0; 3]], &[1.0], 1, 0.0, 0).is_err());
        assert!(voxelize(&[[f32::NAN, 0.0, 0.0]], &[1.0], 1, 0.05, 0).is_err());
        assert!(voxelize(&[[1e6, 0.0, 0.0]], &[1.0], 1, 0.01, 0).is_err());
        assert!(voxelize(&[], &[], 4, 0.05, 0).unwrap().tensor.is_empty());
    }
}
