//! The geometry of one input to CBSCN: everything that depends on the voxel coordinates and
//! not on the weights, built once per input and shared by every layer (and, in training, by
//! the backward pass). Per level: the voxel set, one 3x3x3 submanifold [`ChunkedConv`] (kernel
//! map and chunk plan) used by all of the level's convolutions, one pointwise (1x1x1)
//! [`ChunkedConv`] for its linear layers, the strided convolution to the next level and its
//! transpose; and the trilinear interpolation tables of the cross-scale fusion, whose
//! neighbour look-ups reuse the coarse level's submanifold map (the 8 coarse voxels around a
//! fine voxel lie in the 3x3x3 neighbourhood of its ancestor).
//!
//! Cost: the submanifold plans are built straight from block-index neighbour look-ups (no
//! per-level kernel map: the chunked kernels never read one, and [`NetGeometry::build_maps`]
//! builds them for the rulebook kernels), coarser levels from runs of the Z-ordered voxels
//! (no hashing), pointwise layers from the row count alone.

use rayon::prelude::*;
use semrecon_sparse::{ChunkConfig, ChunkedConv, Coord, GatherTable, KernelMap};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::model::LevelStats;

/// One level of the geometry of an input.
pub(crate) struct Level {
    pub(crate) coords: Vec<Coord>,
    pub(crate) subm: ChunkedConv,
    pub(crate) point: ChunkedConv,
    /// `[n, 27]`: row of the neighbour at each 3x3x3 offset or `u32::MAX` (fusion sources only).
    pub(crate) nbr: Vec<u32>,
    /// Row at level `i + 1` of every row (empty at the coarsest level).
    pub(crate) parent: Vec<u32>,
    /// Strided convolution to level `i + 1` and its transpose back.
    pub(crate) down: Option<(ChunkedConv, ChunkedConv)>,
}

/// Kernel maps, chunk plans and interpolation tables of every level of one input.
pub struct NetGeometry {
    pub(crate) levels: Vec<Level>,
    /// `interp[t][j - t - 1]`: trilinear interpolation from level `j` to level `t`, 8
    /// `(row, weight)` per fine row.
    pub(crate) interp: Vec<Vec<GatherTable>>,
}

