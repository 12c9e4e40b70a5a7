//! An open-addressing hash map from packed voxel keys to row indices. Kernel-map building does
//! one look-up per (voxel, offset), i.e. tens of millions per network pass, so a flat table
//! with linear probing (two parallel arrays, load factor at most 1/2, no deletion, no
//! allocation per entry) beats `std::collections::HashMap` by a wide margin. Two hash
//! functions are offered: a multiply-xorshift mixer (the default, fastest here) and the
//! paper's FNV-style voxel hash (see [`crate::key::fnv_hash`]), which a GPU port can share.

use crate::key::fnv_hash;

const EMPTY: u32 = u32::MAX;

/// The hash function of a [`VoxelHashMap`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyHasher {
    /// A 64-bit multiply-xorshift mixer of the packed key.
    Mix,
    /// The paper's FNV-style hash `(((seed * P) ^ x) * P ^ y) * P ^ z`.
    Fnv {
        /// The random seed `R`.
        seed: u64,
    },
}

/// Open-addressing (linear probing) map from packed voxel keys to `u32` values (row indices;
/// `u32::MAX` is reserved as the empty marker and cannot be stored).
#[derive(Debug, Clone)]
pub struct VoxelHashMap {
    keys: Vec<u64>,
    vals: Vec<u32>,
    mask: usize,
    len: usize,
    hasher: KeyHasher,
}

impl VoxelHashMap {
    /// An empty map sized for `capacity` entries without growing, with the default hasher.
    pub fn with_capacity(capacity: usize) -> Self {
        Self::with_hasher(capacity, KeyHasher::Mix)
    }

    /// An empty map sized for `capacity` entries with the given hash function.
    pub fn with_hasher(capacity: usize, hasher: KeyHasher) -> Self {
        let slots = (capacity.max(4) * 2).next_power_of_two();
        Self { keys: vec![0; slots], vals: vec![EMPTY; slots], mask: slots - 1, len: 0, hasher }
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the map holds no entry.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline]
    fn slot(&self, key: u64) -> usize {
        let h = match self.hasher {
            KeyHasher::Mix => {
                let h = (key ^ (key >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                let h = (h ^ (h >> 32)).wrapping_mul(0x94d0_49bb_1331_11eb);
                h ^ (h >> 29)
            }
            KeyHasher::Fnv { seed } => {
                let h = fnv_hash(key, seed);
                // FNV's low bits are weak for small coordinates: fold the high half in.
                h ^ (h >> 32)
            }
        };
        h as usize & self.mask
    }

    /// The value stored for `key`, if any.
    #[inline]
    pub fn get(&self, key: u64) -> Option<u32> {
        let mut s = self.slot(key);
        loop {
            let v = self.vals[s];
            if v == EMPTY {
                return None;
            }
            if self.keys[s] == key {
                return Some(v);
            }
            s = (s + 1) & self.mask;
        }
    }

    /// Inserts `key -> value` unless `key` is present; returns the value already stored in
    /// that case (the map is unchanged), `None` when the entry was added.
    ///
    /// `value` must not be `u32::MAX` (the empty marker): such a call is ignored and returns
    /// `Some(u32::MAX)`.
    pub fn insert_or_get(&mut self, key: u64, value: u32) -> Option<u32> {
        if value == EMPTY {
            return Some(EMPTY);
        }
        if (self.len + 1) * 2 > self.keys.len() {
            self.grow();
        }
        let mut s = self.slot(key);
        loop {
            let v = self.vals[s];
            if v == EMPTY {
                self.keys[s] = key;
                self.vals[s] = value;
                self.len += 1;
                return None;
            }
            if self.keys[s] == key {
                return Some(v);
            }
            s = (s + 1) & self.mask;
        }
    }

    fn grow(&mut self) {
        let old_keys = std::mem::take(&mut self.keys);
        let old_vals = std::mem::take(&mut self.vals);
        let slots = old_keys.len() * 2;
        self.keys = vec![0; slots];
        self.vals = vec![EMPTY; slots];
        self.mask = slots - 1;
        self.len = 0;
        for (k, v) in old_keys.into_iter().zip(old_vals) {
            if v != EMPTY {
                self.insert_or_get(k, v);
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::key::pack_unchecked;

    #[test]
    fn insert_get_and_grow_with_both_hashers() {
        for hasher in [KeyHasher::Mix, KeyHasher::Fnv { seed: 0x9e37_79b9 }] {
            let mut m = VoxelHashMap::with_hasher(2, hasher);
            let mut n = 0u32;
            for z in -6..6 {
                for y in -6..6 {
                    for x in -6..6 {
                        let k = pack_unchecked([x, y, z, (x & 1).abs()]);
                        assert_eq!(m.insert_or_get(k, n), None);
                        n += 1;
                    }
                }
            }
            assert_eq!(m.len(), n as usize);
            let mut n = 0u32;
            for z in -6..6 {
                for y in -6..6 {
                    for x in -6..6 {
                        let k = pack_unchecked([x, y, z, (x & 1).abs()]);
                        assert_eq!(m.get(k), Some(n));
                        assert_eq!(m.insert_or_get(k, 999_999), Some(n));
                        n += 1;
                    }
                }
            }
            assert_eq!(m.get(pack_unchecked([100, 0, 0, 0])), None);
        }
    }
}
