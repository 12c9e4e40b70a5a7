//! The collision geometry: the labelled visual mesh simplified by vertex clustering and cut
//! into spatial regions, each region one static triangle mesh for rapier.
//!
//! Why simplify: collision cost grows with the number of triangles (measured: 0.1 M
//! triangles at 2 cm cost about 1/7 of 1.7 M at 5 mm per step), while a ball of 3-5 cm
//! radius cannot feel detail below about its radius. Why vertex clustering: it is linear
//! in the mesh size, needs no manifold topology (scanned meshes have holes and slivers),
//! is deterministic, and it snaps every vertex of a grid cell to one representative (the
//! mean of the cell's vertices) independently of the rest of the mesh, so an unchanged
//! part of a growing map simplifies to exactly the same triangles. Triangles that collapse
//! (two corners in one cell) vanish; triangles that become copies of each other (both
//! sides of a thin wall, or a fan of small triangles) merge into one whose class is the
//! majority of the classes of all visual triangles that fell into it (area-weighted, ties
//! to the smaller label id), so a thin sliver of "clutter" cannot repaint a floor.
//!
//! Why regions: a live reconstruction changes only where the camera looks. Every collision
//! triangle belongs to the cubic region (default 1 m) holding its centroid; a region's
//! content (vertices in canonical order, triangles, labels) has a hash, and replacing the
//! map re-creates only the colliders of regions whose hash changed.

use std::collections::{BTreeMap, HashMap};

use glam::{IVec3, Vec3};
use semrecon_data::class::UNLABELED;
use semrecon_data::LabeledMesh;

use crate::error::{PhysicsError, Result};

/// Integer coordinates of a region: `floor(c / region_size + 1/2)` of its triangles'
/// centroids `c`. The half-cell offset (here and in the clustering grid) centres a cell on
/// z = 0: the floor of a world frame lies there, and a grid boundary at the floor would
/// split its noisy vertices into two layers of clusters and its triangles between regions.
pub type RegionKey = [i32; 3];

/// How the visual mesh becomes collision geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionMeshConfig {
    /// Side of the vertex-clustering grid cell, metres (0 keeps the visual mesh as is).
    pub cell: f32,
    /// Side of the cubic regions, metres.
    pub region_size: f32,
}

impl Default for CollisionMeshConfig {
    fn default() -> Self {
        Self { cell: 0.02, region_size: 1.0 }
    }
}

impl CollisionMeshConfig {
    /// Checks that the sizes are finite and sensible (cell 0 or 1 mm..1 m, region >= cell).
    pub fn validate(&self) -> Result<()> {
        let ok_cell = self.cell == 0.0 || (self.cell.is_finite() && (0.001..=1.0).contains(&self.cell));
        if !ok_cell {
            return Err(PhysicsError::InvalidArgument(format!(
                "collision cell {} m must be 0 or within 0.001..=1",
                self.cell
            )));
        }
        if !(self.region_size.is_finite() && self.region_size >= 0.1 && self.region_size <= 1000.0)
            || self.region_size < self.cell
        {
            return Err(PhysicsError::InvalidArgument(format!(
                "region size {} m must be within 0.1..=1000 and >= the cell",
                self.region_size
            )));
        }
        Ok(())
    }
}

/// One region's static triangle mesh.
///
/// # Shapes
/// `vertices`: V positions (world frame, metres); `triangles`: T index triples into
/// `vertices`; `labels`: T class ids (0..13 or [`UNLABELED`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionRegion {
    /// Region coordinates.
    pub key: RegionKey,
    /// Vertex positions, world frame.
    pub vertices: Vec<Vec3>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// Class id per triangle; the triangle index rapier reports in contacts indexes it.
    pub labels: Vec<u8>,
    /// Hash of the content (FNV-1a over vertex bits, indices and labels).
    pub hash: u64,
}

/// The collision geometry of a whole map: regions by key.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CollisionMesh {
    /// Non-empty regions, in key order.
    pub regions: BTreeMap<RegionKey, CollisionRegion>,
    /// True when the visual mesh had no labels at all (every contact uses the default material).
    pub unlabelled: bool,
}

