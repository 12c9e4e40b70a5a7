//! A re-integration spread over keyframes: the map brought to corrected poses in a *shadow*
//! copy while the live map goes on tracking and fusing, swapped in when complete.
//!
//! Why: re-fusing every frame that touched the moved chunks costs 2-5 s on 7-Scenes; run at
//! once it stalls the front end for that long. The shadow does a bounded number of frame
//! fusions per keyframe ([`super::LoopClosureConfig::reintegration_frames_per_keyframe`]),
//! so the stall per keyframe is bounded and the tracker keeps working on the live map (in
//! the frame it was tracking in) meanwhile.
//!
//! How it stays exact: the shadow starts as a copy of the live map with the chunks to rebuild
//! cleared. Its queue holds, in capture order, the stored frames that touched those chunks
//! (fused into them only, at the corrected poses), then every frame fused live since the
//! start (fused whole, at its corrected pose). Each chunk therefore receives its frames in
//! capture order at the poses of the plan, which is what fusing the scan afresh at those poses
//! gives, bit for bit. The swap happens at the first keyframe at which the queue is empty:
//! a count of frames, never a clock, so the output does not depend on time or threads.
//!
//! Why a copy of the whole map and not of the rebuilt chunks only: the map has no way to
//! move a chunk between maps from this crate, and swapping whole maps is one pointer swap.
//! The copy costs a memcpy of the map at the start (tens of milliseconds for 7-Scenes'
//! map) and a second map in memory while the shadow lives.

use std::collections::{HashSet, VecDeque};

use glam::Affine3A;
use semrecon_data::Intrinsics;
use semrecon_recon::{ChunkKey, TsdfMap};

use super::StoredFrame;
use crate::error::Result;

/// Revisions the shadow skips at its start. The mesher notices a changed chunk by its
/// revision differing from the one it meshed; the live map and the shadow each count
/// revisions from the same copy, so without a gap a rebuilt chunk could carry the very
/// revision the live map gave that chunk meanwhile, and the mesher would skip it. The live
/// map takes one revision per fused frame, so a window shorter than this many frames is safe
/// ([`Shadow::must_finish`]).
const REVISION_GAP: u64 = 1 << 20;

/// One unit of the shadow's work: a stored frame to fuse.
struct Work {
    /// Position in the frame store.
    frame: usize,
    /// Fused into the rebuilt chunks only (frames from before the start), or whole (frames
    /// fused live since the start).
    rebuilt_only: bool,
    /// Its chunk selection at the planned pose, when already known.
    selection: Option<Vec<ChunkKey>>,
}

/// What a re-integration changes, planned at its start.
pub(super) struct Plan {
    /// Per stored frame, whether it moves to its corrected pose.
    pub moved: Vec<bool>,
    /// Per stored frame, the pose the map will hold it at.
    pub poses: Vec<Affine3A>,
    /// Chunks to clear and rebuild, sorted (z, y, x).
    pub keys: Vec<ChunkKey>,
    /// The same, for lookups.
    pub rebuild: HashSet<ChunkKey>,
    /// Stored frames that touched a rebuilt chunk, in capture order, with the selections
    /// already computed (the moved frames').
    pub work: Vec<(usize, Option<Vec<ChunkKey>>)>,
}

impl Plan {
    /// Fuses stored frame `pos` of `frames` into `map` at its planned pose, into the rebuilt
    /// chunks only or whole; returns whether it changed a chunk it was asked into.
    fn fuse(
        map: &mut TsdfMap,
        rebuild: &HashSet<ChunkKey>,
        frames: &[StoredFrame],
        intrinsics: Intrinsics,
        pose: Affine3A,
        work: Work,
    ) -> Result<bool> {
        let frame = frames[work.frame].frame(intrinsics);
        let selection = match work.selection {
            Some(s) => s,
            None => map.select_chunks(&frame, pose)?,
        };
        let mine: Vec<ChunkKey> =
            if work.rebuilt_only { selection.into_iter().filter(|k| rebuild.contains(k)).collect() } else { selection };
        if mine.is_empty() {
            return Ok(false);
        }
        map.integrate_chunks(&frame, pose, &mine)?;
        Ok(true)
    }