impl NetGeometry {
    /// Builds the geometry of `coords` (distinct voxels; any order, but the chunked kernels
    /// are fastest in Z-order) for a network of `cfg.levels` levels.
    ///
    /// # Errors
    /// Duplicate or out-of-range coordinates, bad chunk configurations ([`NetError::Sparse`]).
    pub fn build(coords: Vec<Coord>, cfg: &NetConfig, chunk: &ChunkConfig) -> Result<Self> {
        let l = cfg.levels;
        let mut levels: Vec<Level> = Vec::with_capacity(l);
        let mut current = coords;
        for i in 0..l {
            let subm = ChunkedConv::submanifold(&current, 3, chunk)?;
            let nbr = if i >= 1 && i + 2 <= l { subm.neighbour_table() } else { Vec::new() };
            let point = ChunkedConv::pointwise(current.len())?;
            let (next, parent, down) = if i + 1 < l {
                let (coarse, dmap) = KernelMap::downsample(&current)?;
                let mut parent = vec![0u32; current.len()];
                for k in 0..dmap.kernel_volume() {
                    let (ins, outs) = dmap.pairs(k);
                    for (&f, &c) in ins.iter().zip(outs) {
                        parent[f as usize] = c;
                    }
                }
                let down = ChunkedConv::new(dmap, &current, &coarse, chunk)?;
                let up = down
                    .transposed()
                    .ok_or_else(|| NetError::InvalidInput("strided layer without transpose".into()))?;
                (coarse, parent, Some((down, up)))
            } else {
                (Vec::new(), Vec::new(), None)
            };
            levels.push(Level { coords: std::mem::replace(&mut current, next), subm, point, nbr, parent, down });
        }
        let coords: Vec<&[Coord]> = levels.iter().map(|v| v.coords.as_slice()).collect();
        let parents: Vec<&[u32]> = levels.iter().map(|v| v.parent.as_slice()).collect();
        let nbrs: Vec<&[u32]> = levels.iter().map(|v| v.nbr.as_slice()).collect();
        let interp = interpolation_tables(&coords, &parents, &nbrs)?;
        Ok(Self { levels, interp })
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Voxels of level `i` (level 0: the input's, in the order given to [`Self::build`];
    /// coarser levels in order of first appearance of `floor(u / 2)`).
    pub fn coords(&self, i: usize) -> &[Coord] {
        &self.levels[i].coords
    }

    /// The 3x3x3 submanifold convolution of level `i` (map and plan).
    pub fn submanifold(&self, i: usize) -> &ChunkedConv {
        &self.levels[i].subm
    }

    /// The pointwise (1x1x1) convolution of level `i`: linear layers on its rows.
    pub fn pointwise(&self, i: usize) -> &ChunkedConv {
        &self.levels[i].point
    }

    /// Strided convolution from level `i` to `i + 1` (`None` at the coarsest level).
    pub fn down(&self, i: usize) -> Option<&ChunkedConv> {
        self.levels[i].down.as_ref().map(|d| &d.0)
    }

    /// Transposed convolution from level `i + 1` back to level `i`.
    pub fn up(&self, i: usize) -> Option<&ChunkedConv> {
        self.levels[i].down.as_ref().map(|d| &d.1)
    }

    /// Trilinear interpolation from level `j` to level `t < j` (fusion sources
    /// `j = t + 1 ..= L - 2` only): `(rows, weights)`, 8 per fine row, rows of level `j`,
    /// weights renormalised over existing coarse voxels (absent ones have weight 0).
    ///
    /// # Shapes
    /// `[n_t, 8]` each.
    pub fn interpolation(&self, t: usize, j: usize) -> Option<(&[u32], &[f32])> {
        let ip = self.interp.get(t)?.get(j.checked_sub(t + 1)?)?;
        Some((ip.rows(), ip.weights()))
    }

    /// Voxels and neighbour pairs per level.
    pub fn stats(&self) -> Vec<LevelStats> {
        self.levels.iter().map(|l| LevelStats { voxels: l.coords.len(), neighbour_pairs: l.subm.num_pairs() }).collect()
    }

    /// Builds every layer's kernel map (pair lists) now. The chunked kernels never read them;
    /// the rulebook kernels do, and call this so that building them counts as geometry.
    pub fn build_maps(&self) {
        self.levels.par_iter().for_each(|l| {
            l.subm.map();
        });
    }
}

/// The cross-scale fusion's trilinear tables of every pair of levels `t < j <= L - 2`:
/// `result[t][j - t - 1]` interpolates level `j` onto level `t`.
///
/// # Shapes
/// Per level `i`: `coords[i]`: `[n_i]`; `parents[i]`: `[n_i]` rows of level `i + 1`;
/// `nbrs[i]`: `[n_i, 27]` (needed for the fusion sources `1 ..= L - 2` only).
pub(crate) fn interpolation_tables(
    coords: &[&[Coord]],
    parents: &[&[u32]],
    nbrs: &[&[u32]],
) -> Result<Vec<Vec<GatherTable>>> {
    let l = coords.len();
    let mut interp = Vec::new();
    for (t, fine) in coords.iter().enumerate().take(l.saturating_sub(2)) {
        let mut per = Vec::new();
        let mut anc: Vec<u32> = (0..fine.len() as u32).collect();
        for j in t + 1..=l - 2 {
            let par = parents[j - 1];
            anc.iter_mut().for_each(|a| *a = par[*a as usize]);
            per.push(interp_table(fine, &anc, nbrs[j], (j - t) as u32)?);
        }
        interp.push(per);
    }
    Ok(interp)
}

/// `[n, 27]` neighbour rows of a submanifold map (`u32::MAX` where absent): the input of
/// output `u` at offset `k` is `u + offset(k)`.
#[cfg(test)]
pub(crate) fn neighbour_table(map: &KernelMap) -> Vec<u32> {
    let kv = map.kernel_volume();
    let mut nbr = vec![u32::MAX; map.n_out() * kv];
    for k in 0..kv {
        let (ins, outs) = map.pairs(k);
        for (&i, &o) in ins.iter().zip(outs) {
            nbr[o as usize * kv + k] = i;
        }
    }
    nbr
}

/// Trilinear weights from the coarse level `shift` levels up to every fine voxel.
///
/// In coarse voxel units the fine voxel's centre sits at `(u + 0.5) / 2^shift`; the coarse
/// centres at `v + 0.5`. Per axis the two bracketing coarse voxels are the ancestor
/// `v = floor(u / 2^shift)` and its neighbour on the side of the centre, so all 8 corners lie
/// in the ancestor's 3x3x3 neighbourhood (`nbr`, the coarse level's submanifold table). The
/// weights of absent corners are dropped and the rest renormalised; the ancestor itself always
/// exists and has a positive weight, so the sum is never zero.
///
/// # Shapes
/// `fine`: `[n]`; `ancestor`: `[n]` coarse rows; `nbr`: `[n_coarse, 27]`; result `[n, 8]`.
pub(crate) fn interp_table(fine: &[Coord], ancestor: &[u32], nbr: &[u32], shift: u32) -> Result<GatherTable> {
    let n = fine.len();
    let mut rows = vec![0u32; n * 8];
    let mut weights = vec![0f32; n * 8];
    let scale = 1.0 / f64::from(1u32 << shift);
    // Per axis and remainder `x mod 2^shift`: (offset from the ancestor, weight) of the two
    // bracketing voxels; a table, since there are only 2^shift remainders.
    let axis_of: Vec<[(i32, f64); 2]> = (0..1i32 << shift)
        .map(|rem| {
            let pos = (f64::from(rem) + 0.5) * scale - 0.5;
            if pos < 0.0 {
                [(-1, -pos), (0, 1.0 + pos)]
            } else {
                [(0, 1.0 - pos), (1, pos)]
            }
        })
        .collect();
    let mask = (1i32 << shift) - 1;
    rows.par_chunks_mut(8 * 1024).zip(weights.par_chunks_mut(8 * 1024)).enumerate().for_each(|(blk, (rb, wb))| {
        for (j, (r8, w8)) in rb.chunks_exact_mut(8).zip(wb.chunks_exact_mut(8)).enumerate() {
            let u = blk * 1024 + j;
            let c = fine[u];
            let a = ancestor[u];
            let axis = |x: i32| axis_of[(x & mask) as usize];
            let (ax, ay, az) = (axis(c[0]), axis(c[1]), axis(c[2]));
            let mut total = 0.0;
            let mut q = 0;
            for &(dz, wz) in &az {
                for &(dy, wy) in &ay {
                    for &(dx, wx) in &ax {
                        let k = ((dz + 1) * 9 + (dy + 1) * 3 + dx + 1) as usize;
                        let row = if k == 13 { a } else { nbr[a as usize * 27 + k] };
                        if row != u32::MAX {
                            let w = wx * wy * wz;
                            r8[q] = row;
                            w8[q] = w as f32;
                            total += w;
                        } else {
                            r8[q] = a;
                            w8[q] = 0.0;
                        }
                        q += 1;
                    }
                }
            }
            for w in w8.iter_mut() {
                *w = (f64::from(*w) / total) as f32;
            }
        }
    });
    Ok(GatherTable::new(rows, weights, 8)?)
}
