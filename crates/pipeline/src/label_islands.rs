//! Small islands of a class in the label map, merged into their surroundings.
//!
//! A semantic pass labels each 5 cm cell on its own, and a few cells at a class boundary or
//! in clutter come out as a class the room does not hold at all: a dozen cells of `chair` on
//! a column, a patch of `sofa` on a rug. For a user they are specks of the wrong class (a
//! ball bouncing softly off a column); for the mIoU of a room each such speck of an absent
//! class counts as a whole class at 0 %. Objects are larger than a few hand-widths, so a
//! connected set of same-class cells (26-neighbourhood) smaller than a minimum area takes
//! the class most of its neighbouring cells outside it have, counting only neighbours that
//! belong to islands of at least that area. An island with no such neighbour (a small
//! object alone, say) keeps its class.
//!
//! Deterministic: components are grown from cells in (z, y, x) order and ties between
//! classes go to the lowest id.

use std::collections::HashMap;

use glam::IVec3;

use crate::semantic_map::CellKey;

/// The 26 neighbours of a cell.
fn neighbours(k: CellKey) -> impl Iterator<Item = CellKey> {
    (-1..=1).flat_map(move |dz| {
        (-1..=1).flat_map(move |dy| {
            (-1..=1).filter(move |&dx| (dx, dy, dz) != (0, 0, 0)).map(move |dx| k + IVec3::new(dx, dy, dz))
        })
    })
}

/// Labels with every island of fewer than `min_cells` cells given its surroundings' class.
///
/// `labels` are (cell, class) pairs in (z, y, x) order, each cell once (as
/// [`crate::label_store::LabelStore::labels`] gives them). `min_cells` of 0 or 1 changes
/// nothing.
pub fn merge_small_islands(labels: &[(CellKey, u8)], min_cells: usize) -> Vec<(CellKey, u8)> {
    if min_cells <= 1 || labels.is_empty() {
        return labels.to_vec();
    }
    let index: HashMap<CellKey, usize> = labels.iter().enumerate().map(|(i, (k, _))| (*k, i)).collect();
    // Connected components of same-class cells.
    let mut component = vec![usize::MAX; labels.len()];
    let mut members: Vec<Vec<usize>> = Vec::new();
    for start in 0..labels.len() {
        if component[start] != usize::MAX {
            continue;
        }
        let id = members.len();
        let class = labels[start].1;
        component[start] = id;
        let mut stack = vec![start];
        let mut cells = Vec::new();
        while let Some(i) = stack.pop() {
            cells.push(i);
            for n in neighbours(labels[i].0) {
                if let Some(&j) = index.get(&n) {
                    if component[j] == usize::MAX && labels[j].1 == class {
                        component[j] = id;
                        stack.push(j);
                    }
                }
            }
        }
        members.push(cells);
    }
    let mut out = labels.to_vec();
    for (id, cells) in members.iter().enumerate() {
        if cells.len() >= min_cells {
            continue;
        }
        let mut votes = [0usize; 256];
        for &i in cells {
            for n in neighbours(labels[i].0) {
                if let Some(&j) = index.get(&n) {
                    if component[j] != id && members[component[j]].len() >= min_cells {
                        votes[labels[j].1 as usize] += 1;
                    }
                }
            }
        }
        // The first maximum: the lowest class id on ties.
        let (best, &count) = votes.iter().enumerate().rev().max_by_key(|(_, &v)| v).unwrap_or((0, &0));
        if count > 0 {
            for &i in cells {
                out[i].1 = best as u8;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sorted(mut v: Vec<(CellKey, u8)>) -> Vec<(CellKey, u8)> {
        v.sort_by_key(|(k, _)| (k.z, k.y, k.x));
        v
    }

    /// A 20 x 20 wall of class 2 in the plane y = 0.
    fn wall() -> Vec<(CellKey, u8)> {
        (0..20).flat_map(|z| (0..20).map(move |x| (IVec3::new(x, 0, z), 2u8))).collect()
    }

    #[test]
    fn a_small_island_takes_its_surroundings_class_and_a_large_one_stays() {
        let mut cells = wall();
        for (k, c) in cells.iter_mut() {
            // A 2 x 2 speck of chair and a 6 x 6 door.
            if (3..5).contains(&k.x) && (3..5).contains(&k.z) {
                *c = 7;
            }
            if (10..16).contains(&k.x) && (0..6).contains(&k.z) {
                *c = 6;
            }
        }
        let cells = sorted(cells);
        let out = merge_small_islands(&cells, 10);
        for ((k, before), (k2, after)) in cells.iter().zip(&out) {
            assert_eq!(k, k2);
            let want = if *before == 7 { 2 } else { *before };
            assert_eq!(*after, want, "cell {k}");
        }
        assert_eq!(merge_small_islands(&cells, 1), cells);
        assert_eq!(merge_small_islands(&cells, 0), cells);
    }

    #[test]
    fn a_lone_small_object_keeps_its_class_and_ties_go_to_the_lowest_id() {
        // A lone 2-cell object far from anything.
        let lone = vec![(IVec3::new(50, 50, 50), 12u8), (IVec3::new(51, 50, 50), 12u8)];
        assert_eq!(merge_small_islands(&lone, 5), lone);
        // One cell between two rows of 10 with equal contact on each side.
        let mut cells: Vec<(CellKey, u8)> = (0..10).map(|x| (IVec3::new(x, 0, 0), 10u8)).collect();
        cells.extend((0..10).map(|x| (IVec3::new(x, 0, 2), 8u8)));
        cells.push((IVec3::new(4, 0, 1), 3u8));
        let out = merge_small_islands(&sorted(cells), 5);
        let middle = out.iter().find(|(k, _)| *k == IVec3::new(4, 0, 1)).map(|c| c.1);
        assert_eq!(middle, Some(8));
    }

    #[test]
    fn matches_a_plain_flood_fill_on_random_labels() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut cells: Vec<(CellKey, u8)> = Vec::new();
        for z in 0..8 {
            for y in 0..8 {
                for x in 0..8 {
                    if rng.random::<f32>() < 0.5 {
                        cells.push((IVec3::new(x, y, z), rng.random_range(0..3)));
                    }
                }
            }
        }
        let cells = sorted(cells);
        let out = merge_small_islands(&cells, 4);
        // Reference: islands by repeated relaxation of a minimum id over same-class neighbours.
        let label: HashMap<CellKey, u8> = cells.iter().copied().collect();
        let mut root: HashMap<CellKey, usize> = cells.iter().enumerate().map(|(i, (k, _))| (*k, i)).collect();
        loop {
            let mut changed = false;
            for (k, c) in &cells {
                for n in neighbours(*k) {
                    if label.get(&n) == Some(c) && root[&n] < root[k] {
                        let r = root[&n];
                        root.insert(*k, r);
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        let mut size: HashMap<usize, usize> = HashMap::new();
        for r in root.values() {
            *size.entry(*r).or_default() += 1;
        }
        for ((k, before), (_, after)) in cells.iter().zip(&out) {
            if size[&root[k]] >= 4 {
                assert_eq!(before, after, "a large island changed at {k}");
            } else {
                // A small island's new class is one of a large neighbouring island's, or its own.
                let ok = after == before
                    || cells
                        .iter()
                        .any(|(m, c)| c == after && size[&root[m]] >= 4 && (*m - *k).abs().max_element() <= 3);
                assert!(ok, "cell {k}: {before} -> {after}");
            }
        }
        // Some islands were merged, and the result does not depend on anything but the input.
        assert_ne!(out, cells);
        assert_eq!(out, merge_small_islands(&cells, 4));
    }
}
