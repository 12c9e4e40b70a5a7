//! A level of a device voxel hierarchy read back to the host, in plain vectors: what tests
//! compare with the host's geometry (in every build, so that callers need no conditional code).

use semrecon_sparse::Coord;

/// The tables of one level read back to the host (`GpuEngine::download_level`), for checks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostLevel {
    /// The voxels.
    pub coords: Vec<Coord>,
    /// `[rows, 27]` submanifold neighbour rows, `u32::MAX` where absent.
    pub subm: Vec<u32>,
    /// `[next rows, 8]` and `[rows, 8]`: the strided layer's tables, down and up.
    pub down: Option<(Vec<u32>, Vec<u32>)>,
    /// `[rows]` parent rows.
    pub parent: Option<Vec<u32>>,
}
