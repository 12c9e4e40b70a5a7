//! Keeping the map small: cold chunks packed in memory, and past a memory budget the
//! coldest packed chunks spilled to a file and read back when the camera returns.
//!
//! Why by frame counts: a chunk that fusion has not changed for a while is behind the camera
//! or out of its range, and will only be read again (meshing its neighbours, ray casting
//! when the camera turns back) or refused again much later. Deciding by fused frame index,
//! never by time or thread, keeps the output the same bits whatever the machine does; and
//! packing is lossless but for distances far from the surface (exact too with
//! `TsdfConfig::packed_far_step_voxels` 0), so the map reads as it would unpacked where any
//! reader looks.
//!
//! The spill order is the same: coldest neighbourhood first (the latest frame that changed
//! the chunk or any of its 26 neighbours), ties in key order. A chunk is spilled only when
//! its whole neighbourhood is quiet, and fusion reads back the spilled chunks around every
//! chunk it selects ([`TsdfMap::restore_spilled`]), so meshing, which reads the neighbours of
//! changed chunks, finds them in memory.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use glam::IVec3;
use rayon::prelude::*;

use super::spill::{SpillError, SpillFile};
use super::storage::{ColdVoxels, HeapBytes, Packed, VoxelStore};
use super::{key_order, Chunk, ChunkKey, TsdfMap};

/// The map's memory state: the spill file and the budget.
#[derive(Debug, Clone, Default)]
pub(crate) struct MemoryState {
    spill: Option<Arc<SpillFile>>,
    /// The budget in bytes (map in memory), as asked.
    budget: Option<usize>,
    /// The budget after raising it to what the chunks in view needed, when it was raised.
    raised_to: Option<usize>,
    /// Set once a chunk was spilled: fusion then reads spilled neighbours back.
    pub(crate) any_spilled: bool,
    /// Spilling stopped after this write error (the chunks stay in memory).
    spill_error: Option<String>,
}

/// Where the map's bytes are (see [`TsdfMap::memory`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MapMemory {
    /// Allocated chunks.
    pub chunks: usize,
    /// Chunks whose voxels are plain 4 KiB blocks (being fused).
    pub hot_chunks: usize,
    /// Chunks packed in memory.
    pub packed_chunks: usize,
    /// Chunks packed in the spill file.
    pub spilled_chunks: usize,
    /// Bytes of the hot chunks' voxel blocks.
    pub hot_bytes: usize,
    /// Bytes of the packed chunks in memory (packed bytes and their records).
    pub packed_bytes: usize,
    /// Bytes of unpacked copies of cold chunks made by readers since the last compaction.
    pub cache_bytes: usize,
    /// Bytes of every chunk's record (key, frame runs, flags; spilled chunks keep theirs)
    /// and of the hash index.
    pub record_bytes: usize,
    /// Bytes of the spilled chunks' records in the spill file (not in memory).
    pub spilled_bytes: usize,
}

impl MapMemory {
    /// Bytes in memory: hot, packed, caches and records.
    pub fn in_memory(&self) -> usize {
        self.hot_bytes + self.packed_bytes + self.cache_bytes + self.record_bytes
    }
}

/// What one compaction did and what it warns about.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Compaction {
    /// Hot chunks packed.
    pub packed: usize,
    /// Packed chunks written to the spill file.
    pub spilled: usize,
    /// Problems to tell the user (budget raised, spill file failed); the map lost nothing.
    pub warnings: Vec<String>,
}

impl Chunk {
    /// The latest frame that changed or selected the chunk (`None`: none yet, or frame 0
    /// only).
    fn last_changed(&self) -> Option<u32> {
        let changed = self.frames.runs().iter().map(|r| r.1).max();
        changed.max((self.touched > 0).then_some(self.touched))
    }

    /// Whether the voxels are packed (in memory or in the spill file).
    pub fn is_packed(&self) -> bool {
        self.voxels.is_cold()
    }

    /// Whether the voxels are in the spill file.
    pub fn is_spilled(&self) -> bool {
        self.voxels.is_spilled()
    }
}

