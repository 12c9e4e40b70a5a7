//! The spill file: packed cold chunks written to disk when the map passes its memory budget,
//! read back when fusion, ray casting or meshing comes near them again.
//!
//! Why one append-only file: a spilled chunk is written once and read back at most once
//! before it changes (a chunk read back for fusion turns hot and is packed afresh later), so
//! nothing is ever rewritten in place; the map keeps each chunk's offset, and the space of
//! records read back is simply not reused (the file is temporary and deleted with the map).
//!
//! Each record carries its chunk key, length and a 64-bit FNV-1a checksum, so a truncated or
//! altered file is reported as an error naming the file and the offset, never a panic and
//! never wrong voxels. A write that fails (full disk, file gone) is cut back off the file and
//! reported; the chunk stays packed in memory, so the map loses nothing.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::compressed::PackError;
use super::ChunkKey;

/// Errors of the spill file; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum SpillError {
    /// The file could not be created, written or read.
    #[error("spill file {path}: cannot {action}: {source}")]
    Io {
        /// The spill file.
        path: PathBuf,
        /// What was being done ("create", "write", "read").
        action: &'static str,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A record read back does not match what was written (truncated or altered file).
    #[error("spill file {path}: record at byte {offset} is damaged: {reason}")]
    Corrupt {
        /// The spill file.
        path: PathBuf,
        /// Where the record starts.
        offset: u64,
        /// What does not match.
        reason: String,
    },
}

/// Record header: magic, chunk key (3 x i32), payload length (u32), checksum (u64).
const HEADER: usize = 4 + 12 + 4 + 8;
const MAGIC: [u8; 4] = *b"SRC1";

/// Where one spilled chunk is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SpillRecord {
    offset: u64,
    len: u32,
    key: ChunkKey,
}

impl SpillRecord {
    /// Bytes the record takes on disk.
    pub(crate) fn disk_bytes(&self) -> usize {
        HEADER + self.len as usize
    }
}

/// An open spill file, deleted when dropped (the last copy of the map sharing it).
#[derive(Debug)]
pub struct SpillFile {
    path: PathBuf,
    /// The file and its length (appends and reads take turns; both are rare next to fusion).
    file: Mutex<(File, u64)>,
}

impl SpillFile {
    /// Creates the file at `path`; refuses to overwrite an existing file.
    pub fn create(path: &Path) -> Result<Self, SpillError> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|source| SpillError::Io { path: path.to_path_buf(), action: "create", source })?;
        Ok(Self { path: path.to_path_buf(), file: Mutex::new((file, 0)) })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes written so far (records read back included: space is not reused).
    pub fn len(&self) -> u64 {
        self.file.lock().map_or(0, |f| f.1)
    }

    /// Whether nothing was written yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn io(&self, action: &'static str, source: std::io::Error) -> SpillError {
        SpillError::Io { path: self.path.clone(), action, source }
    }

    /// Appends the packed chunk `payload` of `key`; on failure the file is cut back to its
    /// length before the call.
    pub(crate) fn append(&self, key: ChunkKey, payload: &[u8]) -> Result<SpillRecord, SpillError> {
        let len = u32::try_from(payload.len())
            .map_err(|_| self.io("write", std::io::Error::other("record larger than 4 GiB")))?;
        let mut buf = Vec::with_capacity(HEADER + payload.len());
        buf.extend_from_slice(&MAGIC);
        for c in key.to_array() {
            buf.extend_from_slice(&c.to_le_bytes());
        }
        buf.extend_from_slice(&len.to_le_bytes());
        buf.extend_from_slice(&fnv1a(payload).to_le_bytes());
        buf.extend_from_slice(payload);
        let mut guard = self.file.lock().map_err(|_| self.io("write", std::io::Error::other("lock poisoned")))?;
        let (file, end) = &mut *guard;
        let offset = *end;
        let written = file.seek(SeekFrom::Start(offset)).and_then(|_| file.write_all(&buf));
        if let Err(e) = written {
            // Leave no half record behind; if even this fails, the bytes past `end` are
            // never indexed, so they are only wasted space.
            let _ = file.set_len(offset);
            return Err(self.io("write", e));
        }
        *end += buf.len() as u64;
        Ok(SpillRecord { offset, len, key })
    }

    /// Reads back the payload of `record`, checking header and checksum.
    pub(crate) fn read(&self, record: &SpillRecord) -> Result<Vec<u8>, SpillError> {
        let mut buf = vec![0u8; record.disk_bytes()];
        {
            let mut guard = self.file.lock().map_err(|_| self.io("read", std::io::Error::other("lock poisoned")))?;
            let file = &mut guard.0;
            file.seek(SeekFrom::Start(record.offset))
                .and_then(|_| file.read_exact(&mut buf))
                .map_err(|e| self.corrupt_reason(record, format!("cannot read it: {e}")))?;
        }
        let (header, payload) = buf.split_at(HEADER);
        let word = |a: usize, b: usize| &header[a..b];
        let mut key = [0i32; 3];
        for (k, c) in key.iter_mut().zip(word(4, 16).chunks_exact(4)) {
            *k = i32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        let len = u32::from_le_bytes([header[16], header[17], header[18], header[19]]);
        let mut sum = [0u8; 8];
        sum.copy_from_slice(word(20, 28));
        if word(0, 4) != MAGIC || ChunkKey::from_array(key) != record.key || len != record.len {
            return Err(self.corrupt_reason(record, "header does not match the index".into()));
        }
        if fnv1a(payload) != u64::from_le_bytes(sum) {
            return Err(self.corrupt_reason(record, "checksum mismatch".into()));
        }
        Ok(payload.to_vec())
    }

    /// The error for a record whose payload does not unpack.
    pub(crate) fn corrupt(&self, record: &SpillRecord, e: PackError) -> SpillError {
        self.corrupt_reason(record, e.to_string())
    }

    fn corrupt_reason(&self, record: &SpillRecord, reason: String) -> SpillError {
        SpillError::Corrupt { path: self.path.clone(), offset: record.offset, reason }
    }
}

