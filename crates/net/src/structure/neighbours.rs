//! The 26-neighbourhood of the occupied voxels: for every voxel, the row of each of its
//! neighbours in one fixed offset order ([`NEIGHBOUR_OFFSETS`]). The normals are fitted to it
//! and the segmentation graph is built on its pairs, so [`super::refine`] computes it once per
//! room for both. Rows of voxels along x are swept in sorted order instead of hashing each
//! neighbour: linear in the voxels, reading memory in order, and the same for any number of
//! threads.

use rayon::prelude::*;
use semrecon_sparse::key::{pack_key, unpack_key, AXIS_BITS};
use semrecon_sparse::Coord;

/// The 26 neighbour offsets `(dx, dy, dz)`, ordered by `(dz, dy, dx)`: the first 13 precede
/// the centre, the last 13 follow it (each undirected neighbour pair appears once among the
/// "following" offsets of its first voxel).
pub const NEIGHBOUR_OFFSETS: [[i32; 3]; 26] = {
    let mut out = [[0; 3]; 26];
    let mut i = 0;
    let mut dz = -1;
    while dz <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dx = -1;
            while dx <= 1 {
                if !(dx == 0 && dy == 0 && dz == 0) {
                    out[i] = [dx, dy, dz];
                    i += 1;
                }
                dx += 1;
            }
            dy += 1;
        }
        dz += 1;
    }
    out
};

/// Marks a missing neighbour in [`voxel_neighbours`].
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// For every voxel, the row of each of its 26 neighbours ([`NEIGHBOUR_OFFSETS`] order), or
/// [`NO_NEIGHBOUR`].
///
/// # Shapes
/// `coords`: `[n]` distinct; result `[n]`.
pub fn voxel_neighbours(coords: &[Coord]) -> Vec<[u32; 26]> {
    // Rows of voxels along x, sorted by (batch, z, y, x) (the packed key's order): the
    // neighbours of a row lie in the 9 rows around it, and two pointers walk each pair of
    // rows once. Linear in the voxels, and the memory is read in order (26 hash look-ups a
    // voxel cost 15 times more).
    let mut sorted: Vec<(u64, u32)> =
        coords.iter().enumerate().filter_map(|(i, &c)| pack_key(c, i).ok().map(|k| (k, i as u32))).collect();
    sorted.par_sort_unstable();
    let row_of = |k: u64| k >> AXIS_BITS;
    let mut rows: Vec<(u64, usize, usize)> = Vec::new();
    let mut start = 0;
    for i in 1..=sorted.len() {
        if i == sorted.len() || row_of(sorted[i].0) != row_of(sorted[start].0) {
            rows.push((row_of(sorted[start].0), start, i));
            start = i;
        }
    }
    let x_of = |k: u64| (k & ((1 << AXIS_BITS) - 1)) as i64;
    let per_row: Vec<Vec<(u32, [u32; 26])>> = rows
        .par_iter()
        .map(|&(_, a, b)| {
            let mut out: Vec<(u32, [u32; 26])> = sorted[a..b].iter().map(|&(_, i)| (i, [NO_NEIGHBOUR; 26])).collect();
            let c = unpack_key(sorted[a].0);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    let q = [c[0], c[1] + dy, c[2] + dz, c[3]];
                    let Ok(qk) = pack_key(q, 0) else { continue };
                    let Ok(r) = rows.binary_search_by_key(&row_of(qk), |e| e.0) else { continue };
                    let (qa, qb) = (rows[r].1, rows[r].2);
                    let mut p = qa;
                    for (slot, &(k, _)) in out.iter_mut().zip(&sorted[a..b]) {
                        let x = x_of(k);
                        while p < qb && x_of(sorted[p].0) < x - 1 {
                            p += 1;
                        }
                        let mut s = p;
                        while s < qb && x_of(sorted[s].0) <= x + 1 {
                            let dx = x_of(sorted[s].0) - x;
                            if !(dx == 0 && dy == 0 && dz == 0) {
                                slot.1[offset_slot(dx as i32, dy, dz)] = sorted[s].1;
                            }
                            s += 1;
                        }
                    }
                }
            }
            out
        })
        .collect();
    let mut result = vec![[NO_NEIGHBOUR; 26]; coords.len()];
    for (i, nb) in per_row.into_iter().flatten() {
        result[i as usize] = nb;
    }
    result
}

/// The index of offset `(dx, dy, dz)` (each in -1..=1, not all 0) in [`NEIGHBOUR_OFFSETS`].
#[inline]
fn offset_slot(dx: i32, dy: i32, dz: i32) -> usize {
    let linear = ((dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)) as usize;
    if linear > 13 {
        linear - 1
    } else {
        linear
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::collections::HashSet;

    #[test]
    fn neighbours_match_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut set = HashSet::new();
        while set.len() < 300 {
            set.insert([rng.random_range(-4..4), rng.random_range(-4..4), rng.random_range(-4..4), 0]);
        }
        let coords: Vec<Coord> = set.into_iter().collect();
        let nb = voxel_neighbours(&coords);
        for (i, c) in coords.iter().enumerate() {
            for (slot, o) in nb[i].iter().zip(NEIGHBOUR_OFFSETS) {
                let q = [c[0] + o[0], c[1] + o[1], c[2] + o[2], 0];
                let want = coords.iter().position(|&d| d == q).map_or(NO_NEIGHBOUR, |j| j as u32);
                assert_eq!(*slot, want);
            }
        }
    }

    #[test]
    fn offset_slots_follow_the_table() {
        for (i, o) in NEIGHBOUR_OFFSETS.iter().enumerate() {
            assert_eq!(offset_slot(o[0], o[1], o[2]), i);
        }
    }
}
