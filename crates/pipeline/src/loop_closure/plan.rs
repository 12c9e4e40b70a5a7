//! What a re-integration rebuilds: the chunks where a correction moves the map by more than a
//! fraction of a voxel, and the stored frames that made them.
//!
//! Why per chunk and not per frame: on a scan that dwells on one place (7-Scenes) every frame
//! shares chunks with most others, so "every chunk a moved frame touched, and every frame that
//! touched those" was nearly the whole map and the whole clip at every correction. What the map
//! needs is narrower: a chunk must be rebuilt when one of the frames fused into it would now put
//! its surface somewhere else, that is when the frame's pose change, applied to the chunk's
//! centre (which accounts for the depth at which the frame saw it, and for turns), moves it by
//! more than [`super::LoopClosureConfig::min_chunk_move_voxels`] voxels. A chunk whose every
//! frame moved less keeps its voxels: what it holds is within that fraction of a voxel of what
//! re-fusing it would give.
//!
//! The frames to fuse again are those recorded in a rebuilt chunk (its frame runs); each is
//! fused later, at its corrected pose, into the rebuilt chunks its view reaches from there
//! (see `shadow`). A frame whose move stayed under the threshold everywhere it was fused has
//! its surface where it was, so the frames that reach a rebuilt chunk are those recorded in it.

use std::collections::HashSet;

use glam::{Affine3A, Vec3, Vec3A};
use rayon::prelude::*;
use semrecon_recon::{ChunkKey, TsdfMap, CHUNK_SIDE};

use super::StoredFrame;

/// A re-integration, planned from the live map and the corrected poses.
pub(super) struct Plan {
    /// Per stored frame, the pose the map will hold it at: the corrected one for the frames
    /// fused again, where the map holds it for the others.
    pub poses: Vec<Affine3A>,
    /// Frames whose correction moves some point of the map by more than the threshold.
    pub moved: usize,
    /// Chunks to rebuild.
    pub rebuild: HashSet<ChunkKey>,
    /// Stored frames to fuse again, in capture order (positions in the store).
    pub work: Vec<usize>,
}

impl Plan {
    /// Whether there is nothing to do: no chunk moves by more than the threshold.
    pub fn is_empty(&self) -> bool {
        self.rebuild.is_empty()
    }
}

/// Plans bringing `map` (which holds each stored frame at its `map_pose`) to `estimates`
/// (one per stored frame): chunks move when a frame recorded in them moves their centre by
/// more than `min_move_m` metres.
pub(super) fn plan(map: &TsdfMap, frames: &[StoredFrame], estimates: &[Affine3A], min_move_m: f32) -> Plan {
    // The correction of each frame as a move of the world: where its view of a point now puts
    // that point.
    let deltas: Vec<Affine3A> = frames.iter().zip(estimates).map(|(f, e)| *e * f.map_pose.inverse()).collect();
    // A frame whose delta moves no point of the map by more than the threshold needs no
    // per-chunk check: |R c + t - c| <= |R - I| |c| + |t| (Frobenius norm) for |c| up to
    // the map's extent.
    let reach = map.chunks().map(|c| chunk_centre(map, c.key()).length()).fold(0.0f32, f32::max);
    let static_frame: Vec<bool> = deltas
        .iter()
        .map(|d| {
            let m = d.matrix3;
            let r = (m.x_axis - Vec3A::X).length_squared()
                + (m.y_axis - Vec3A::Y).length_squared()
                + (m.z_axis - Vec3A::Z).length_squared();
            r.sqrt() * reach + d.translation.length() <= min_move_m
        })
        .collect();
    let moved = static_frame.iter().filter(|s| !**s).count();
    let poses: Vec<Affine3A> = frames.iter().map(|f| f.map_pose).collect();
    if moved == 0 {
        return Plan { poses, moved, rebuild: HashSet::new(), work: Vec::new() };
    }
    let indices: Vec<u32> = frames.iter().map(|f| f.index as u32).collect();
    // Per chunk (in parallel; each result depends on its chunk only): rebuilt when a frame
    // recorded in it moves its centre too far. Runs may cover frames that never touched the
    // chunk (merged gaps); such a frame can only make the test stricter.
    let chunks: Vec<&semrecon_recon::Chunk> = map.chunks().collect();
    let rebuilt: Vec<bool> = chunks
        .par_iter()
        .with_min_len(256)
        .map(|c| {
            let centre = chunk_centre(map, c.key());
            c.frames().runs().iter().any(|&(a, b)| {
                let (lo, hi) = (indices.partition_point(|&i| i < a), indices.partition_point(|&i| i <= b));
                (lo..hi).any(|p| !static_frame[p] && deltas[p].transform_point3(centre).distance(centre) > min_move_m)
            })
        })
        .collect();
    // Frames recorded in a rebuilt chunk: a difference array over the store, which is in
    // capture order.
    let mut cover = vec![0i64; indices.len() + 1];
    let mut rebuild = HashSet::new();
    for (c, _) in chunks.iter().zip(&rebuilt).filter(|(_, r)| **r) {
        rebuild.insert(c.key());
        for &(a, b) in c.frames().runs() {
            cover[indices.partition_point(|&i| i < a)] += 1;
            cover[indices.partition_point(|&i| i <= b)] -= 1;
        }
    }
    let mut depth = 0i64;
    let mut poses = poses;
    let mut work = Vec::new();
    for (p, d) in cover[..indices.len()].iter().enumerate() {
        depth += d;
        if depth > 0 {
            work.push(p);
            poses[p] = estimates[p];
        }
    }
    Plan { poses, moved, rebuild, work }
}

/// The world position of chunk `key`'s centre (voxel centres sit at multiples of the voxel
/// size, so chunk k spans voxels 8k .. 8k + 7).
fn chunk_centre(map: &TsdfMap, key: ChunkKey) -> Vec3 {
    let half = (CHUNK_SIDE as f32 - 1.0) / 2.0;
    (key.as_vec3() * CHUNK_SIDE as f32 + Vec3::splat(half)) * map.config().voxel_size
}
