//! Which chunks a set of changes re-meshes.
//!
//! A chunk's mesh reads the nearby voxels of its 26 neighbours, so a change re-meshes the
//! changed chunk and those allocated neighbours that read the changed voxels: a 27-bit
//! reader mask per changed chunk, bit `ox + 3 oy + 9 oz` for the neighbour at offset
//! `(ox, oy, oz) - 1`. Looking each of them up in the map's hash index costs 27 probes per
//! changed chunk (about 270 k per keyframe on 7-Scenes at 5 mm, 2.5-4 ms of a keyframe's
//! meshing). Instead the marks are set in a bitmap over the changes' bounding box, one bit
//! per chunk, and one pass over the map's chunks reads it. Changes too far apart for a small
//! bitmap fall back to the hash lookups, which stay as the definition.

use glam::IVec3;
use rayon::prelude::*;

use crate::map::{ChunkKey, TsdfMap};

/// Largest bitmap, in chunks (2 Mi bits, 256 KiB: a box of 128 chunks, 5 m at 5 mm voxels,
/// on each side).
const MAX_BITS: i64 = 1 << 21;

/// Every reader bit: the chunk and all 26 neighbours.
pub(super) const ALL_READERS: u32 = (1 << 27) - 1;

/// The reader bits of a chunk and the neighbours whose cells take corners from it: offsets
/// -1 and 0 on every axis, since a chunk owns the cells whose lowest corner is one of its
/// voxels (the other neighbours read it only for the normals at their edge).
pub(super) const CELL_READERS: u32 = 1 << 0 | 1 << 1 | 1 << 3 | 1 << 4 | 1 << 9 | 1 << 10 | 1 << 12 | 1 << 13;

/// The neighbour offset of reader bit `b` (0..27).
pub(super) fn reader_offset(b: u32) -> IVec3 {
    IVec3::new((b % 3) as i32, ((b / 3) % 3) as i32, (b / 9) as i32) - IVec3::ONE
}

/// The set bits of a reader mask.
pub(super) fn bits(mask: u32) -> impl Iterator<Item = u32> {
    let mut rest = mask & ALL_READERS;
    std::iter::from_fn(move || {
        (rest != 0).then(|| {
            let b = rest.trailing_zeros();
            rest &= rest - 1;
            b
        })
    })
}

/// Map slots (ascending, each once) of the allocated chunks that `marks` (changed or freed
/// chunk, reader mask) re-mesh.
pub(super) fn marked_slots(map: &TsdfMap, marks: &[(ChunkKey, u32)]) -> Vec<u32> {
    match Bitmap::new(marks) {
        Some(bitmap) => map
            .chunks
            .par_iter()
            .enumerate()
            .filter(|(_, c)| bitmap.contains(c.key))
            .map(|(slot, _)| slot as u32)
            .collect(),
        None => marked_slots_by_lookup(map, marks),
    }
}

/// [`marked_slots`] by looking every marked neighbour up in the map's index.
pub(super) fn marked_slots_by_lookup(map: &TsdfMap, marks: &[(ChunkKey, u32)]) -> Vec<u32> {
    let mut slots: Vec<u32> = marks
        .par_iter()
        .flat_map_iter(|&(key, mask)| bits(mask).filter_map(move |b| map.index.get(&(key + reader_offset(b))).copied()))
        .collect();
    slots.par_sort_unstable();
    slots.dedup();
    slots
}

/// One bit per chunk of a box.
struct Bitmap {
    lo: IVec3,
    dims: IVec3,
    words: Vec<u64>,
}