impl CollisionMesh {
    /// Simplifies `mesh` at `config.cell` and splits it into regions.
    ///
    /// Triangle classes come from `triangle_labels`, else from the majority of the three
    /// `vertex_labels` (what the reconstruction produces), else unlabelled.
    pub fn build(mesh: &LabeledMesh, config: &CollisionMeshConfig) -> Result<Self> {
        config.validate()?;
        mesh.validate().map_err(PhysicsError::Mesh)?;
        let unlabelled = mesh.triangle_labels.is_empty() && mesh.vertex_labels.is_empty();
        let labels = triangle_labels(mesh);
        let (positions, triangles, tri_labels) =
            if config.cell > 0.0 { cluster(mesh, &labels, config.cell) } else { drop_degenerate(mesh, &labels) };
        let mut by_region: BTreeMap<RegionKey, Vec<usize>> = BTreeMap::new();
        for (t, tri) in triangles.iter().enumerate() {
            let c = tri.iter().fold(Vec3::ZERO, |s, &i| s + positions[i as usize]) / 3.0;
            let k = grid_cell(c, config.region_size);
            by_region.entry(k.to_array()).or_default().push(t);
        }
        let regions = by_region
            .into_iter()
            .map(|(key, tris)| (key, make_region(key, &positions, &triangles, &tri_labels, &tris)))
            .collect();
        Ok(Self { regions, unlabelled })
    }

    /// Total number of collision triangles.
    pub fn triangle_count(&self) -> usize {
        self.regions.values().map(|r| r.triangles.len()).sum()
    }
}

/// Per-triangle labels of a visual mesh: its own, or the majority of its vertices' labels
/// (first vertex on a three-way tie), or all [`UNLABELED`].
pub fn triangle_labels(mesh: &LabeledMesh) -> Vec<u8> {
    if !mesh.triangle_labels.is_empty() {
        return mesh.triangle_labels.clone();
    }
    if mesh.vertex_labels.is_empty() {
        return vec![UNLABELED; mesh.triangles.len()];
    }
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.vertex_labels[i as usize]);
            if b == c {
                b
            } else {
                a
            }
        })
        .collect()
}

/// Cell of `p` in a grid of side `size` whose cells are centred on multiples of `size`.
fn grid_cell(p: Vec3, size: f32) -> IVec3 {
    (p / size + 0.5).floor().as_ivec3()
}

type Simplified = (Vec<Vec3>, Vec<[u32; 3]>, Vec<u8>);

fn drop_degenerate(mesh: &LabeledMesh, labels: &[u8]) -> Simplified {
    let mut tris = Vec::with_capacity(mesh.triangles.len());
    let mut out_labels = Vec::with_capacity(mesh.triangles.len());
    for (t, &l) in mesh.triangles.iter().zip(labels) {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        if (b - a).cross(c - a).length_squared() > 0.0 {
            tris.push(*t);
            out_labels.push(l);
        }
    }
    (mesh.positions.clone(), tris, out_labels)
}

/// Vertex clustering on a grid of side `cell`; see the module documentation.
fn cluster(mesh: &LabeledMesh, labels: &[u8], cell: f32) -> Simplified {
    // Cluster ids in first-use order of the vertices: deterministic for a given mesh.
    let mut cluster_of_cell: HashMap<IVec3, u32> = HashMap::new();
    let mut sums: Vec<([f64; 3], u32)> = Vec::new();
    let vertex_cluster: Vec<u32> = mesh
        .positions
        .iter()
        .map(|&p| {
            let k = grid_cell(p, cell);
            let id = *cluster_of_cell.entry(k).or_insert_with(|| {
                sums.push(([0.0; 3], 0));
                (sums.len() - 1) as u32
            });
            let s = &mut sums[id as usize];
            s.0[0] += p.x as f64;
            s.0[1] += p.y as f64;
            s.0[2] += p.z as f64;
            s.1 += 1;
            id
        })
        .collect();
    let positions: Vec<Vec3> = sums
        .iter()
        .map(|(s, n)| {
            let n = *n as f64;
            Vec3::new((s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32)
        })
        .collect();
    // Output triangles keyed by their sorted cluster triple; votes per label, by area.
    let mut index_of: HashMap<[u32; 3], usize> = HashMap::new();
    let mut tris: Vec<[u32; 3]> = Vec::new();
    let mut votes: Vec<Vec<(u8, f32)>> = Vec::new();
    for (t, &l) in mesh.triangles.iter().zip(labels) {
        let c = t.map(|i| vertex_cluster[i as usize]);
        if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
            continue;
        }
        let [a, b, d] = c.map(|i| positions[i as usize]);
        if (b - a).cross(d - a).length_squared() == 0.0 {
            continue;
        }
        let [pa, pb, pc] = t.map(|i| mesh.positions[i as usize]);
        let area = 0.5 * (pb - pa).cross(pc - pa).length();
        let mut key = c;
        key.sort_unstable();
        let idx = *index_of.entry(key).or_insert_with(|| {
            tris.push(c);
            votes.push(Vec::new());
            tris.len() - 1
        });
        match votes[idx].iter_mut().find(|(label, _)| *label == l) {
            Some(v) => v.1 += area,
            None => votes[idx].push((l, area)),
        }
    }
    let out_labels = votes
        .iter()
        .map(|v| {
            // Largest total area; ties (and zero areas) go to the smaller label id.
            v.iter()
                .copied()
                .fold(None::<(u8, f32)>, |best, (l, a)| match best {
                    Some((bl, ba)) if ba > a || (ba == a && bl < l) => Some((bl, ba)),
                    _ => Some((l, a)),
                })
                .map(|(l, _)| l)
                .unwrap_or(UNLABELED)
        })
        .collect();
    (positions, tris, out_labels)
}

