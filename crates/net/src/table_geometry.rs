//! The geometry of one input as plain neighbour tables in row order, for engines that order
//! their work by rows themselves: the GPU engine's chunked kernel walks tiles of consecutive
//! (Z-ordered) rows and reads a `[rows, K^3]` table, so the CPU engine's chunk plans
//! ([`crate::NetGeometry`]) would be built only to be flattened again. Per level: the voxels,
//! their 3x3x3 neighbour table, and the strided layer to the next level as two tables (down:
//! `[coarse, 8]`, up: `[fine, 8]`, the same offsets); the interpolation tables are
//! [`crate::NetGeometry`]'s. On the benchmark room's finest level the table costs about half
//! of the planned layer (docs/gpu.md).

use rayon::prelude::*;
use semrecon_sparse::{Coord, GatherTable, KernelMap};

use crate::config::NetConfig;
use crate::error::Result;
use crate::geometry::interpolation_tables;
use crate::model::LevelStats;

/// Marks a missing neighbour.
const NONE: u32 = u32::MAX;

/// One level of a [`TableGeometry`].
pub(crate) struct TableLevel {
    pub(crate) coords: Vec<Coord>,
    /// `[n, 27]`: the row of the neighbour at each 3x3x3 offset, or `u32::MAX`.
    pub(crate) subm: Vec<u32>,
    /// `[n_next, 8]` and `[n, 8]`: the strided layer to level `i + 1` (each coarse voxel's
    /// fine rows per offset) and its transpose (each fine voxel's coarse row, at its offset).
    pub(crate) down: Option<(Vec<u32>, Vec<u32>)>,
}

/// Neighbour tables and interpolation tables of every level of one input.
pub(crate) struct TableGeometry {
    pub(crate) levels: Vec<TableLevel>,
    pub(crate) interp: Vec<Vec<GatherTable>>,
}

impl TableGeometry {
    /// The tables of `coords` (distinct voxels, Z-ordered for the GPU's tiles) for a network
    /// of `cfg.levels` levels: the same maps as [`crate::NetGeometry::build`], without plans.
    ///
    /// # Errors
    /// Duplicate or out-of-range coordinates.
    pub(crate) fn build(coords: Vec<Coord>, cfg: &NetConfig) -> Result<Self> {
        let l = cfg.levels;
        let mut levels = Vec::with_capacity(l);
        let mut parents = Vec::with_capacity(l);
        let mut current = coords;
        for i in 0..l {
            let subm = KernelMap::submanifold_table(&current, 3)?;
            let (next, parent, down) = if i + 1 < l {
                let (coarse, map) = KernelMap::downsample(&current)?;
                let mut parent = vec![0u32; current.len()];
                let mut down = vec![NONE; coarse.len() * 8];
                let mut up = vec![NONE; current.len() * 8];
                for k in 0..map.kernel_volume() {
                    let (ins, outs) = map.pairs(k);
                    for (&f, &c) in ins.iter().zip(outs) {
                        parent[f as usize] = c;
                        down[c as usize * 8 + k] = f;
                        up[f as usize * 8 + k] = c;
                    }
                }
                (coarse, parent, Some((down, up)))
            } else {
                (Vec::new(), Vec::new(), None)
            };
            parents.push(parent);
            levels.push(TableLevel { coords: std::mem::replace(&mut current, next), subm, down });
        }
        let coords: Vec<&[Coord]> = levels.iter().map(|v| v.coords.as_slice()).collect();
        let parent_refs: Vec<&[u32]> = parents.iter().map(Vec::as_slice).collect();
        let nbrs: Vec<&[u32]> = levels.iter().map(|v| v.subm.as_slice()).collect();
        let interp = interpolation_tables(&coords, &parent_refs, &nbrs)?;
        Ok(Self { levels, interp })
    }

    /// Voxels and neighbour pairs per level.
    pub(crate) fn stats(&self) -> Vec<LevelStats> {
        self.levels
            .iter()
            .map(|l| LevelStats {
                voxels: l.coords.len(),
                neighbour_pairs: l.subm.par_iter().filter(|&&r| r != NONE).count(),
            })
            .collect()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::NetGeometry;
    use semrecon_sparse::backend_tests::surface_set;
    use semrecon_sparse::morton::morton_order;
    use semrecon_sparse::ChunkConfig;

    /// The tables are the planned geometry's maps, level by level, and the interpolation
    /// tables are the same.
    #[test]
    fn tables_match_the_planned_geometry() {
        let raw = surface_set(9);
        let coords: Vec<Coord> = morton_order(&raw).unwrap().iter().map(|&i| raw[i as usize]).collect();
        let cfg = NetConfig::from_name_or_file("s20").unwrap();
        let planned = NetGeometry::build(coords.clone(), &cfg, &ChunkConfig::default()).unwrap();
        let tables = TableGeometry::build(coords, &cfg).unwrap();
        assert_eq!(tables.levels.len(), planned.levels());
        for (i, level) in tables.levels.iter().enumerate() {
            assert_eq!(level.coords, planned.coords(i), "level {i} voxels");
            assert_eq!(level.subm, planned.submanifold(i).neighbour_table(), "level {i} submanifold table");
            match (&level.down, planned.down(i), planned.up(i)) {
                (Some((down, up)), Some(d), Some(u)) => {
                    assert_eq!(down, &d.neighbour_table(), "level {i} down");
                    assert_eq!(up, &u.neighbour_table(), "level {i} up");
                }
                (None, None, None) => {}
                _ => panic!("level {i}: strided layers differ"),
            }
        }
        assert_eq!(tables.stats(), planned.stats());
        for t in 0..tables.interp.len() {
            for (q, table) in tables.interp[t].iter().enumerate() {
                let (rows, weights) = planned.interpolation(t, t + 1 + q).unwrap();
                assert_eq!((table.rows(), table.weights()), (rows, weights), "interpolation {t} <- {}", t + 1 + q);
            }
        }
    }
}
