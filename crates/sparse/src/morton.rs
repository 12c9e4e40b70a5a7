//! Morton (Z-order) codes. Sorting voxels by their Morton code keeps spatial neighbours close
//! in memory and, more importantly for the chunked kernel, makes every aligned cube of side
//! `2^s` a contiguous run of the sorted list: chunks and their adaptive subdivisions are then
//! plain ranges found by comparing code prefixes.
//!
//! Layout: bit `3i` holds bit `i` of `x + 2^20`, bit `3i + 1` of `y + 2^20`, bit `3i + 2` of
//! `z + 2^20` (i < 21), bit 63 the batch, so batches sort apart.

use crate::error::Result;
use crate::key::{pack_key, Coord};

#[inline]
fn spread(v: u64) -> u64 {
    let mut v = v & 0x1f_ffff;
    v = (v | (v << 32)) & 0x001f_0000_0000_ffff;
    v = (v | (v << 16)) & 0x001f_0000_ff00_00ff;
    v = (v | (v << 8)) & 0x100f_00f0_0f00_f00f;
    v = (v | (v << 4)) & 0x10c3_0c30_c30c_30c3;
    v = (v | (v << 2)) & 0x1249_2492_4924_9249;
    v
}

/// The Morton code of a coordinate known to be in the key range.
#[inline]
pub(crate) fn morton_unchecked(c: Coord) -> u64 {
    let b = 1i64 << 20;
    spread((c[0] as i64 + b) as u64)
        | (spread((c[1] as i64 + b) as u64) << 1)
        | (spread((c[2] as i64 + b) as u64) << 2)
        | ((c[3] as u64 & 1) << 63)
}

/// The Morton code of a coordinate.
///
/// # Errors
/// [`crate::SparseError::CoordOutOfRange`] outside the key range.
pub fn morton_code(c: Coord) -> Result<u64> {
    pack_key(c, 0)?;
    Ok(morton_unchecked(c))
}

/// The permutation that sorts `coords` along the Z-order curve (batch first): `order[i]` is
/// the row that goes to position `i`. Ties (duplicates) keep their input order.
///
/// # Errors
/// [`crate::SparseError::CoordOutOfRange`] naming the first row outside the key range.
pub fn morton_order(coords: &[Coord]) -> Result<Vec<u32>> {
    let mut keyed = Vec::with_capacity(coords.len());
    for (row, &c) in coords.iter().enumerate() {
        pack_key(c, row)?;
        keyed.push((morton_unchecked(c), row as u32));
    }
    keyed.sort_unstable();
    Ok(keyed.into_iter().map(|(_, r)| r).collect())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn aligned_cubes_are_contiguous() {
        let mut coords = Vec::new();
        for z in -4..4 {
            for y in -4..4 {
                for x in -4..4 {
                    coords.push([x, y, z, 0]);
                }
            }
        }
        let order = morton_order(&coords).unwrap();
        // Every run of 8 consecutive voxels is one aligned 2x2x2 cube.
        for run in order.chunks(8) {
            let p: Vec<_> = run.iter().map(|&r| crate::key::parent(coords[r as usize])).collect();
            assert!(p.iter().all(|&q| q == p[0]), "{p:?}");
        }
    }

    #[test]
    fn batch_sorts_first() {
        let a = morton_code([COORD, COORD, COORD, 0]).unwrap();
        let b = morton_code([-COORD, -COORD, -COORD, 1]).unwrap();
        assert!(a < b);
    }
    const COORD: i32 = crate::key::COORD_MAX;
}