impl Bitmap {
    /// The marks in a bitmap over their bounding box (grown by one chunk), `None` when that
    /// holds more than [`MAX_BITS`] chunks.
    fn new(marks: &[(ChunkKey, u32)]) -> Option<Self> {
        let Some(&(first, _)) = marks.first() else {
            return Some(Self { lo: IVec3::ZERO, dims: IVec3::ZERO, words: Vec::new() });
        };
        let (lo, hi) = marks.iter().fold((first, first), |(lo, hi), &(k, _)| (lo.min(k), hi.max(k)));
        if lo.cmpeq(IVec3::MIN).any() || hi.cmpeq(IVec3::MAX).any() {
            return None; // the box grown by one chunk would leave i32
        }
        // In i64: keys may lie anywhere in i32, and the box's sides must not overflow.
        let side = |a: i32, b: i32| b as i64 - a as i64 + 3;
        let (sx, sy, sz) = (side(lo.x, hi.x), side(lo.y, hi.y), side(lo.z, hi.z));
        if sx.saturating_mul(sy).saturating_mul(sz) > MAX_BITS {
            return None;
        }
        let mut bitmap = Self {
            lo: lo - IVec3::ONE,
            dims: IVec3::new(sx as i32, sy as i32, sz as i32),
            words: vec![0; ((sx * sy * sz) as usize).div_ceil(64)],
        };
        for &(key, mask) in marks {
            for b in bits(mask) {
                let i = bitmap.index(key + reader_offset(b));
                bitmap.words[i / 64] |= 1 << (i % 64);
            }
        }
        Some(bitmap)
    }

    /// Bit of `k`, which must lie in the box.
    fn index(&self, k: ChunkKey) -> usize {
        let r = k - self.lo;
        (r.x + self.dims.x * (r.y + self.dims.y * r.z)) as usize
    }

    fn contains(&self, k: ChunkKey) -> bool {
        // In i64 so that keys far outside the box cannot wrap into it.
        let r = k.as_i64vec3() - self.lo.as_i64vec3();
        if r.cmplt(glam::I64Vec3::ZERO).any() || r.cmpge(self.dims.as_i64vec3()).any() {
            return false;
        }
        let i = self.index(k);
        self.words[i / 64] >> (i % 64) & 1 != 0
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::map::TsdfConfig;

    #[test]
    fn cell_readers_are_the_lower_neighbours_and_the_chunk() {
        let want: u32 = (0..27).filter(|&b| reader_offset(b).cmple(IVec3::ZERO).all()).map(|b| 1 << b).sum();
        assert_eq!(CELL_READERS, want);
        assert_eq!(bits(ALL_READERS).count(), 27);
    }

    #[test]
    fn the_bitmap_marks_what_the_lookups_mark() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for round in 0..40 {
            let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
            let spread = [3, 6, 20][round % 3];
            let random_key = |rng: &mut ChaCha8Rng| {
                IVec3::new(
                    rng.random_range(-spread..spread),
                    rng.random_range(-spread..spread),
                    rng.random_range(-2..3),
                )
            };
            for _ in 0..rng.random_range(0..400) {
                let key = random_key(&mut rng);
                map.allocate(key);
            }
            let mut marks: Vec<(ChunkKey, u32)> = (0..rng.random_range(0..60))
                .map(|_| {
                    let mask = match rng.random_range(0..3) {
                        0 => ALL_READERS,
                        1 => 1 << 13,
                        _ => rng.random::<u32>() & ALL_READERS,
                    };
                    (random_key(&mut rng), mask)
                })
                .collect();
            let want = marked_slots_by_lookup(&map, &marks);
            assert_eq!(marked_slots(&map, &marks), want, "round {round}");
            if marks.is_empty() {
                continue;
            }
            assert!(Bitmap::new(&marks).is_some(), "round {round}: a small box takes the bitmap path");
            // One change far away: too big a box, the lookups answer.
            marks.push((IVec3::new(i32::MAX - 1, 0, i32::MIN + 1), ALL_READERS));
            assert!(Bitmap::new(&marks).is_none());
            assert_eq!(marked_slots(&map, &marks), marked_slots_by_lookup(&map, &marks), "round {round}");
        }
    }
}
