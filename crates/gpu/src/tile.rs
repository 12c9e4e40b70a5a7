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

/// Workgroups under which a layer counts as small: its tiles cannot fill a large GPU, so it
/// gets the small tile and its offsets are split (see [`TileShape::for_layer`]). About 1.5
/// waves of one workgroup per SM on an H100/H200 (132 SMs).
pub const SMALL_LAYER_GROUPS: u32 = 192;

/// Workgroups a split layer aims for: several per SM, so that the latency of each workgroup's
/// serial loop over offsets and channel steps is hidden.
const SPLIT_TARGET_GROUPS: u32 = 512;

/// (Offset, channel step) pairs each split keeps at least (fewer would make the partial sums'
/// extra traffic dominate).
const STEPS_PER_SPLIT: u32 = 4;

/// Input channels per step of the chunked kernel (shaders/chunked.wgsl `CT`).
pub const CHANNEL_STEP: u32 = 16;

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

    /// The shape for a layer of `rows` destinations and `c_out` output channels: by the
    /// width ([`Self::for_channels`]) when its tiles fill the GPU, else 64 x 64, the most
    /// workgroups per row. Measured on an H200 with the s20 network's layers (docs/gpu.md,
    /// session 17): 64 x 64 was 1.2-1.4x faster than the width's shape on levels of 277-6,190
    /// voxels, the width's shape 1.1-1.4x faster on 26,006 and 107,365.
    pub fn for_layer(rows: u32, c_out: usize) -> usize {
        let wide = Self::for_channels(c_out);
        let shape = CHUNKED_TILES[wide];
        let groups = rows.div_ceil(shape.rows).saturating_mul((c_out as u32).div_ceil(shape.channels));
        if groups >= SMALL_LAYER_GROUPS {
            wide
        } else {
            0
        }
    }

    /// Into how many ranges to split the serial work of a layer of `groups` workgroups, `kv`
    /// offsets and `c_in` input channels (the sequence of (offset, channel step) pairs each
    /// workgroup walks): 1 for layers that fill the GPU; small layers get enough splits to
    /// make about [`SPLIT_TARGET_GROUPS`] workgroups, each range keeping at least four steps.
    /// On a GPU a workgroup's steps are a chain of dependent loads and barriers, so a small
    /// layer costs its chain's length, not its arithmetic. Each split writes partial sums that
    /// are then added in split order: a function of the sizes alone, so the result's bits do
    /// not depend on the device or the run.
    pub fn splits(groups: u32, kv: u32, c_in: u32) -> u32 {
        if groups == 0 || groups >= SMALL_LAYER_GROUPS {
            return 1;
        }
        let steps = kv.saturating_mul(c_in.div_ceil(CHANNEL_STEP));
        SPLIT_TARGET_GROUPS.div_ceil(groups).clamp(1, (steps / STEPS_PER_SPLIT).max(1))
    }

    /// Workgroup memory of this shape in bytes: the gathered input tile (16 channels x rows),
    /// the weight tile (16 x channels) and the tile's source rows, plus two words.
    pub const fn workgroup_bytes(self) -> u32 {
        (16 * self.rows + 16 * self.channels + self.rows + 2) * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_that_fill_the_gpu_keep_the_widths_shape_and_no_splits() {
        assert_eq!(TileShape::for_layer(107_365, 32), 1);
        assert_eq!(TileShape::for_layer(26_006, 64), 2);
        let groups = 26_006u32.div_ceil(128);
        assert_eq!(TileShape::splits(groups, 27, 64), 1);
    }

    #[test]
    fn small_layers_get_the_small_tile_and_bounded_splits() {
        assert_eq!(TileShape::for_layer(1_380, 128), 0);
        assert_eq!(TileShape::for_layer(277, 160), 0);
        // 277 rows x 160 channels in 64 x 64 tiles: 15 workgroups, 27 x 10 steps: 35 splits
        // make about 512 workgroups.
        assert_eq!(TileShape::splits(5 * 3, 27, 160), 35);
        // A strided layer of 3 input channels (8 steps) keeps at least four steps a split.
        assert_eq!(TileShape::splits(10, 8, 3), 2);
        // A pointwise layer of 16 input channels is one step: never split.
        assert_eq!(TileShape::splits(10, 1, 16), 1);
        assert_eq!(TileShape::splits(0, 27, 16), 1);
        // Enough workgroups already: about the target, no more.
        assert_eq!(TileShape::splits(150, 27, 32), 4);
    }
}
