//! Sparse voxel tensors: a list of active voxel coordinates and one row-major `f32` feature
//! row per voxel. Rows are kept in the caller's order (kernels never require sorting), but
//! duplicate coordinates are merged at construction because every kernel map assumes a set.

use crate::error::{Result, SparseError};
use crate::hash_map::VoxelHashMap;
use crate::key::{pack_key, Coord};
use crate::morton::morton_order;

/// Coordinates and feature rows of active voxels.
///
/// # Shapes
/// `coords`: `[n]` of `[x, y, z, batch]`; `features`: `[n, channels]` row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseTensor {
    coords: Vec<Coord>,
    features: Vec<f32>,
    channels: usize,
}

/// Checks that a feature buffer holds `rows x channels` values.
pub(crate) fn check_rows(what: &'static str, data: &[f32], rows: usize, channels: usize) -> Result<()> {
    if rows.checked_mul(channels) != Some(data.len()) {
        return Err(SparseError::FeatureShape { what, len: data.len(), rows, channels });
    }
    Ok(())
}

/// Checks a row count against the 32-bit row indices of maps and plans.
pub(crate) fn check_row_count(n: usize) -> Result<()> {
    if n >= u32::MAX as usize - 1 {
        return Err(SparseError::TooManyRows(n));
    }
    Ok(())
}

impl SparseTensor {
    /// A tensor from coordinates and features. Duplicate coordinates are merged into the row
    /// of their first occurrence with the features averaged; the other rows keep their order.
    ///
    /// # Shapes
    /// `coords`: `[n]`; `features`: `[n, channels]` row-major.
    ///
    /// # Errors
    /// [`SparseError::FeatureShape`] when `features.len() != n * channels`,
    /// [`SparseError::CoordOutOfRange`] for a coordinate outside the key range.
    pub fn new(coords: Vec<Coord>, features: Vec<f32>, channels: usize) -> Result<Self> {
        check_rows("features", &features, coords.len(), channels)?;
        check_row_count(coords.len())?;
        let mut index = VoxelHashMap::with_capacity(coords.len());
        let mut first = Vec::with_capacity(coords.len());
        let mut unique = 0u32;
        for (row, &c) in coords.iter().enumerate() {
            let k = pack_key(c, row)?;
            match index.insert_or_get(k, unique) {
                None => {
                    first.push(unique);
                    unique += 1;
                }
                Some(u) => first.push(u),
            }
        }
        if unique as usize == coords.len() {
            return Ok(Self { coords, features, channels });
        }
        let u = unique as usize;
        let mut merged_coords = vec![[0; 4]; u];
        let mut sums = vec![0f64; u * channels];
        let mut counts = vec![0u32; u];
        for (row, (&c, &m)) in coords.iter().zip(&first).enumerate() {
            let m = m as usize;
            merged_coords[m] = c;
            counts[m] += 1;
            for ch in 0..channels {
                sums[m * channels + ch] += f64::from(features[row * channels + ch]);
            }
        }
        let merged = sums
            .chunks(channels.max(1))
            .zip(&counts)
            .flat_map(|(s, &n)| s.iter().map(move |v| (v / f64::from(n)) as f32))
            .collect::<Vec<_>>();
        let merged = if channels == 0 { Vec::new() } else { merged };
        Ok(Self { coords: merged_coords, features: merged, channels })
    }

    /// An empty tensor with `channels` channels.
    pub fn empty(channels: usize) -> Self {
        Self { coords: Vec::new(), features: Vec::new(), channels }
    }

    /// Voxel coordinates, `[n]`.
    pub fn coords(&self) -> &[Coord] {
        &self.coords
    }

    /// Feature rows, `[n, channels]` row-major.
    pub fn features(&self) -> &[f32] {
        &self.features
    }

    /// Mutable feature rows, `[n, channels]` row-major.
    pub fn features_mut(&mut self) -> &mut [f32] {
        &mut self.features
    }

    /// Channels per row.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Number of active voxels.
    pub fn len(&self) -> usize {
        self.coords.len()
    }

    /// Whether there is no active voxel.
    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    /// Coordinates and features, consuming the tensor.
    pub fn into_parts(self) -> (Vec<Coord>, Vec<f32>) {
        (self.coords, self.features)
    }

    /// The same voxels reordered along the Z-order curve, and the permutation used
    /// (`order[i]` = old row of new row `i`). Sorted tensors make chunk regions contiguous.
    pub fn sorted_morton(&self) -> (Self, Vec<u32>) {
        // Coordinates were range-checked at construction, so this cannot fail.
        let order = morton_order(&self.coords).unwrap_or_else(|_| (0..self.len() as u32).collect());
        let coords = order.iter().map(|&r| self.coords[r as usize]).collect();
        let c = self.channels;
        let mut features = Vec::with_capacity(self.features.len());
        for &r in &order {
            features.extend_from_slice(&self.features[r as usize * c..(r as usize + 1) * c]);
        }
        (Self { coords, features, channels: c }, order)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn duplicates_are_averaged_into_the_first_row() {
        let t =
            SparseTensor::new(vec![[0, 0, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]], vec![1.0, 10.0, 2.0, 20.0, 3.0, 30.0], 2)
                .unwrap();
        assert_eq!(t.coords(), &[[0, 0, 0, 0], [1, 0, 0, 0]]);
        assert_eq!(t.features(), &[2.0, 20.0, 2.0, 20.0]);
    }

    #[test]
    fn bad_shapes_and_ranges_are_errors() {
        assert!(matches!(SparseTensor::new(vec![[0, 0, 0, 0]], vec![1.0], 2), Err(SparseError::FeatureShape { .. })));
        assert!(matches!(
            SparseTensor::new(vec![[0, 0, 0, 5]], vec![1.0], 1),
            Err(SparseError::CoordOutOfRange { row: 0, .. })
        ));
        let e = SparseTensor::new(vec![], vec![], 3).unwrap();
        assert!(e.is_empty());
        assert_eq!(e.sorted_morton().0.len(), 0);
    }
}
