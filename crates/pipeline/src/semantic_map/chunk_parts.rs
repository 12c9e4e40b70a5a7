//! One chunk's contribution to the cells it overlaps, stored compactly.
//!
//! [`SurfaceCells`](super::SurfaceCells) keeps every surface chunk's per-cell sums so that a
//! changed chunk's old contribution can be subtracted exactly. On a whole home that is some
//! 10^5 to 10^6 chunks of a few parts each, so their size is most of the semantic map's
//! memory. Written as absolute sums (64-bit fixed-point positions in map coordinates, 64-bit
//! colour and normal sums and a cell key) a part took 96 bytes in a vector with room for four.
//! Relative to the chunk it is small: a chunk holds at most `3 * 9^3` surface points (one per
//! voxel edge, its upper faces' edges included), each within `CHUNK_SIDE + 1` voxels of the
//! chunk's first voxel, so positions summed relative to that voxel, colours and normals fit
//! 32 bits with room to spare whatever the voxel size (positions are counted in
//! `POSITION_STEPS_PER_VOXEL` steps a voxel), and the cell is a small offset from the cell of
//! the chunk's first voxel. Such a part takes 44 bytes, in a slice of exactly the parts.
//!
//! The encoding is lossless: decoding gives back the absolute sums bit for bit (test
//! `chunk_parts_decode_to_what_was_encoded`). A chunk whose parts do not fit (coordinates so far
//! from the origin that the fixed-point values lose their meaning, or cells much smaller than
//! chunks) keeps the absolute form, so nothing is ever clamped.

use super::{CellKey, CellSum};

/// A part relative to its chunk: the sums of one cell's surface points in one chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct ChunkPart {
    /// The cell, as an offset from the cell of the chunk's first voxel.
    cell: [i8; 3],
    /// Surface points.
    count: u16,
    /// Fixed-point positions summed relative to the chunk's first voxel.
    position: [i32; 3],
    /// Colours summed.
    color: [u32; 3],
    /// Fixed-point normals summed.
    normal: [i32; 3],
}

/// A chunk's parts in (z, y, x) cell order: compact when they fit, else absolute.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum ChunkParts {
    /// Relative to the chunk (nearly always).
    Compact(Box<[ChunkPart]>),
    /// Absolute sums, for parts that do not fit the compact form.
    Wide(Box<[(CellKey, CellSum)]>),
}

/// Where a chunk's parts are measured from: the cell of its first voxel, and its first voxel
/// in fixed point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct PartOrigin {
    /// The cell holding the chunk's first voxel.
    pub cell: CellKey,
    /// The chunk's first voxel in fixed-point position steps.
    pub position: [i64; 3],
}

impl ChunkParts {
    /// No parts (a chunk without surface); allocates nothing.
    pub fn empty() -> Self {
        ChunkParts::Compact(Box::new([]))
    }

    /// The parts `parts` (absolute sums, in (z, y, x) cell order) of a chunk measured from
    /// `origin`, compact when every one fits.
    pub fn encode(parts: Vec<(CellKey, CellSum)>, origin: PartOrigin) -> Self {
        let compact: Option<Box<[ChunkPart]>> =
            parts.iter().map(|(cell, sum)| compact_part(*cell, sum, origin)).collect();
        match compact {
            Some(c) => ChunkParts::Compact(c),
            None => ChunkParts::Wide(parts.into_boxed_slice()),
        }
    }

    /// Whether the chunk has no part.
    pub fn is_empty(&self) -> bool {
        match self {
            ChunkParts::Compact(p) => p.is_empty(),
            ChunkParts::Wide(p) => p.is_empty(),
        }
    }

    /// Calls `f` with each part's cell and absolute sums, in (z, y, x) cell order.
    pub fn for_each(&self, origin: PartOrigin, mut f: impl FnMut(CellKey, &CellSum)) {
        match self {
            ChunkParts::Compact(parts) => {
                for p in parts.iter() {
                    let (cell, sum) = absolute_part(p, origin);
                    f(cell, &sum);
                }
            }
            ChunkParts::Wide(parts) => {
                for (cell, sum) in parts.iter() {
                    f(*cell, sum);
                }
            }
        }
    }

    /// Heap bytes of the parts.
    pub fn heap_bytes(&self) -> usize {
        match self {
            ChunkParts::Compact(p) => std::mem::size_of_val::<[ChunkPart]>(p),
            ChunkParts::Wide(p) => std::mem::size_of_val::<[(CellKey, CellSum)]>(p),
        }
    }
}