/// Builds a region from the given triangles in a canonical order (vertices sorted by
/// position bits, triangles by their vertex triple), so that the same geometry always
/// gives the same content and hash whatever the order of the input mesh.
fn make_region(
    key: RegionKey,
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    labels: &[u8],
    tris: &[usize],
) -> CollisionRegion {
    let mut used: Vec<u32> = tris.iter().flat_map(|&t| triangles[t]).collect();
    let bits = |i: u32| positions[i as usize].to_array().map(f32::to_bits);
    used.sort_unstable_by_key(|&i| (bits(i), i));
    used.dedup();
    let local: HashMap<u32, u32> = used.iter().enumerate().map(|(j, &i)| (i, j as u32)).collect();
    let mut out: Vec<([u32; 3], u8)> = tris
        .iter()
        .map(|&t| {
            let tri = triangles[t].map(|i| local[&i]);
            // Rotate (keeping the winding) so the smallest index comes first.
            let r = (0..3).min_by_key(|&k| tri[k]).unwrap_or(0);
            ([tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]], labels[t])
        })
        .collect();
    out.sort_unstable();
    let vertices: Vec<Vec3> = used.iter().map(|&i| positions[i as usize]).collect();
    let triangles: Vec<[u32; 3]> = out.iter().map(|(t, _)| *t).collect();
    let labels: Vec<u8> = out.iter().map(|(_, l)| *l).collect();
    let mut h = Fnv::default();
    for v in &vertices {
        for b in v.to_array() {
            h.write(&b.to_bits().to_le_bytes());
        }
    }
    for t in &triangles {
        for i in t {
            h.write(&i.to_le_bytes());
        }
    }
    h.write(&labels);
    CollisionRegion { key, vertices, triangles, labels, hash: h.0 }
}

