//! The tile shapes of the GPU engine's chunked kernel (shaders/chunked.wgsl): plain data,
//! present in every build so that callers can name and pick shapes without the `gpu` feature.

/// One tile shape of the chunked kernel (shaders/chunked.wgsl `TR`, `TO`, `RQ`, `CQ`): `rows`
/// destinations x `channels` output channels per workgroup of 256 threads, each thread a block
/// of `4 row_quads` destinations x `4 channel_quads` channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileShape {
    /// Destinations per tile.
    pub rows: u32,
    /// Output channels per tile.
    pub channels: u32,
    /// Destinations per thread, in fours.
    pub row_quads: u32,
    /// Output channels per thread, in fours.
    pub channel_quads: u32,
}

/// The chunked kernel's tile shapes, compiled once per device: 64 x 64 (4 x 4 a thread),
/// 128 x 32 for layers of at most 32 output channels, 128 x 64 (8 x 4 a thread) for wider
/// ones, and 64 x 128 (4 x 8 a thread), kept for benchmarks. [`TileShape::for_channels`]
/// picks one; on an H100 (docs/gpu.md, run 6) 128 x 32 was the fastest at 32 channels and
/// 128 x 64 at 64 and 128 (10-13 % ahead of 64 x 64 at 2 cm, 64 x 128 within 3 % at 128
/// channels and 1.9x slower at 64).
pub const CHUNKED_TILES: [TileShape; 4] = [
    TileShape { rows: 64, channels: 64, row_quads: 1, channel_quads: 1 },
    TileShape { rows: 128, channels: 32, row_quads: 1, channel_quads: 1 },
    TileShape { rows: 128, channels: 64, row_quads: 2, channel_quads: 1 },
    TileShape { rows: 64, channels: 128, row_quads: 1, channel_quads: 2 },
];

impl TileShape {
    /// The index in [`CHUNKED_TILES`] of the shape for a layer of `c_out` output channels:
    /// the narrow tile up to 32, 128 x 64 beyond.
    pub fn for_channels(c_out: usize) -> usize {
        if c_out <= 32 {
            1
        } else {
            2
        }
    }

    /// Workgroup memory of this shape in bytes: the gathered input tile (16 channels x rows),
    /// the weight tile (16 x channels) and the tile's source rows, plus two words.
    pub const fn workgroup_bytes(self) -> u32 {
        (16 * self.rows + 16 * self.channels + self.rows + 2) * 4
    }
}