/// Offsets of a chunk's 26 neighbours.
fn neighbourhood() -> impl Iterator<Item = IVec3> {
    (-1..=1).flat_map(|z| (-1..=1).flat_map(move |y| (-1..=1).map(move |x| IVec3::new(x, y, z))))
}

impl TsdfMap {
    /// Spills the coldest packed chunks to a new file at `spill_path` whenever a
    /// [`TsdfMap::compact`] leaves more than `budget_bytes` in memory.
    ///
    /// # Errors
    /// The file cannot be created (it exists, or the folder is missing or read-only).
    pub fn set_memory_budget(&mut self, budget_bytes: usize, spill_path: &Path) -> Result<(), SpillError> {
        self.memory.spill = Some(Arc::new(SpillFile::create(spill_path)?));
        self.memory.budget = Some(budget_bytes);
        self.memory.raised_to = None;
        self.memory.spill_error = None;
        Ok(())
    }

    /// The budget as asked and, when the chunks in view needed more, the most they needed
    /// (spilling still aims at the budget as asked once the view needs less).
    pub fn memory_budget(&self) -> Option<(usize, Option<usize>)> {
        self.memory.budget.map(|b| (b, self.memory.raised_to))
    }

    /// The spill file's path, when a budget is set.
    pub fn spill_path(&self) -> Option<&Path> {
        self.memory.spill.as_deref().map(SpillFile::path)
    }

    /// Where the map's bytes are.
    pub fn memory(&self) -> MapMemory {
        let mut m = MapMemory { chunks: self.chunks.len(), ..MapMemory::default() };
        let mut heap = HeapBytes::default();
        for c in &self.chunks {
            let h = c.voxels.heap_bytes();
            heap.hot += h.hot;
            heap.packed += h.packed;
            heap.spilled_record += h.spilled_record;
            heap.cache += h.cache;
            heap.on_disk += h.on_disk;
            if c.voxels.is_spilled() {
                m.spilled_chunks += 1;
            } else if c.voxels.is_cold() {
                m.packed_chunks += 1;
            } else {
                m.hot_chunks += 1;
            }
        }
        m.hot_bytes = heap.hot;
        m.packed_bytes = heap.packed;
        m.cache_bytes = heap.cache;
        m.spilled_bytes = heap.on_disk;
        m.record_bytes = self.chunks.capacity() * std::mem::size_of::<Chunk>()
            + self.index.capacity() * (std::mem::size_of::<(ChunkKey, u32)>() + 1)
            + heap.spilled_record;
        m
    }

    /// Packs the chunks no frame changed in the `cold_after` frames up to frame `now`, drops
    /// the unpacked copies readers made of packed chunks, and, past the memory budget,
    /// spills the coldest packed chunks. Packing stores distances far from the surface in the
    /// steps of [`TsdfConfig::packed_far_step_voxels`](crate::TsdfConfig::packed_far_step_voxels)
    /// (exactly with 0); everything else, and spilling, is lossless.
    ///
    /// Never fails: a spill file that cannot be written stops spilling (the chunks stay
    /// packed in memory) and a budget smaller than the chunks near the camera is raised;
    /// both come back as warnings.
    pub fn compact(&mut self, now: u32, cold_after: u32) -> Compaction {
        let quiet = |c: &Chunk| c.last_changed().is_none_or(|f| f.saturating_add(cold_after) <= now);
        let coding = self.config.distance_coding();
        let packed = self
            .chunks
            .par_iter_mut()
            .map(|c| {
                let was_hot = !c.voxels.is_cold();
                if !was_hot || quiet(c) {
                    c.voxels.freeze(coding);
                }
                (was_hot && c.voxels.is_cold()) as usize
            })
            .sum();
        let mut out = Compaction { packed, ..Compaction::default() };
        // Always aimed at the budget as asked: a raise lasts only while the view needs it.
        if let Some(budget) = self.memory.budget {
            self.spill_over(budget, now, cold_after, &mut out);
        }
        out
    }

