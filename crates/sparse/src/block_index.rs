//! A two-level voxel index for neighbour look-ups: a small hash map of 4 x 4 x 4 blocks, each
//! a dense array of 64 row slots. Kernel-map building looks up every voxel's 26 neighbours;
//! with one hash entry per voxel the table outgrows the L1/L2 caches and every probe is a
//! cache miss, while the block table of a surface is ~17x smaller and a neighbour mostly sits
//! in a block already in cache. Only used where blocks are well filled (surfaces); very
//! sparse sets fall back to the flat [`VoxelHashMap`].
//!
//! Whole neighbour tables ([`VoxelIndex::neighbour_table`]) go one step further: the 3x3x3
//! neighbourhood of a voxel lies in the 3x3x3 blocks around its own, so the blocks' neighbours
//! are looked up once per block (27 hash probes per block instead of 26 per voxel) and every
//! voxel's neighbours are then plain array reads.

use rayon::prelude::*;

use crate::error::{Result, SparseError};
use crate::hash_map::VoxelHashMap;
use crate::key::{in_range, pack_key, pack_unchecked, Coord};

const EMPTY: u32 = u32::MAX;

/// Voxel coordinate -> row, through 4^3 blocks.
pub(crate) struct BlockIndex {
    blocks: VoxelHashMap,
    cells: Vec<u32>,
    /// Block of every row.
    row_block: Vec<u32>,
    /// Block coordinate (`floor(c / 4)`, batch) of every block.
    block_coords: Vec<Coord>,
}

#[inline]
fn block_key(c: Coord) -> u64 {
    pack_unchecked([c[0] >> 2, c[1] >> 2, c[2] >> 2, c[3]])
}

#[inline]
fn cell(c: Coord) -> usize {
    ((c[0] & 3) | ((c[1] & 3) << 2) | ((c[2] & 3) << 4)) as usize
}

/// A voxel index: blocks where they pay, the flat hash map otherwise.
pub(crate) enum VoxelIndex {
    Blocks(BlockIndex),
    Flat(VoxelHashMap),
}

impl VoxelIndex {
    /// Indexes `coords` (rows in order).
    ///
    /// # Errors
    /// Coordinates outside the key range; duplicate coordinates.
    pub(crate) fn build(coords: &[Coord]) -> Result<Self> {
        let duplicate = |row: usize, c: Coord| {
            SparseError::InvalidArgument(format!(
                "duplicate coordinate {c:?} at row {row} (build a SparseTensor to merge duplicates)"
            ))
        };
        let mut blocks = VoxelHashMap::with_capacity(coords.len() / 8 + 16);
        let mut row_block = Vec::with_capacity(coords.len());
        let mut block_coords = Vec::new();
        // Consecutive rows mostly share a block (Z-ordered sets): skip the probe then.
        let mut last: Option<(u64, u32)> = None;
        for (row, &c) in coords.iter().enumerate() {
            pack_key(c, row)?;
            let key = block_key(c);
            let b = match last {
                Some((k, b)) if k == key => b,
                _ => {
                    let fresh = block_coords.len() as u32;
                    let b = blocks.insert_or_get(key, fresh).unwrap_or(fresh);
                    if b == fresh {
                        block_coords.push([c[0] >> 2, c[1] >> 2, c[2] >> 2, c[3]]);
                    }
                    last = Some((key, b));
                    b
                }
            };
            row_block.push(b);
        }
        let n_blocks = block_coords.len();
        if n_blocks * 64 <= coords.len() * 8 {
            let mut cells = vec![EMPTY; n_blocks * 64];
            for (row, (&c, &b)) in coords.iter().zip(&row_block).enumerate() {
                let slot = &mut cells[b as usize * 64 + cell(c)];
                if *slot != EMPTY {
                    return Err(duplicate(row, c));
                }
                *slot = row as u32;
            }
            return Ok(Self::Blocks(BlockIndex { blocks, cells, row_block, block_coords }));
        }
        let mut map = VoxelHashMap::with_capacity(coords.len());
        for (row, &c) in coords.iter().enumerate() {
            if map.insert_or_get(pack_unchecked(c), row as u32).is_some() {
                return Err(duplicate(row, c));
            }
        }
        Ok(Self::Flat(map))
    }

    /// The row of `c`, if it is indexed (coordinates outside the key range are never).
    #[inline]
    pub(crate) fn get(&self, c: Coord) -> Option<u32> {
        if !in_range(c) {
            return None;
        }
        match self {
            Self::Blocks(b) => {
                let blk = b.blocks.get(block_key(c))? as usize;
                let r = b.cells[blk * 64 + cell(c)];
                (r != EMPTY).then_some(r)
            }
            Self::Flat(m) => m.get(pack_unchecked(c)),
        }
    }

    /// The `[n, K^3]` neighbour table of the indexed rows `coords` (the same list, in the
    /// same order, as given to [`Self::build`]): entry `(u, k)` is the row of
    /// `coords[u] + offset(k)` or `u32::MAX`, with the submanifold offset numbering of
    /// [`crate::kernel_map`] (`k = ((dz + r) K + dy + r) K + dx + r`). Odd `K <= 9`.
    pub(crate) fn neighbour_table(&self, coords: &[Coord], kernel_size: usize) -> Vec<u32> {
        let finder = NeighbourFinder::new(self, coords, kernel_size);
        let kv = finder.kernel_volume();
        let mut table = vec![EMPTY; coords.len() * kv];
        table.par_chunks_mut(kv * 1024).enumerate().for_each(|(chunk, out)| {
            for (j, row) in out.chunks_exact_mut(kv).enumerate() {
                finder.fill(chunk * 1024 + j, row);
            }
        });
        table
    }
}

