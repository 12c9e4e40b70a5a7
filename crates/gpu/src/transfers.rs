//! Counts of host-device transfers, kept by every GPU context: the measure of whether a
//! network really stays on the device (weights once per model, one input upload and one
//! read-back per forward). Plain data, built with or without the `gpu` feature.

/// Transfers between host and device since the context was opened.
///
/// Kernel parameters (a few words per dispatch, in uniform buffers) are not counted: they are
/// part of every dispatch, not data.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TransferCounts {
    /// Feature and weight buffers copied to the device (resident tensors and the per-call
    /// copies of the host-slice interface).
    pub tensor_uploads: u64,
    /// Bytes of those.
    pub tensor_bytes: u64,
    /// Layer geometry copied to the device (chunk plans, pair lists, gather tables,
    /// coordinates).
    pub geometry_uploads: u64,
    /// Bytes of those.
    pub geometry_bytes: u64,
    /// Buffers read back to the host.
    pub readbacks: u64,
    /// Bytes of those.
    pub readback_bytes: u64,
    /// Waits for a few status words (the device hierarchy's voxel counts, one per level).
    pub status_reads: u64,
}

impl TransferCounts {
    /// The transfers since `earlier` (a snapshot of the same context).
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            tensor_uploads: self.tensor_uploads.saturating_sub(earlier.tensor_uploads),
            tensor_bytes: self.tensor_bytes.saturating_sub(earlier.tensor_bytes),
            geometry_uploads: self.geometry_uploads.saturating_sub(earlier.geometry_uploads),
            geometry_bytes: self.geometry_bytes.saturating_sub(earlier.geometry_bytes),
            readbacks: self.readbacks.saturating_sub(earlier.readbacks),
            readback_bytes: self.readback_bytes.saturating_sub(earlier.readback_bytes),
            status_reads: self.status_reads.saturating_sub(earlier.status_reads),
        }
    }
}