    /// Spills packed chunks, coldest neighbourhood first, until the map fits `budget`.
    fn spill_over(&mut self, budget: usize, now: u32, cold_after: u32, out: &mut Compaction) {
        let Some(file) = self.memory.spill.clone() else { return };
        let excess = self.memory().in_memory().saturating_sub(budget);
        if excess == 0 || self.memory.spill_error.is_some() {
            return;
        }
        // Candidates: packed in memory, with the whole neighbourhood quiet.
        let mut candidates: Vec<(u32, (i32, i32, i32), u32)> = self
            .chunks
            .par_iter()
            .enumerate()
            .filter(|(_, c)| c.voxels.is_packed_in_memory())
            .filter_map(|(slot, c)| {
                let mut latest = c.last_changed();
                for o in neighbourhood() {
                    if let Some(&s) = self.index.get(&(c.key + o)) {
                        latest = latest.max(self.chunks[s as usize].last_changed());
                    }
                }
                let since = latest.map_or(0, |f| f + 1);
                (since.saturating_add(cold_after) <= now).then_some((since, key_order(c.key), slot as u32))
            })
            .collect();
        candidates.sort_unstable();
        let excess = self.spill_slots(&file, candidates.into_iter().map(|c| c.2), excess, out);
        if excess > 0 && self.memory.spill_error.is_none() {
            // What is left is near the camera or recently fused: the budget must hold it.
            // Reported at its largest; said again only when the need grows.
            let needed = self.memory().in_memory();
            if self.memory.raised_to.is_none_or(|r| needed > r) {
                self.memory.raised_to = Some(needed);
                out.warnings.push(format!(
                    "map memory budget of {budget} bytes is smaller than the chunks near the camera need; raised to {needed} bytes"
                ));
            }
        }
    }

    /// Spills every packed chunk still in memory, however recently it changed, in key
    /// order: for a moment when nothing will read the map and its memory is wanted elsewhere
    /// (the end of a scan, while the final mesh is assembled from the live mesh). Plain
    /// chunks stay as they are (packing them would round their far distances); a spilled
    /// chunk comes back at its next read, as always. Without a budget (no spill file), or
    /// once spilling has failed, nothing moves.
    pub fn spill_packed(&mut self) -> Compaction {
        let mut out = Compaction::default();
        let Some(file) = self.memory.spill.clone() else { return out };
        if self.memory.spill_error.is_some() {
            return out;
        }
        let mut slots: Vec<((i32, i32, i32), u32)> = self
            .chunks
            .iter()
            .enumerate()
            .filter(|(_, c)| c.voxels.is_packed_in_memory())
            .map(|(slot, c)| (key_order(c.key), slot as u32))
            .collect();
        slots.sort_unstable();
        self.spill_slots(&file, slots.into_iter().map(|s| s.1), usize::MAX, &mut out);
        out
    }

    /// Writes the packed chunks at `slots` to `file`, in order, until `excess` bytes have
    /// left memory; returns what is left of `excess`. A write error stops spilling for good
    /// (a warning; the chunks stay packed in memory).
    fn spill_slots(
        &mut self,
        file: &Arc<SpillFile>,
        slots: impl Iterator<Item = u32>,
        mut excess: usize,
        out: &mut Compaction,
    ) -> usize {
        for slot in slots {
            if excess == 0 {
                break;
            }
            let chunk = &mut self.chunks[slot as usize];
            let VoxelStore::Cold(cold) = &mut chunk.voxels else { continue };
            let Packed::Memory(bytes) = &cold.packed else { continue };
            match file.append(chunk.key, bytes) {
                Ok(record) => {
                    excess = excess.saturating_sub(bytes.len());
                    cold.packed = Packed::Spilled(file.clone(), record);
                    self.memory.any_spilled = true;
                    out.spilled += 1;
                }
                Err(e) => {
                    let message = format!("{e}; spilling stopped, the map stays in memory");
                    self.memory.spill_error = Some(message.clone());
                    out.warnings.push(message);
                    break;
                }
            }
        }
        excess
    }