/// `sum` of `cell` relative to `origin`, `None` when some field does not fit.
fn compact_part(cell: CellKey, sum: &CellSum, origin: PartOrigin) -> Option<ChunkPart> {
    let count = i64::try_from(sum.count).ok()?;
    let mut part = ChunkPart {
        cell: [0; 3],
        count: u16::try_from(sum.count).ok()?,
        position: [0; 3],
        color: [0; 3],
        normal: [0; 3],
    };
    for k in 0..3 {
        part.cell[k] = i8::try_from(cell[k].checked_sub(origin.cell[k])?).ok()?;
        let offset = origin.position[k].checked_mul(count)?;
        part.position[k] = i32::try_from(sum.position[k].checked_sub(offset)?).ok()?;
        part.color[k] = u32::try_from(sum.color[k]).ok()?;
        part.normal[k] = i32::try_from(sum.normal[k]).ok()?;
    }
    Some(part)
}

/// The absolute cell and sums of `part` (the inverse of [`compact_part`]: the offsets added
/// back cannot overflow, [`compact_part`] computed them from these values).
fn absolute_part(part: &ChunkPart, origin: PartOrigin) -> (CellKey, CellSum) {
    let count = u64::from(part.count);
    let mut sum = CellSum { count, ..CellSum::default() };
    let mut cell = origin.cell;
    for k in 0..3 {
        cell[k] += i32::from(part.cell[k]);
        sum.position[k] = i64::from(part.position[k]) + origin.position[k] * count as i64;
        sum.color[k] = u64::from(part.color[k]);
        sum.normal[k] = i64::from(part.normal[k]);
    }
    (cell, sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::IVec3;
    use rand::{Rng, SeedableRng};

    fn decode(parts: &ChunkParts, origin: PartOrigin) -> Vec<(CellKey, CellSum)> {
        let mut out = Vec::new();
        parts.for_each(origin, |c, s| out.push((c, *s)));
        out
    }

    /// Random parts of chunks near and far: the compact form is taken whenever the values are
    /// those a chunk can hold, the wide one otherwise, and both decode to what was encoded.
    #[test]
    fn chunk_parts_decode_to_what_was_encoded() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (mut compact, mut wide) = (0, 0);
        for case in 0..2000 {
            let far = case % 10 == 0;
            let voxel = IVec3::new(
                rng.random_range(-40_000..40_000),
                rng.random_range(-40_000..40_000),
                rng.random_range(-40_000..40_000),
            );
            let origin = PartOrigin { cell: voxel / 10, position: voxel.to_array().map(|v| i64::from(v) * 256) };
            let parts: Vec<(CellKey, CellSum)> = (0..rng.random_range(0..9))
                .map(|_| {
                    let count: u64 = if far { rng.random_range(0..100_000) } else { rng.random_range(0..=2187) };
                    let cell = origin.cell
                        + IVec3::new(rng.random_range(0..3), rng.random_range(0..3), rng.random_range(0..3));
                    let spread = if far { 1i64 << 40 } else { 2304 };
                    let sum = CellSum {
                        position: origin
                            .position
                            .map(|p| p * count as i64 + rng.random_range(-10..=spread) * count.min(2187) as i64),
                        color: [0; 3].map(|_: u64| rng.random_range(0..=255 * count)),
                        normal: [0; 3].map(|_: i64| rng.random_range(-1024..=1024) * count.min(2187) as i64),
                        count,
                    };
                    (cell, sum)
                })
                .collect();
            let encoded = ChunkParts::encode(parts.clone(), origin);
            match &encoded {
                ChunkParts::Compact(_) => compact += 1,
                ChunkParts::Wide(_) => wide += 1,
            }
            if !far {
                assert!(matches!(encoded, ChunkParts::Compact(_)), "a chunk's values fit: {parts:?}");
            }
            assert_eq!(encoded.is_empty(), parts.is_empty());
            assert_eq!(decode(&encoded, origin), parts);
        }
        assert!(compact > 1000 && wide > 50, "{compact} compact, {wide} wide");
        assert_eq!(ChunkParts::empty().heap_bytes(), 0);
        assert_eq!(std::mem::size_of::<ChunkPart>(), 44);
    }
}
