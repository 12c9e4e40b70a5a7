//! A two-level voxel index for neighbour look-ups: a small hash map of 4 x 4 x 4 blocks, each
//! a dense array of 64 row slots. Kernel-map building looks up every voxel's 26 neighbours;
//! with one hash entry per voxel the table outgrows the L1/L2 caches and every probe is a
//! cache miss, while the block table of a surface is ~17x smaller and a neighbour mostly sits
//! in a block already in cache. Only used where blocks are well filled (surfaces); very
//! sparse sets fall back to the flat [`VoxelHashMap`].

use crate::error::{Result, SparseError};
use crate::hash_map::VoxelHashMap;
use crate::key::{in_range, pack_key, pack_unchecked, Coord};

const EMPTY: u32 = u32::MAX;

/// Voxel coordinate -> row, through 4^3 blocks.
pub(crate) struct BlockIndex {
    blocks: VoxelHashMap,
    cells: Vec<u32>,
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
        let mut n_blocks = 0u32;
        for (row, &c) in coords.iter().enumerate() {
            pack_key(c, row)?;
            if blocks.insert_or_get(block_key(c), n_blocks).is_none() {
                n_blocks += 1;
            }
        }
        if (n_blocks as usize) * 64 <= coords.len() * 8 {
            let mut cells = vec![EMPTY; n_blocks as usize * 64];
            for (row, &c) in coords.iter().enumerate() {
                let b = blocks.get(block_key(c)).unwrap_or(0) as usize;
                let slot = &mut cells[b * 64 + cell(c)];
                if *slot != EMPTY {
                    return Err(duplicate(row, c));
                }
                *slot = row as u32;
            }
            return Ok(Self::Blocks(BlockIndex { blocks, cells }));
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
