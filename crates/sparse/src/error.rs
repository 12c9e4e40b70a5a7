//! The one error type of the sparse convolution crate. Everything a caller can get wrong
//! (shapes, coordinates, configuration) is reported here instead of panicking, with the row or
//! the sizes involved so that the culprit can be found without a debugger.

/// Result with [`SparseError`].
pub type Result<T, E = SparseError> = std::result::Result<T, E>;

/// Everything that can go wrong while building sparse tensors, kernel maps or running kernels.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SparseError {
    /// A coordinate outside the packed key range (see [`crate::key`]).
    #[error("coordinate {coord:?} at row {row} is outside the key range (x, y, z in [{min}, {max}], batch in [0, {batch_max}])", min = crate::key::COORD_MIN, max = crate::key::COORD_MAX, batch_max = crate::key::BATCH_MAX)]
    CoordOutOfRange {
        /// Row of the offending coordinate (or point) in its input.
        row: usize,
        /// The coordinate `[x, y, z, batch]`.
        coord: [i64; 4],
    },
    /// A feature buffer whose length does not match `rows x channels`.
    #[error("{what}: {len} values do not make {rows} rows of {channels} channels")]
    FeatureShape {
        /// Which buffer (`features`, `x`, `dy`, ...).
        what: &'static str,
        /// Its length.
        len: usize,
        /// Expected rows.
        rows: usize,
        /// Expected channels.
        channels: usize,
    },
    /// A weight buffer whose length does not match `[kernel_volume, c_in, c_out]`.
    #[error("weights: {len} values do not match the shape [{kernel_volume}, {c_in}, {c_out}]")]
    WeightShape {
        /// Its length.
        len: usize,
        /// Offsets of the kernel map.
        kernel_volume: usize,
        /// Input channels.
        c_in: usize,
        /// Output channels.
        c_out: usize,
    },
    /// A kernel size that is not odd and positive (submanifold maps) or too large.
    #[error("kernel size {0} is not supported (submanifold maps need an odd size in 1..=9)")]
    KernelSize(usize),
    /// A coordinate list whose length does not match the kernel map it is used with.
    #[error("{what}: {got} coordinates given but the kernel map has {expected} rows")]
    CoordCount {
        /// Which list (`in_coords` or `out_coords`).
        what: &'static str,
        /// Given.
        got: usize,
        /// Expected.
        expected: usize,
    },
    /// A fine voxel of an upsampling map whose parent is not in the coarse set.
    #[error("fine voxel {coord:?} at row {row} has no parent in the coarse set")]
    MissingParent {
        /// Row in the fine set.
        row: usize,
        /// Its coordinate.
        coord: [i32; 4],
    },
    /// More rows than 32-bit row indices can address.
    #[error("{0} rows exceed the supported maximum of 2^32 - 2")]
    TooManyRows(usize),
    /// An engine-owned tensor shorter than the shape an operation reads or writes.
    #[error("{what}: a tensor of {len} values is shorter than the {rows} x {channels} an operation needs")]
    TensorTooShort {
        /// Which operand (`x`, `y`, `weights`, ...).
        what: &'static str,
        /// The tensor's length.
        len: usize,
        /// Rows the operation needs.
        rows: usize,
        /// Values per row.
        channels: usize,
    },
    /// A bad parameter (voxel size, chunk side, point coordinates, ...).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
