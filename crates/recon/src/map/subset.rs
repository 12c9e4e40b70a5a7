//! Moving chunks between maps: a map built beside the live one from a subset of its chunks
//! (loop closure's shadow re-integration) and handed back chunk by chunk.
//!
//! Why: re-integrating after a pose-graph correction rebuilds the chunks whose frames moved,
//! while the live map goes on fusing. Building the rebuilt chunks in a second map that holds
//! only them (and copies of the few chunks the live frames touch meanwhile) costs what those
//! chunks cost; a copy of the whole map cost a stall of hundreds of milliseconds and doubled
//! the map's memory while it lived. These operations only move or copy whole chunk records,
//! so they stay correct whatever a chunk's storage is.
//!
//! Revisions: consumers (the incremental mesher, the semantic cells) notice a changed chunk by
//! its revision, some by comparing it with the largest they saw. A successor map therefore
//! counts revisions from a gap above its source's, and a chunk handed back keeps a revision
//! above any the live map gave meanwhile as long as the live map took fewer revisions than the
//! gap (one per fused frame).

use std::collections::BTreeSet;

use super::{ChunkKey, TsdfMap};

impl TsdfMap {
    /// An empty map with this map's configuration whose revisions start `revision_gap` above
    /// this map's next one.
    pub fn empty_successor(&self, revision_gap: u64) -> TsdfMap {
        TsdfMap {
            config: self.config,
            index: Default::default(),
            chunks: Vec::new(),
            next_revision: self.next_revision.saturating_add(revision_gap),
            // No budget and no spill file: a successor holds a few chunks for a while.
            memory: Default::default(),
        }
    }

    /// Copies the chunks at `keys` from `source` into this map (keys absent there, or
    /// already present here, are skipped; repeats allowed). The copies take one new revision
    /// of this map and are marked changed: handed back later, they must read as changed to
    /// every consumer of the map they go to. Returns how many were copied.
    pub fn copy_chunks_from(&mut self, source: &TsdfMap, keys: &[ChunkKey]) -> usize {
        let revision = self.next_revision;
        self.next_revision += 1;
        let mut copied = 0;
        for key in keys {
            if self.index.contains_key(key) {
                continue;
            }
            let Some(&slot) = source.index.get(key) else { continue };
            let mut chunk = source.chunks[slot as usize].clone();
            chunk.revision = revision;
            chunk.dirty = true;
            self.index.insert(*key, self.chunks.len() as u32);
            self.chunks.push(chunk);
            copied += 1;
        }
        copied
    }

    /// Takes the chunks of `other` (built by [`TsdfMap::empty_successor`] of this map) and
    /// makes every key of `owned` hold what `other` holds there: its chunk replaces or joins
    /// this map's, and a key `other` has no chunk for is freed here. Chunks of `other` go in
    /// its allocation order and freed slots in sorted order, so the result does not depend on
    /// the order of `owned` nor on threads. Revisions continue from the larger of the two
    /// maps'. Returns (chunks taken, chunks freed).
    pub fn adopt_chunks(&mut self, other: TsdfMap, owned: impl IntoIterator<Item = ChunkKey>) -> (usize, usize) {
        self.next_revision = self.next_revision.max(other.next_revision);
        let absent: Vec<ChunkKey> = owned.into_iter().filter(|k| !other.index.contains_key(k)).collect();
        let taken = other.chunks.len();
        for mut chunk in other.chunks {
            chunk.dirty = true;
            match self.index.get(&chunk.key) {
                Some(&slot) => self.chunks[slot as usize] = chunk,
                None => {
                    self.index.insert(chunk.key, self.chunks.len() as u32);
                    self.chunks.push(chunk);
                }
            }
        }
        let slots: BTreeSet<u32> = absent.iter().filter_map(|k| self.index.get(k).copied()).collect();
        let freed = slots.len();
        self.free(slots.into_iter().collect());
        (taken, freed)
    }
}

#[cfg(test)]
mod tests {
    use glam::IVec3;

    use crate::map::{TsdfConfig, TsdfMap};

    fn map_with(keys: &[IVec3]) -> TsdfMap {
        let mut m = TsdfMap::new(TsdfConfig::default()).expect("map");
        m.allocate_all(keys);
        for (i, c) in m.chunks.iter_mut().enumerate() {
            c.voxels.weight[0] = i as u16 + 1;
            c.revision = 1;
        }
        m.next_revision = 2;
        m
    }

    #[test]
    fn adopting_replaces_adds_and_frees_the_owned_keys_only() {
        let (a, b, c, d) = (IVec3::new(0, 0, 0), IVec3::new(1, 0, 0), IVec3::new(2, 0, 0), IVec3::new(3, 0, 0));
        let mut live = map_with(&[a, b, c]);
        let mut shadow = live.empty_successor(100);
        assert_eq!(shadow.copy_chunks_from(&live, &[b, d, b]), 1);
        shadow.allocate_all(&[d]);
        shadow.chunks[1].voxels.weight[0] = 77;
        let copied_revision = shadow.chunk(b).expect("copied").revision();
        assert!(copied_revision >= 102);
        let (taken, freed) = live.adopt_chunks(shadow, [a, b, d]);
        assert_eq!((taken, freed), (2, 1));
        assert!(live.chunk(a).is_none(), "owned and absent in the shadow: freed");
        assert_eq!(live.chunk(b).expect("b").revision(), copied_revision);
        assert_eq!(live.chunk(c).expect("c, not owned, untouched").stored_weights()[0], 3);
        assert_eq!(live.chunk(d).expect("d, new").stored_weights()[0], 77);
        assert!(live.next_revision > copied_revision);
        for k in [b, c, d] {
            let slot = live.index[&k] as usize;
            assert_eq!(live.chunks[slot].key(), k, "index consistent");
        }
    }
}
