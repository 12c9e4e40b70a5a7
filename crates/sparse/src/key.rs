//! Voxel coordinates and their packed 64-bit keys. A voxel is `[x, y, z, batch]` in integer
//! grid units. Packing all four into one `u64` makes hashing, comparing and sorting voxels a
//! single integer operation, which is what the hash map and the kernel-map builders live on.
//!
//! Layout of a key, least significant bit first: bits 0..21 hold `x + 2^20`, bits 21..42
//! `y + 2^20`, bits 42..63 `z + 2^20`, bit 63 the batch index. Hence the supported range is
//! x, y, z in `[-2^20, 2^20 - 1]` (about ±21 km at 2 cm voxels) and batch in `{0, 1}`;
//! anything else is a [`SparseError::CoordOutOfRange`]. (Larger batches are made by shifting
//! the scenes apart in space, which the sparse kernels handle at no cost.)

use crate::error::{Result, SparseError};

/// A voxel coordinate `[x, y, z, batch]` in grid units.
pub type Coord = [i32; 4];

/// Bits per spatial axis in a packed key.
pub const AXIS_BITS: u32 = 21;
/// Smallest supported spatial coordinate.
pub const COORD_MIN: i32 = -(1 << 20);
/// Largest supported spatial coordinate.
pub const COORD_MAX: i32 = (1 << 20) - 1;
/// Largest supported batch index.
pub const BATCH_MAX: i32 = 1;

const BIAS: i32 = 1 << 20;
const AXIS_MASK: u64 = (1 << AXIS_BITS) - 1;

/// Whether a coordinate can be packed.
#[inline]
pub fn in_range(c: Coord) -> bool {
    (COORD_MIN..=COORD_MAX).contains(&c[0])
        && (COORD_MIN..=COORD_MAX).contains(&c[1])
        && (COORD_MIN..=COORD_MAX).contains(&c[2])
        && (0..=BATCH_MAX).contains(&c[3])
}

/// Packs a coordinate into its key; `row` only names the culprit in the error.
///
/// # Errors
/// [`SparseError::CoordOutOfRange`] when the coordinate is outside the documented range.
pub fn pack_key(c: Coord, row: usize) -> Result<u64> {
    if in_range(c) {
        Ok(pack_unchecked(c))
    } else {
        Err(SparseError::CoordOutOfRange { row, coord: c.map(i64::from) })
    }
}

/// Packs a coordinate already known to be in range.
#[inline]
pub(crate) fn pack_unchecked(c: Coord) -> u64 {
    ((c[0] + BIAS) as u64 & AXIS_MASK)
        | (((c[1] + BIAS) as u64 & AXIS_MASK) << AXIS_BITS)
        | (((c[2] + BIAS) as u64 & AXIS_MASK) << (2 * AXIS_BITS))
        | ((c[3] as u64 & 1) << 63)
}

/// The coordinate of a packed key.
#[inline]
pub fn unpack_key(key: u64) -> Coord {
    [
        (key & AXIS_MASK) as i32 - BIAS,
        ((key >> AXIS_BITS) & AXIS_MASK) as i32 - BIAS,
        ((key >> (2 * AXIS_BITS)) & AXIS_MASK) as i32 - BIAS,
        (key >> 63) as i32,
    ]
}

/// The FNV prime of the paper's voxel hash.
pub const FNV_PRIME: u64 = 16_777_619;

/// The paper's FNV-style voxel hash `(((seed * P) ^ x) * P ^ y) * P ^ z` with `P = 16777619`
/// (wrapping 64-bit arithmetic; the coordinates enter as their 21-bit biased values, the batch
/// is folded into z).
#[inline]
pub fn fnv_hash(key: u64, seed: u64) -> u64 {
    let x = key & AXIS_MASK;
    let y = (key >> AXIS_BITS) & AXIS_MASK;
    let z = (key >> (2 * AXIS_BITS)) & AXIS_MASK | ((key >> 63) << AXIS_BITS);
    let h = seed.wrapping_mul(FNV_PRIME) ^ x;
    let h = h.wrapping_mul(FNV_PRIME) ^ y;
    h.wrapping_mul(FNV_PRIME) ^ z
}

/// Floor division of a coordinate by 2 on the spatial axes (the strided level below).
#[inline]
pub(crate) fn parent(c: Coord) -> Coord {
    [c[0] >> 1, c[1] >> 1, c[2] >> 1, c[3]]
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn pack_round_trip_at_the_range_ends() {
        for c in [[0, 0, 0, 0], [COORD_MIN, COORD_MAX, -1, 1], [COORD_MAX, COORD_MIN, COORD_MAX, 0], [-5, 7, -11, 1]] {
            let k = pack_key(c, 0).unwrap();
            assert_eq!(unpack_key(k), c);
        }
    }

    #[test]
    fn out_of_range_is_an_error() {
        assert!(pack_key([COORD_MAX + 1, 0, 0, 0], 3).is_err());
        assert!(pack_key([0, COORD_MIN - 1, 0, 0], 3).is_err());
        assert!(pack_key([0, 0, 0, 2], 3).is_err());
        assert!(pack_key([0, 0, 0, -1], 3).is_err());
        let e = pack_key([0, 0, i32::MAX, 0], 7).unwrap_err();
        assert!(e.to_string().contains("row 7"), "{e}");
    }

    #[test]
    fn fnv_hash_differs_for_neighbours() {
        let a = fnv_hash(pack_unchecked([1, 2, 3, 0]), 0x1234);
        let b = fnv_hash(pack_unchecked([1, 2, 4, 0]), 0x1234);
        let c = fnv_hash(pack_unchecked([1, 2, 3, 1]), 0x1234);
        assert_ne!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn parent_floors_negative_coordinates() {
        assert_eq!(parent([-1, -2, 3, 1]), [-1, -1, 1, 1]);
    }
}