    /// Re-integrates in place: clears the chunks and fuses the work into them now (the end
    /// of a scan, or no per-keyframe budget). Returns the frames fused.
    pub fn apply(self, map: &mut TsdfMap, frames: &[StoredFrame], intrinsics: Intrinsics) -> Result<usize> {
        map.reset_chunks(&self.keys);
        let mut fused = 0;
        for (frame, selection) in self.work {
            let work = Work { frame, rebuilt_only: true, selection };
            fused += usize::from(Self::fuse(map, &self.rebuild, frames, intrinsics, self.poses[frame], work)?);
        }
        map.free_unobserved(&self.keys);
        Ok(fused)
    }
}

/// A re-integration in progress. See the module documentation.
pub(super) struct Shadow {
    map: TsdfMap,
    rebuild: HashSet<ChunkKey>,
    keys: Vec<ChunkKey>,
    queue: VecDeque<Work>,
    /// Per stored frame (those stored since the start included), the pose the shadow fuses
    /// it at and the live map will hold it at after the swap.
    pub poses: Vec<Affine3A>,
    /// Frames moved to a corrected pose.
    pub moved: usize,
    /// Frames fused into the shadow so far.
    pub fused: usize,
    /// Frames fused live since the start.
    window_frames: usize,
    /// The frame at which it started.
    pub started_at: usize,
    /// Time spent on it, ms (the copy and the fusions).
    pub ms: f64,
    /// The most time it took at one keyframe, ms (its start included in the first).
    pub longest_ms: f64,
    /// Time of the start not yet counted in a keyframe's share, ms.
    pub start_ms: f64,
}

impl Shadow {
    /// Starts from a copy of `live` with the plan's chunks cleared.
    pub fn start(live: &TsdfMap, plan: Plan, started_at: usize) -> Self {
        let mut map = live.clone();
        for _ in 0..REVISION_GAP {
            map.reset_chunks(&[]);
        }
        map.reset_chunks(&plan.keys);
        Self {
            map,
            rebuild: plan.rebuild,
            keys: plan.keys,
            queue: plan
                .work
                .into_iter()
                .map(|(frame, selection)| Work { frame, rebuilt_only: true, selection })
                .collect(),
            poses: plan.poses,
            moved: plan.moved.iter().filter(|m| **m).count(),
            fused: 0,
            window_frames: 0,
            started_at,
            ms: 0.0,
            longest_ms: 0.0,
            start_ms: 0.0,
        }
    }

    /// Chunks being rebuilt.
    pub fn rebuilt_chunks(&self) -> usize {
        self.keys.len()
    }

    /// A frame fused live since the start (stored at `frame`): queued, to be fused whole at
    /// `pose` after everything before it.
    pub fn push_live_frame(&mut self, frame: usize, pose: Affine3A, moved: bool) {
        debug_assert_eq!(frame, self.poses.len());
        self.poses.push(pose);
        self.moved += usize::from(moved);
        self.window_frames += 1;
        self.queue.push_back(Work { frame, rebuilt_only: false, selection: None });
    }

    /// Whether it must complete now: the revision gap would run out (see [`REVISION_GAP`]).
    pub fn must_finish(&self) -> bool {
        self.window_frames as u64 >= REVISION_GAP / 2
    }

    /// Fuses up to `budget` queued frames (all with `None`); returns whether the queue is
    /// empty.
    pub fn step(&mut self, frames: &[StoredFrame], intrinsics: Intrinsics, budget: Option<usize>) -> Result<bool> {
        let t = std::time::Instant::now();
        let mut left = budget.unwrap_or(usize::MAX);
        while left > 0 {
            let Some(work) = self.queue.pop_front() else { break };
            let pose = self.poses[work.frame];
            self.fused += usize::from(Plan::fuse(&mut self.map, &self.rebuild, frames, intrinsics, pose, work)?);
            left -= 1;
        }
        let ms = t.elapsed().as_secs_f64() * 1e3;
        self.ms += ms;
        self.longest_ms = self.longest_ms.max(ms + std::mem::take(&mut self.start_ms));
        Ok(self.queue.is_empty())
    }

    /// The completed map, its emptied chunks freed.
    pub fn into_map(mut self) -> TsdfMap {
        self.map.free_unobserved(&self.keys);
        self.map
    }
}
