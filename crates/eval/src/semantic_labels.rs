//! Ground-truth classes for points of a reconstruction: the class of the nearest surface of a
//! labelled ground-truth mesh. This is how a reconstructed, network-labelled mesh is scored
//! (the demo's mIoU) and how reconstructions of rendered scans become training data: the
//! reconstruction has its own vertices, so labels cannot be copied by index.

use glam::Vec3;
use rayon::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_data::LabeledMesh;

use crate::error::Result;
use crate::mesh_metrics::{MeshEvalConfig, SurfaceIndex};

/// Labels points by the nearest surface of a labelled mesh.
pub struct SurfaceLabeler<'a> {
    mesh: &'a LabeledMesh,
    index: SurfaceIndex<'a>,
    max_distance_m: f32,
}

impl<'a> SurfaceLabeler<'a> {
    /// Indexes `gt` (sampled at 1 cm); points further than `max_distance_m` from it get
    /// [`UNLABELED`] (a reconstruction's outliers have no true class).
    ///
    /// # Errors
    /// An inconsistent or empty mesh.
    pub fn new(gt: &'a LabeledMesh, max_distance_m: f32) -> Result<Self> {
        let config = MeshEvalConfig { sample_spacing_m: 0.01, ..MeshEvalConfig::default() };
        Ok(Self { mesh: gt, index: SurfaceIndex::new(gt, &config, "ground-truth")?, max_distance_m })
    }

    /// The class of the surface nearest to `p`: its triangle's label, else the label of the
    /// triangle's corner nearest to `p`, else [`UNLABELED`].
    pub fn label(&self, p: Vec3) -> u8 {
        let (d, triangle) = self.index.nearest_triangle(p);
        if d.is_nan() || d > self.max_distance_m {
            return UNLABELED;
        }
        let Some(t) = triangle else { return UNLABELED };
        let t = t as usize;
        if let Some(&l) = self.mesh.triangle_labels.get(t) {
            if l != UNLABELED {
                return l;
            }
        }
        let tri = self.mesh.triangles[t];
        tri.iter()
            .filter_map(|&i| {
                Some((
                    self.mesh.positions.get(i as usize)?.distance_squared(p),
                    *self.mesh.vertex_labels.get(i as usize)?,
                ))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map_or(UNLABELED, |(_, l)| l)
    }

    /// [`SurfaceLabeler::label`] of every point, in parallel, in input order.
    pub fn labels(&self, points: &[Vec3]) -> Vec<u8> {
        points.par_iter().map(|p| self.label(*p)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_take_the_class_of_the_nearest_triangle() {
        let mesh = LabeledMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(0.0, 1.0, 1.0),
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
            colors: vec![[9, 9, 9]; 6],
            triangle_labels: vec![0, 7],
            ..LabeledMesh::default()
        };
        let labeler = SurfaceLabeler::new(&mesh, 0.1).expect("indexed");
        let labels = labeler.labels(&[Vec3::new(0.2, 0.2, 0.03), Vec3::new(0.2, 0.2, 0.95), Vec3::new(0.2, 0.2, 0.5)]);
        assert_eq!(labels, vec![0, 7, UNLABELED]);
    }
}
