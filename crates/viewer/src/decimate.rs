//! Simplification of very large meshes for the browser: a 5 mm reconstruction of a room
//! can have tens of millions of triangles, more than a page can upload or draw smoothly.
//! Vertex clustering on a uniform grid (all vertices of a cell merge into their mean) is
//! crude but fast, deterministic and keeps the room's layout, colours and labels, which is
//! all a viewer needs; the physics keeps using the full mesh.

use std::collections::HashMap;

use glam::{IVec3, Vec3};
use semrecon_data::LabeledMesh;

/// Meshes with more triangles than this are simplified before they are sent to the page.
pub const MAX_DISPLAY_TRIANGLES: usize = 2_000_000;

/// `mesh` itself when it has at most `max_triangles` triangles, else a vertex-clustered copy
/// with at most `max_triangles` (normals dropped: the page computes its own).
pub fn decimate_for_display(mesh: &LabeledMesh, max_triangles: usize) -> LabeledMesh {
    if mesh.triangles.len() <= max_triangles.max(1) {
        return mesh.clone();
    }
    let area = mesh.surface_area();
    // A clustered surface has about two triangles per cell it crosses.
    let mut cell = (2.0 * area / max_triangles.max(1) as f32).sqrt().max(1e-6);
    loop {
        let out = cluster(mesh, cell);
        if out.triangles.len() <= max_triangles || !cell.is_finite() {
            return out;
        }
        cell *= 1.25;
    }
}

/// Merges the vertices of each `cell`-sized grid cell; triangles that collapse are dropped.
fn cluster(mesh: &LabeledMesh, cell: f32) -> LabeledMesh {
    let mut index_of_cell: HashMap<IVec3, u32> = HashMap::new();
    let mut sums: Vec<(Vec3, [u32; 3], u32)> = Vec::new();
    let mut first_vertex: Vec<usize> = Vec::new();
    let remap: Vec<u32> = mesh
        .positions
        .iter()
        .enumerate()
        .map(|(v, p)| {
            let key = (*p / cell).floor().as_ivec3();
            let id = *index_of_cell.entry(key).or_insert_with(|| {
                sums.push((Vec3::ZERO, [0; 3], 0));
                first_vertex.push(v);
                (sums.len() - 1) as u32
            });
            let s = &mut sums[id as usize];
            s.0 += *p;
            for k in 0..3 {
                s.1[k] += mesh.colors[v][k] as u32;
            }
            s.2 += 1;
            id
        })
        .collect();
    let mut out = LabeledMesh {
        positions: sums.iter().map(|(p, _, n)| *p / *n as f32).collect(),
        colors: sums.iter().map(|(_, c, n)| c.map(|x| (x / n) as u8)).collect(),
        ..Default::default()
    };
    if !mesh.vertex_labels.is_empty() {
        out.vertex_labels = first_vertex.iter().map(|&v| mesh.vertex_labels[v]).collect();
    }
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|i| remap[i as usize]);
        if a != b && b != c && a != c {
            out.triangles.push([a, b, c]);
            if let Some(&l) = mesh.triangle_labels.get(t) {
                out.triangle_labels.push(l);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat n x n grid of quads (2 n^2 triangles) on z = 0, labelled by half.
    fn grid(n: u32) -> LabeledMesh {
        let mut m = LabeledMesh::default();
        for y in 0..=n {
            for x in 0..=n {
                m.positions.push(Vec3::new(x as f32 / n as f32, y as f32 / n as f32, 0.0));
                m.colors.push([x as u8, y as u8, 7]);
                m.vertex_labels.push(if x * 2 < n { 1 } else { 2 });
            }
        }
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                m.triangles.push([i, i + 1, i + n + 2]);
                m.triangles.push([i, i + n + 2, i + n + 1]);
            }
        }
        m
    }

    #[test]
    fn small_meshes_are_untouched() {
        let m = grid(4);
        assert_eq!(decimate_for_display(&m, 1000), m);
    }

    #[test]
    fn large_meshes_fit_the_budget_and_keep_extent_and_labels() {
        let m = grid(100);
        let d = decimate_for_display(&m, 2000);
        assert!(d.triangles.len() <= 2000 && d.triangles.len() > 500, "{} triangles", d.triangles.len());
        assert!(d.validate().is_ok());
        let (lo, hi) = d.bounds().expect("not empty");
        assert!(lo.x < 0.05 && hi.x > 0.95 && lo.y < 0.05 && hi.y > 0.95);
        assert!(d.vertex_labels.contains(&1) && d.vertex_labels.contains(&2));
        assert_eq!(decimate_for_display(&m, 2000), d, "deterministic");
    }
}
