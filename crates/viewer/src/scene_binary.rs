//! The mesh as the page receives it: one compact little-endian binary blob that maps
//! straight onto WebGL buffers (JSON numbers would be 3-4 times larger and slow to parse).
//!
//! Layout (`SRM1`), every section starting on a 4-byte boundary:
//!
//! | bytes | content |
//! |---|---|
//! | 4 | magic `SRM1` |
//! | 4 x 3 | u32 vertex count `n`, u32 triangle count `t`, u32 flags (bit 0: labelled) |
//! | 12 n | f32 positions `[x, y, z]`, metres, world frame (z up) |
//! | 3 n, padded | u8 colours `[r, g, b]`, sRGB |
//! | n, padded | u8 class id per vertex (255: unlabelled) |
//! | 12 t | u32 vertex indices, three per triangle |
//!
//! Labels go per vertex because WebGL colours per vertex; a mesh labelled per triangle
//! (the synthetic rooms) has the vertices shared by triangles of different classes
//! duplicated, so class borders stay sharp.

use std::collections::HashMap;

use semrecon_data::class::UNLABELED;
use semrecon_data::LabeledMesh;

/// Magic bytes at the start of the blob.
pub const MAGIC: &[u8; 4] = b"SRM1";

/// Encodes `mesh` in the layout of the module docs.
pub fn encode_mesh(mesh: &LabeledMesh) -> Vec<u8> {
    let labelled = !mesh.vertex_labels.is_empty() || !mesh.triangle_labels.is_empty();
    let (positions, colors, labels, triangles) = per_vertex_labels(mesh);
    let n = positions.len();
    let mut out = Vec::with_capacity(16 + n * 16 + 8 + triangles.len() * 12);
    out.extend_from_slice(MAGIC);
    for x in [n as u32, triangles.len() as u32, labelled as u32] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    for p in &positions {
        for x in p.to_array() {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    out.extend(colors.iter().flatten());
    pad4(&mut out);
    out.extend_from_slice(&labels);
    pad4(&mut out);
    for i in triangles.iter().flatten() {
        out.extend_from_slice(&i.to_le_bytes());
    }
    out
}

type Arrays = (Vec<glam::Vec3>, Vec<[u8; 3]>, Vec<u8>, Vec<[u32; 3]>);

/// Positions, colours, one label per vertex and triangles.
fn per_vertex_labels(mesh: &LabeledMesh) -> Arrays {
    if !mesh.vertex_labels.is_empty() || mesh.triangle_labels.is_empty() {
        let labels = if mesh.vertex_labels.is_empty() {
            vec![UNLABELED; mesh.positions.len()]
        } else {
            mesh.vertex_labels.clone()
        };
        return (mesh.positions.clone(), mesh.colors.clone(), labels, mesh.triangles.clone());
    }
    let mut index: HashMap<(u32, u8), u32> = HashMap::new();
    let (mut positions, mut colors, mut labels) = (Vec::new(), Vec::new(), Vec::new());
    let triangles = mesh
        .triangles
        .iter()
        .zip(&mesh.triangle_labels)
        .map(|(tri, &l)| {
            tri.map(|v| {
                *index.entry((v, l)).or_insert_with(|| {
                    positions.push(mesh.positions[v as usize]);
                    colors.push(mesh.colors[v as usize]);
                    labels.push(l);
                    (positions.len() - 1) as u32
                })
            })
        })
        .collect();
    (positions, colors, labels, triangles)
}

fn pad4(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
    }

    #[test]
    fn triangle_labels_split_shared_vertices() {
        // Two triangles sharing an edge, different classes: the 2 shared vertices double.
        let mesh = LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE],
            colors: vec![[1, 2, 3]; 4],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            triangle_labels: vec![1, 8],
            ..Default::default()
        };
        let b = encode_mesh(&mesh);
        assert_eq!(&b[..4], MAGIC);
        let (n, t, flags) = (u32_at(&b, 4) as usize, u32_at(&b, 8) as usize, u32_at(&b, 12));
        assert_eq!((n, t, flags), (6, 2, 1));
        let colors_at = 16 + 12 * n;
        let labels_at = colors_at + (3 * n).div_ceil(4) * 4;
        assert_eq!(&b[labels_at..labels_at + n], &[1, 1, 1, 8, 8, 8]);
        let idx_at = labels_at + n.div_ceil(4) * 4;
        assert_eq!(b.len(), idx_at + 12 * t);
        let second: Vec<u32> = (0..3).map(|k| u32_at(&b, idx_at + 12 + 4 * k)).collect();
        assert_eq!(second, vec![3, 4, 5]);
        // Vertex 4 of the output is input vertex 3 = (1,1,1).
        let x4 = f32::from_le_bytes([b[16 + 48], b[17 + 48], b[18 + 48], b[19 + 48]]);
        assert_eq!(x4, 1.0);
    }

    #[test]
    fn unlabelled_mesh_has_flag_zero_and_label_255() {
        let mesh = LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            colors: vec![[9, 9, 9]; 3],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        };
        let b = encode_mesh(&mesh);
        assert_eq!(u32_at(&b, 12), 0);
        let labels_at = 16 + 36 + 12;
        assert_eq!(&b[labels_at..labels_at + 3], &[255, 255, 255]);
    }
}