    /// Reads back into memory (packed) the spilled chunks at `keys` and around them (their
    /// 26 neighbours); returns how many. Fusion calls this for the chunks it selects, so the
    /// map near the camera is always in memory.
    ///
    /// # Errors
    /// A spill record cannot be read or is damaged: the error names the file; the chunk
    /// stays spilled (nothing changes in the map for it).
    pub fn restore_spilled(&mut self, keys: &[ChunkKey]) -> Result<usize, SpillError> {
        if !self.memory.any_spilled {
            return Ok(0);
        }
        let (index, chunks) = (&self.index, &self.chunks);
        let mut slots: Vec<u32> = keys
            .par_iter()
            .flat_map_iter(|&k| {
                neighbourhood().filter_map(move |o| {
                    let s = *index.get(&(k + o))?;
                    chunks[s as usize].voxels.is_spilled().then_some(s)
                })
            })
            .collect();
        slots.sort_unstable();
        slots.dedup();
        for &slot in &slots {
            let VoxelStore::Cold(cold) = &mut self.chunks[slot as usize].voxels else { continue };
            let Packed::Spilled(file, record) = &cold.packed else { continue };
            let bytes = file.read(record)?;
            // Unpacked here to check the bytes before trusting the chunk to them; the block is
            // kept as the read cache, as fusion or meshing is about to read it.
            let mut block = super::VoxelBlock::empty();
            super::compressed::unpack_into(&bytes, &mut block).map_err(|e| file.corrupt(record, e))?;
            **cold = ColdVoxels::new(Packed::Memory(bytes.into_boxed_slice()), OnceLock::from(block));
        }
        Ok(slots.len())
    }

    /// Drops every unpacked copy of a packed chunk that readers made (at the end of a scan,
    /// when the readers are done; [`TsdfMap::compact`] keeps those read since the previous
    /// compaction).
    pub fn release_caches(&mut self) {
        self.chunks.par_iter_mut().for_each(|c| c.voxels.drop_cache());
    }

    /// Reads every spilled chunk back into memory (before handing the map to code that
    /// reads it all, or to drop the spill file).
    ///
    /// # Errors
    /// As [`TsdfMap::restore_spilled`].
    pub fn restore_all(&mut self) -> Result<usize, SpillError> {
        let keys: Vec<ChunkKey> = self.chunks.iter().filter(|c| c.voxels.is_spilled()).map(|c| c.key).collect();
        self.restore_spilled(&keys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::TsdfConfig;

    /// A spill file on a full disk: a warning naming the file, spilling stops, every chunk
    /// stays (packed) in memory and reads as before.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_failing_spill_file_keeps_the_map_in_memory() {
        let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
        for x in 0..20 {
            let (slot, _) = map.allocate(IVec3::new(x, 0, 0));
            let c = &mut map.chunks[slot as usize];
            c.voxels.tsdf[x as usize] = 1000 + x as i16;
            c.voxels.weight[x as usize] = 256;
        }
        let before: Vec<Vec<crate::Voxel>> = map.chunks().map(|c| c.voxels().collect()).collect();
        let full = std::fs::OpenOptions::new().read(true).write(true).open("/dev/full").expect("/dev/full");
        let file = Arc::new(SpillFile::for_test(std::path::PathBuf::from("/dev/full"), full));
        // One reference is never dropped: dropping the last would delete the "file".
        let keep = std::mem::ManuallyDrop::new(file.clone());
        map.memory.spill = Some(file);
        map.memory.budget = Some(1);
        let out = map.compact(100, 1);
        assert_eq!(out.packed, 20);
        assert_eq!(out.spilled, 0);
        assert!(out.warnings.iter().any(|w| w.contains("/dev/full") && w.contains("stays in memory")), "{out:?}");
        assert_eq!(map.memory().packed_chunks, 20);
        let after: Vec<Vec<crate::Voxel>> = map.chunks().map(|c| c.voxels().collect()).collect();
        assert!(before == after);
        // Spilling stays off: no second warning.
        assert!(map.compact(200, 1).warnings.is_empty());
        let _ = keep;
    }
}