#[cfg(test)]
impl SpillFile {
    /// A spill file over an already open file (tests: `/dev/full`). Dropping the result
    /// deletes `path`: keep a reference alive where `path` is not a temporary.
    pub(crate) fn for_test(path: PathBuf, file: File) -> Self {
        Self { path, file: Mutex::new((file, 0)) }
    }
}

impl Drop for SpillFile {
    fn drop(&mut self) {
        // A temporary: nothing in it outlives the map.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// 64-bit FNV-1a: enough to catch damaged records (not an adversary).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::IVec3;

    #[test]
    fn records_read_back_and_damage_is_an_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("map.spill");
        let f = SpillFile::create(&path).expect("create");
        let a = f.append(IVec3::new(1, -2, 3), b"first payload").expect("append");
        let b = f.append(IVec3::new(4, 5, 6), &[7u8; 1000]).expect("append");
        assert_eq!(f.read(&b).expect("read"), vec![7u8; 1000]);
        assert_eq!(f.read(&a).expect("read"), b"first payload");
        assert!(SpillFile::create(&path).is_err(), "an existing file is not overwritten");
        // Altered byte: checksum; truncated file: read error; both name the file.
        let mut bytes = std::fs::read(&path).expect("read file");
        bytes[a.offset as usize + HEADER + 2] ^= 1;
        std::fs::write(&path, &bytes).expect("write");
        let e = f.read(&a).expect_err("altered");
        assert!(e.to_string().contains("map.spill") && e.to_string().contains("checksum"), "{e}");
        std::fs::write(&path, &bytes[..bytes.len() - 10]).expect("truncate");
        let e = f.read(&b).expect_err("truncated");
        assert!(matches!(e, SpillError::Corrupt { .. }), "{e}");
        drop(f);
        assert!(!path.exists(), "deleted with the map");
    }

    /// A full disk: the write fails with an error naming the file, and nothing is indexed.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_full_disk_is_an_error_naming_the_file() {
        let full = OpenOptions::new().read(true).write(true).open("/dev/full").expect("/dev/full");
        // Never dropped, not even when an assertion fails: dropping deletes the file.
        let f =
            std::mem::ManuallyDrop::new(SpillFile { path: PathBuf::from("/dev/full"), file: Mutex::new((full, 0)) });
        let e = f.append(IVec3::ZERO, &[1u8; 4096]).expect_err("no space");
        assert!(e.to_string().contains("/dev/full") && e.to_string().contains("write"), "{e}");
        assert_eq!(f.len(), 0);
    }

    #[test]
    fn unwritable_place_is_a_clear_error() {
        let e = SpillFile::create(Path::new("/nonexistent-dir/sub/map.spill")).expect_err("no such dir");
        assert!(e.to_string().contains("/nonexistent-dir/sub/map.spill") && e.to_string().contains("create"), "{e}");
    }
}
