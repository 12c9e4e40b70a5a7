//! A triangle mesh with a colour per vertex and a semantic class per triangle: what the
//! synthetic scene generator makes, the renderer draws, PLY files carry, and the
//! reconstruction produces (there with per-vertex labels).

use glam::Vec3;

use crate::class::UNLABELED;

/// Indexed triangle mesh with optional per-vertex normals and labels and per-triangle labels.
///
/// Invariants (checked by [`LabeledMesh::validate`]): `colors.len() == positions.len()`;
/// `normals` and `vertex_labels` are empty or as long as `positions`; `triangle_labels` is
/// empty or as long as `triangles`; every index is `< positions.len()`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabeledMesh {
    /// Vertex positions, metres, world frame.
    pub positions: Vec<Vec3>,
    /// Vertex colours, sRGB.
    pub colors: Vec<[u8; 3]>,
    /// Vertex normals (unit length) or empty.
    pub normals: Vec<Vec3>,
    /// Per-vertex class ids (0..13, [`UNLABELED`] for none) or empty.
    pub vertex_labels: Vec<u8>,
    /// Triangles as vertex indices, counter-clockwise seen from the front.
    pub triangles: Vec<[u32; 3]>,
    /// Per-triangle class ids or empty.
    pub triangle_labels: Vec<u8>,
}

impl LabeledMesh {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Checks the invariants listed on the type; the message says which one fails.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.positions.len();
        if self.colors.len() != n {
            return Err(format!("{} colours for {} vertices", self.colors.len(), n));
        }
        if !self.normals.is_empty() && self.normals.len() != n {
            return Err(format!("{} normals for {} vertices", self.normals.len(), n));
        }
        if !self.vertex_labels.is_empty() && self.vertex_labels.len() != n {
            return Err(format!("{} vertex labels for {} vertices", self.vertex_labels.len(), n));
        }
        if !self.triangle_labels.is_empty() && self.triangle_labels.len() != self.triangles.len() {
            return Err(format!(
                "{} triangle labels for {} triangles",
                self.triangle_labels.len(),
                self.triangles.len()
            ));
        }
        if let Some((t, tri)) = self.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= n)) {
            return Err(format!("triangle {t} has index {:?} out of range for {n} vertices", tri));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(format!("vertex {i} has a non-finite position"));
        }
        Ok(())
    }

    /// Appends `other`, shifting its indices.
    pub fn append(&mut self, other: &LabeledMesh) {
        let base = self.positions.len() as u32;
        // Keep optional attributes consistent: fill with defaults where one side lacks them.
        let fill_normals = !self.normals.is_empty() || !other.normals.is_empty();
        if fill_normals && self.normals.is_empty() {
            self.normals = vec![Vec3::ZERO; self.positions.len()];
        }
        let fill_vlabels = !self.vertex_labels.is_empty() || !other.vertex_labels.is_empty();
        if fill_vlabels && self.vertex_labels.is_empty() {
            self.vertex_labels = vec![UNLABELED; self.positions.len()];
        }
        let fill_tlabels = !self.triangle_labels.is_empty() || !other.triangle_labels.is_empty();
        if fill_tlabels && self.triangle_labels.is_empty() {
            self.triangle_labels = vec![UNLABELED; self.triangles.len()];
        }
        self.positions.extend_from_slice(&other.positions);
        self.colors.extend_from_slice(&other.colors);
        if fill_normals {
            if other.normals.is_empty() {
                self.normals.extend(std::iter::repeat_n(Vec3::ZERO, other.positions.len()));
            } else {
                self.normals.extend_from_slice(&other.normals);
            }
        }
        if fill_vlabels {
            if other.vertex_labels.is_empty() {
                self.vertex_labels.extend(std::iter::repeat_n(UNLABELED, other.positions.len()));
            } else {
                self.vertex_labels.extend_from_slice(&other.vertex_labels);
            }
        }
        self.triangles.extend(other.triangles.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
        if fill_tlabels {
            if other.triangle_labels.is_empty() {
                self.triangle_labels.extend(std::iter::repeat_n(UNLABELED, other.triangles.len()));
            } else {
                self.triangle_labels.extend_from_slice(&other.triangle_labels);
            }
        }
    }

    /// Axis-aligned bounds `(min, max)`; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))))
    }

    /// Total area of the triangles in square metres (f32, summed in triangle order).
    pub fn surface_area(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Per-vertex labels derived from triangle labels (each vertex takes the label of the
    /// first triangle that uses it); the mesh's own vertex labels when it has them.
    pub fn vertex_labels_or_from_triangles(&self) -> Vec<u8> {
        if !self.vertex_labels.is_empty() {
            return self.vertex_labels.clone();
        }
        let mut labels = vec![UNLABELED; self.positions.len()];
        for (tri, &l) in self.triangles.iter().zip(&self.triangle_labels) {
            for &i in tri {
                if labels[i as usize] == UNLABELED {
                    labels[i as usize] = l;
                }
            }
        }
        labels
    }

    /// Area-weighted vertex normals from the triangles.
    pub fn compute_normals(&mut self) {
        let mut normals = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let n = (b - a).cross(c - a);
            for &i in t {
                normals[i as usize] += n;
            }
        }
        self.normals = normals.into_iter().map(|n| n.normalize_or_zero()).collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangle(label: u8) -> LabeledMesh {
        LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            colors: vec![[1, 2, 3]; 3],
            triangles: vec![[0, 1, 2]],
            triangle_labels: vec![label],
            ..Default::default()
        }
    }

    #[test]
    fn append_shifts_indices_and_keeps_invariants() {
        let mut m = triangle(1);
        m.append(&triangle(2));
        assert_eq!(m.triangles[1], [3, 4, 5]);
        assert_eq!(m.triangle_labels, vec![1, 2]);
        m.validate().expect("valid");
        assert_eq!(m.vertex_labels_or_from_triangles(), vec![1, 1, 1, 2, 2, 2]);
        m.compute_normals();
        assert!((m.normals[0] - Vec3::Z).length() < 1e-6);
        assert_eq!(m.surface_area(), 1.0);
    }

    #[test]
    fn validate_reports_bad_indices() {
        let mut m = triangle(0);
        m.triangles.push([0, 1, 7]);
        m.triangle_labels.push(0);
        assert!(m.validate().is_err_and(|e| e.contains("out of range")));
    }
}
