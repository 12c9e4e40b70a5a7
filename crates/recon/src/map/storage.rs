//! Where a chunk's voxels live: a plain 4 KiB block while fusion works on the chunk ("hot"),
//! or packed ([`super::compressed`]) in memory or in the spill file once it has gone quiet
//! ("cold").
//!
//! Why behind `Deref`: every reader of the map (meshing, ray casting, surface cells,
//! exports, loop closure) takes `&Chunk` and reads whole arrays; a cold chunk unpacks itself
//! on first read into a cache that the next compaction drops again, so readers see exactly
//! the bits of the hot chunk and need no change. A write (`DerefMut`: fusion, tests) turns
//! the chunk hot for good. Hot chunks pay one predictable branch per access.
//!
//! Caches get a second chance (the CLOCK rule): a read marks the chunk, and a compaction
//! drops the cache of a chunk only when no read marked it since the previous compaction.
//! Readers that come back every keyframe (meshing the border of the view, the semantic
//! context around changed chunks) would otherwise unpack the same chunks again and again.

use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use super::compressed::{pack, unpack_into, DistanceCoding};
use super::spill::{SpillFile, SpillRecord};
use super::VoxelBlock;

/// A chunk's voxels, hot or cold.
#[derive(Debug, Clone)]
pub(crate) enum VoxelStore {
    /// The plain block, read and written in place.
    Hot(Box<VoxelBlock>),
    /// Packed; boxed so that a chunk record grows by one pointer only.
    Cold(Box<ColdVoxels>),
}

/// A packed chunk and the block it unpacks to when read.
#[derive(Debug)]
pub(crate) struct ColdVoxels {
    pub(crate) packed: Packed,
    /// The unpacked block, made by the first read since the cache was last dropped.
    pub(crate) thawed: OnceLock<Box<VoxelBlock>>,
    /// Set by reads, cleared by compactions (the cache's second chance).
    pub(crate) read: AtomicBool,
}

impl ColdVoxels {
    /// Packed bytes in memory, no cache yet.
    pub(crate) fn new(packed: Packed, thawed: OnceLock<Box<VoxelBlock>>) -> Self {
        Self { packed, thawed, read: AtomicBool::new(false) }
    }
}

impl Clone for ColdVoxels {
    fn clone(&self) -> Self {
        Self { packed: self.packed.clone(), thawed: self.thawed.clone(), read: AtomicBool::new(false) }
    }
}

/// Where the packed bytes are.
#[derive(Debug, Clone)]
pub(crate) enum Packed {
    /// In memory.
    Memory(Box<[u8]>),
    /// In the spill file (shared by copies of the map).
    Spilled(Arc<SpillFile>, SpillRecord),
}

impl VoxelStore {
    /// Packs a hot block, its distances coded as `coding` says; a cold one drops its cache
    /// unless a read marked it since the last call (then only the mark is cleared).
    pub(crate) fn freeze(&mut self, coding: DistanceCoding) {
        match self {
            Self::Hot(b) => {
                let packed = pack(b, coding);
                *self = Self::Cold(Box::new(ColdVoxels::new(Packed::Memory(packed), OnceLock::new())));
            }
            Self::Cold(c) => {
                if !std::mem::take(c.read.get_mut()) {
                    c.thawed.take();
                }
            }
        }
    }

    /// Drops the unpacked cache of a cold chunk, read or not.
    pub(crate) fn drop_cache(&mut self) {
        if let Self::Cold(c) = self {
            c.thawed.take();
            *c.read.get_mut() = false;
        }
    }

    /// Whether the voxels are packed.
    pub(crate) fn is_cold(&self) -> bool {
        matches!(self, Self::Cold(_))
    }

    /// Whether the voxels are packed and the packed bytes in memory (what spilling can move).
    pub(crate) fn is_packed_in_memory(&self) -> bool {
        matches!(self, Self::Cold(c) if matches!(c.packed, Packed::Memory(_)))
    }

    /// Whether the packed bytes are in the spill file.
    pub(crate) fn is_spilled(&self) -> bool {
        matches!(self, Self::Cold(c) if matches!(c.packed, Packed::Spilled(..)))
    }

    /// Heap bytes held in memory: the block, or the packed bytes and their record, plus an
    /// unpacked cache.
    pub(crate) fn heap_bytes(&self) -> HeapBytes {
        match self {
            Self::Hot(_) => HeapBytes { hot: std::mem::size_of::<VoxelBlock>(), ..HeapBytes::default() },
            Self::Cold(c) => {
                let cache = if c.thawed.get().is_some() { std::mem::size_of::<VoxelBlock>() } else { 0 };
                match &c.packed {
                    Packed::Memory(b) => {
                        HeapBytes { packed: b.len() + std::mem::size_of::<ColdVoxels>(), cache, ..HeapBytes::default() }
                    }
                    Packed::Spilled(_, r) => HeapBytes {
                        spilled_record: std::mem::size_of::<ColdVoxels>(),
                        on_disk: r.disk_bytes(),
                        cache,
                        ..HeapBytes::default()
                    },
                }
            }
        }
    }

    /// The block, unpacking (and reading the spill file) when cold.
    fn block(&self) -> &VoxelBlock {
        match self {
            Self::Hot(b) => b,
            Self::Cold(c) => {
                // Load before store: most reads find the mark set and leave the line shared.
                if !c.read.load(Ordering::Relaxed) {
                    c.read.store(true, Ordering::Relaxed);
                }
                c.thawed.get_or_init(|| c.unpack())
            }
        }
    }

    /// The block for writing: a cold chunk becomes hot (its cache, or a fresh unpack).
    fn block_mut(&mut self) -> &mut VoxelBlock {
        if let Self::Cold(c) = self {
            let block = c.thawed.take().unwrap_or_else(|| c.unpack());
            *self = Self::Hot(block);
        }
        match self {
            Self::Hot(b) => b,
            Self::Cold(_) => unreachable!("made hot above"),
        }
    }
}

impl ColdVoxels {
    /// Unpacks the block. The map reads spilled chunks back before fusion, ray casting and
    /// meshing reach them ([`crate::TsdfMap::restore_spilled`]), so reading the spill file
    /// here is a last resort; packed bytes in memory were made by [`pack`] and always decode.
    fn unpack(&self) -> Box<VoxelBlock> {
        let mut block = VoxelBlock::empty();
        let result = match &self.packed {
            Packed::Memory(bytes) => unpack_into(bytes, &mut block).map_err(|e| e.to_string()),
            Packed::Spilled(file, record) => file
                .read(record)
                .and_then(|bytes| unpack_into(&bytes, &mut block).map_err(|e| file.corrupt(record, e)))
                .map_err(|e| e.to_string()),
        };
        if let Err(e) = result {
            // No caller to hand an error to (a `&Chunk` read): this is an invariant broken
            // (bytes in memory changed under us) or the spill file damaged behind the
            // map's back after the explicit read-back paths were skipped.
            panic!("a cold TSDF chunk could not be read back: {e}");
        }
        block
    }
}

impl Deref for VoxelStore {
    type Target = VoxelBlock;

    #[inline]
    fn deref(&self) -> &VoxelBlock {
        self.block()
    }
}

impl DerefMut for VoxelStore {
    #[inline]
    fn deref_mut(&mut self) -> &mut VoxelBlock {
        self.block_mut()
    }
}

/// Heap bytes of a chunk's voxels by kind (see [`VoxelStore::heap_bytes`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct HeapBytes {
    pub(crate) hot: usize,
    pub(crate) packed: usize,
    pub(crate) spilled_record: usize,
    pub(crate) cache: usize,
    pub(crate) on_disk: usize,
}