/// FNV-1a, 64 bit: stable across runs and Rust versions (std's hasher is not guaranteed to be).
struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat n x n grid of squares of side `step` at height z, every triangle labelled `label`.
    pub(crate) fn grid(n: u32, step: f32, z: f32, label: u8) -> LabeledMesh {
        let mut m = LabeledMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                m.positions.push(Vec3::new(i as f32 * step, j as f32 * step, z));
            }
        }
        m.colors = vec![[0; 3]; m.positions.len()];
        let w = n + 1;
        for j in 0..n {
            for i in 0..n {
                let a = j * w + i;
                m.triangles.push([a, a + 1, a + w + 1]);
                m.triangles.push([a, a + w + 1, a + w]);
            }
        }
        m.triangle_labels = vec![label; m.triangles.len()];
        m
    }

    #[test]
    fn clustering_reduces_triangles_and_keeps_the_surface() {
        let m = grid(100, 0.005, 0.0, 1); // 0.5 m square at 5 mm, 20 000 triangles
        let cfg = CollisionMeshConfig { cell: 0.02, ..Default::default() };
        let c = CollisionMesh::build(&m, &cfg).expect("build");
        let n = c.triangle_count();
        assert!(n < m.triangle_count() / 10 && n > 500, "{n} triangles");
        let area: f32 = c
            .regions
            .values()
            .flat_map(|r| {
                r.triangles.iter().map(|t| {
                    let [a, b, d] = t.map(|i| r.vertices[i as usize]);
                    0.5 * (b - a).cross(d - a).length()
                })
            })
            .sum();
        // Cluster means pull the border in by up to half a cell.
        assert!((area - 0.25).abs() < 0.03, "area {area}");
        for r in c.regions.values() {
            assert!(r.vertices.iter().all(|v| v.z == 0.0));
            assert!(r.labels.iter().all(|&l| l == 1));
            // Winding kept: normals point up.
            for t in &r.triangles {
                let [a, b, d] = t.map(|i| r.vertices[i as usize]);
                assert!((b - a).cross(d - a).z > 0.0);
            }
        }
        assert!(!c.unlabelled);
    }

    #[test]
    fn noisy_floor_at_zero_clusters_into_one_layer() {
        let mut m = grid(100, 0.005, 0.0, 1);
        for (i, p) in m.positions.iter_mut().enumerate() {
            p.z = if i % 2 == 0 { 0.0015 } else { -0.0015 };
        }
        let c = CollisionMesh::build(&m, &CollisionMeshConfig::default()).expect("build");
        // 0.5 m at 2 cm: 25 x 25 squares (26 cells per side with the half-cell offset).
        assert!(c.triangle_count() <= 2 * 26 * 26, "{} triangles", c.triangle_count());
        assert_eq!(c.regions.len(), 1);
    }

    #[test]
    fn merged_triangles_take_the_area_majority() {
        // Two coincident copies of a big triangle: a large clutter one and a floor one, plus
        // one more floor copy; the floor copies win by area (2 vs 1).
        let mut m = LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(0.001, 0.0, 0.0)],
            colors: vec![[0; 3]; 4],
            triangles: vec![[0, 1, 2], [3, 1, 2], [0, 1, 2]],
            triangle_labels: vec![12, 1, 1],
            ..Default::default()
        };
        let cfg = CollisionMeshConfig { cell: 0.1, region_size: 1.0 };
        let c = CollisionMesh::build(&m, &cfg).expect("build");
        let labels: Vec<u8> = c.regions.values().flat_map(|r| r.labels.clone()).collect();
        assert_eq!(labels, vec![1]);
        m.triangle_labels.clear();
        m.vertex_labels = vec![4, 4, 4, 4];
        let c = CollisionMesh::build(&m, &cfg).expect("build");
        assert_eq!(c.regions.values().flat_map(|r| r.labels.clone()).collect::<Vec<_>>(), vec![4]);
        m.vertex_labels.clear();
        let c = CollisionMesh::build(&m, &cfg).expect("build");
        assert!(c.unlabelled);
        assert_eq!(c.regions.values().flat_map(|r| r.labels.clone()).collect::<Vec<_>>(), vec![UNLABELED]);
    }

    #[test]
    fn regions_split_and_hash_independently_of_input_order() {
        let m = grid(60, 0.05, 0.0, 1); // 3 m x 3 m
        let cfg = CollisionMeshConfig::default();
        let a = CollisionMesh::build(&m, &cfg).expect("build");
        assert_eq!(a.regions.len(), 16);
        // Same surface, triangles and vertices permuted.
        let mut p = m.clone();
        p.triangles.reverse();
        let n = p.positions.len() as u32;
        p.positions.reverse();
        p.triangles = p.triangles.iter().map(|t| t.map(|i| n - 1 - i)).collect();
        let b = CollisionMesh::build(&p, &cfg).expect("build");
        assert_eq!(a, b);
        // Raising one corner changes only the regions that hold its triangles.
        let mut q = m.clone();
        q.positions[0].z = 0.1;
        let c = CollisionMesh::build(&q, &cfg).expect("build");
        let changed: Vec<_> = a.regions.keys().filter(|k| a.regions[*k].hash != c.regions[*k].hash).collect();
        assert_eq!(changed, vec![&[0, 0, 0]]);
    }

    #[test]
    fn invalid_input_is_an_error() {
        let mut m = grid(2, 0.1, 0.0, 1);
        m.triangles.push([0, 1, 99]);
        m.triangle_labels.push(1);
        assert!(CollisionMesh::build(&m, &CollisionMeshConfig::default()).is_err());
        let m = grid(2, 0.1, 0.0, 1);
        for cfg in [
            CollisionMeshConfig { cell: f32::NAN, region_size: 1.0 },
            CollisionMeshConfig { cell: 0.02, region_size: 0.0 },
            CollisionMeshConfig { cell: -1.0, region_size: 1.0 },
        ] {
            assert!(CollisionMesh::build(&m, &cfg).is_err(), "{cfg:?}");
        }
        let c = CollisionMesh::build(&m, &CollisionMeshConfig { cell: 0.0, region_size: 1.0 }).expect("no clustering");
        assert_eq!(c.triangle_count(), 8);
    }
}