/// The neighbours of any indexed row on demand, one table row at a time, so that a planner
/// can walk them chunk by chunk without materialising the whole `[n, K^3]` table.
pub(crate) struct NeighbourFinder<'a> {
    index: &'a VoxelIndex,
    coords: &'a [Coord],
    offsets: Vec<[i32; 3]>,
    /// Blocks index only: per cell of a block and offset, which of the 27 blocks around holds
    /// the neighbour (`(dz + 1) 9 + (dy + 1) 3 + dx + 1`) and its cell there.
    lut: Vec<(u8, u8)>,
    /// Blocks index only: the 27 blocks around every block (`u32::MAX` where absent).
    around: Vec<[u32; 27]>,
}

impl<'a> NeighbourFinder<'a> {
    /// A finder over `index`, built from `coords`, for an odd `kernel_size <= 9` (so that every
    /// neighbour lies in the 3 x 3 x 3 blocks around a voxel's block).
    pub(crate) fn new(index: &'a VoxelIndex, coords: &'a [Coord], kernel_size: usize) -> Self {
        let ks = kernel_size as i32;
        let r = ks / 2;
        let kv = kernel_size.pow(3);
        let offsets: Vec<[i32; 3]> =
            (0..kv as i32).map(|k| [k % ks - r, (k / ks) % ks - r, k / (ks * ks) - r]).collect();
        let (lut, around) = match index {
            VoxelIndex::Blocks(b) => {
                let lut = (0..64i32)
                    .flat_map(|cl| {
                        let l = [cl & 3, (cl >> 2) & 3, cl >> 4];
                        offsets.iter().map(move |o| {
                            let t = [l[0] + o[0], l[1] + o[1], l[2] + o[2]];
                            let q = ((t[2] >> 2) + 1) * 9 + ((t[1] >> 2) + 1) * 3 + (t[0] >> 2) + 1;
                            (q as u8, ((t[0] & 3) | ((t[1] & 3) << 2) | ((t[2] & 3) << 4)) as u8)
                        })
                    })
                    .collect();
                let around = b
                    .block_coords
                    .par_iter()
                    .map(|bc| {
                        let mut a = [EMPTY; 27];
                        for (q, slot) in a.iter_mut().enumerate() {
                            let q = q as i32;
                            let nb = [bc[0] + q % 3 - 1, bc[1] + (q / 3) % 3 - 1, bc[2] + q / 9 - 1, bc[3]];
                            *slot = b.blocks.get(pack_unchecked(nb)).unwrap_or(EMPTY);
                        }
                        a
                    })
                    .collect();
                (lut, around)
            }
            VoxelIndex::Flat(_) => (Vec::new(), Vec::new()),
        };
        Self { index, coords, offsets, lut, around }
    }

    /// Offsets per row (`K^3`).
    pub(crate) fn kernel_volume(&self) -> usize {
        self.offsets.len()
    }

    /// Row `u` of the neighbour table into `out` (`K^3` entries, all written).
    #[inline]
    pub(crate) fn fill(&self, u: usize, out: &mut [u32]) {
        let kv = self.offsets.len();
        let c = self.coords[u];
        match self.index {
            VoxelIndex::Blocks(b) => {
                let a = &self.around[b.row_block[u] as usize];
                let cl = cell(c);
                for (slot, &(q, cn)) in out.iter_mut().zip(&self.lut[cl * kv..(cl + 1) * kv]) {
                    let blk = a[q as usize];
                    *slot = if blk == EMPTY { EMPTY } else { b.cells[blk as usize * 64 + cn as usize] };
                }
            }
            VoxelIndex::Flat(_) => {
                for (slot, o) in out.iter_mut().zip(&self.offsets) {
                    *slot = self.index.get([c[0] + o[0], c[1] + o[1], c[2] + o[2], c[3]]).unwrap_or(EMPTY);
                }
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn blocks_and_flat_agree() {
        // A dense slab (blocks) and a scattered set (flat), with negative coordinates.
        let slab: Vec<Coord> = (0..512).map(|i| [i % 16 - 8, (i / 16) % 16 - 8, i / 256 - 1, 1]).collect();
        let scattered: Vec<Coord> = (0..100).map(|i| [i * 37 - 1000, i * 11, -i * 5, 0]).collect();
        for (set, blocky) in [(&slab, true), (&scattered, false)] {
            let idx = VoxelIndex::build(set).unwrap();
            assert_eq!(matches!(idx, VoxelIndex::Blocks(_)), blocky);
            for (r, &c) in set.iter().enumerate() {
                assert_eq!(idx.get(c), Some(r as u32));
                assert_eq!(idx.get([c[0], c[1], c[2], 1 - c[3]]), None);
            }
            assert_eq!(idx.get([crate::key::COORD_MAX + 1, 0, 0, 0]), None);
        }
        assert!(VoxelIndex::build(&[[1, 2, 3, 0], [1, 2, 3, 0]]).is_err());
        assert!(VoxelIndex::build(&[[1, 2, 3, 0]; 40]).is_err());
        assert!(VoxelIndex::build(&[[1, 2, 3, 3]]).is_err());
    }
}
