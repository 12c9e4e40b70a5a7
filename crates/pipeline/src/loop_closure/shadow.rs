//! A re-integration spread over keyframes: the chunks to rebuild are built in a *shadow* map
//! beside the live one, which goes on tracking and fusing, and handed to it when complete.
//!
//! Why: re-fusing the frames of the moved chunks costs seconds on 7-Scenes; run at once it
//! stalls the front end for that long. The shadow fuses a bounded amount per keyframe
//! ([`super::LoopClosureConfig::reintegration_frames_per_keyframe`] frames' worth of chunk
//! integrations), so the stall per keyframe is bounded and the tracker keeps working on the
//! live map (in the frame it was tracking in) meanwhile.
//!
//! What it holds, chunk by chunk (copy on write): the rebuilt chunks, which start empty; a
//! copy of every other chunk the live map is about to change while the shadow lives, taken
//! before the change (the live frames are fused into the shadow again at their corrected
//! poses); and the chunks that did not exist when it started. Nothing else is copied: the start
//! costs the plan, not a copy of the map (a whole-map copy was a 0.76 s stall on 7-Scenes and
//! doubled the map's memory while it lived).
//!
//! How it stays exact for what it rebuilds: its queue holds, in capture order, the stored
//! frames recorded in the rebuilt chunks (fused, at their corrected poses, into the rebuilt
//! chunks and the chunks that did not exist at the start), then every frame fused live since
//! the start (fused whole at its corrected pose, into the shadow's copies). Each rebuilt chunk
//! therefore receives its frames in capture order at the corrected poses, which is what fusing
//! the scan afresh at those poses gives. The swap happens at the first keyframe at which the
//! queue is empty: a count of frames, never a clock, so the output does not depend on time or
//! threads. What it approximates: a chunk that is not rebuilt keeps frames that moved less than
//! the threshold there, and a frame whose corrected view newly reaches such a chunk is not
//! added to it (see `plan`).

use std::collections::{HashMap, VecDeque};

use glam::Affine3A;
use semrecon_data::{Frame, Intrinsics};
use semrecon_recon::{averaged_frame, ChunkKey, TsdfMap};

use super::plan::Plan;
use super::StoredFrame;
use crate::error::Result;

/// Revisions the shadow skips at its start. The mesher and the semantic cells notice a changed
/// chunk by its revision (the cells by comparing with the largest they saw); the shadow counts
/// from this far above the live map, so a chunk it hands back carries a revision above any the
/// live map gave meanwhile. The live map takes one revision per fused frame, so a window
/// shorter than this many frames is safe ([`Shadow::must_finish`]).
const REVISION_GAP: u64 = 1 << 20;

/// A run of stored frames is fused from its average only when at least this fraction of its
/// middle frame's valid pixels found a partner in every other frame of the run; otherwise
/// frame by frame. Consecutive frames of a steady camera pair 90-98 % (the rest: occlusion
/// edges, the border of a panning view, flying pixels); far less means the run's poses
/// disagree, and an average would drop most of its surface.
const MIN_PAIRED_FRACTION: f64 = 0.5;

/// Other frames of a run that must confirm a pixel of its middle frame for the pixel to be
/// fused (averaged over the frames that do). One: a depth no other frame of the run sees
/// (a flying pixel, one frame's glimpse past an edge) is left out, while a thin object that
/// parallax takes off some frames' pixels stays. Measured on the rendered drifting loop at a
/// stride of 4 (docs/loop_closure.md): requiring every frame kept 95.3 % of the exact
/// re-fusion's completeness at 1.74 mm accuracy, one 97.6 % at 1.87 mm, none 98.4 % at
/// 1.98 mm (exact: 2.30 mm).
const MIN_PARTNERS: usize = 1;

/// Where a chunk of the shadow came from, which says what frames may go into it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Origin {
    /// Rebuilt: cleared at the start, every frame recorded in it fused again.
    Rebuilt,
    /// Copied from the live map before a live frame changed it (or before the shadow fused a
    /// live frame into it): only the frames fused live since the start go into it.
    Copied,
    /// Absent from the live map at the start: every frame that reaches it goes into it.
    Absent,
}

/// One unit of the shadow's work: stored frames to fuse as one (a run) or one by one.
struct Work {
    /// Positions in the frame store, in capture order: frames with pixels, each following
    /// the frames the previous one stands for (consecutive frames of the scan).
    frames: Vec<usize>,
    /// How many fused frames they stand for (their observations weigh that much): their
    /// count, or more where the store thinned out frames between them.
    weight: usize,
    /// Fused live since the start: fused whole. Otherwise into the rebuilt and absent chunks
    /// only.
    whole: bool,
}

/// A re-integration in progress. See the module documentation.
pub(super) struct Shadow {
    map: TsdfMap,
    origin: HashMap<ChunkKey, Origin>,
    queue: VecDeque<Work>,
    rebuilt: usize,
    /// Per stored frame (those stored since the start included), the pose the shadow fuses
    /// it at and the live map will hold it at after the swap.
    pub poses: Vec<Affine3A>,
    /// Frames whose correction moves the map by more than the threshold somewhere.
    pub moved: usize,
    /// Fusions into the shadow so far (a run fused from its average counts once).
    pub fused: usize,
    /// Chunk integrations so far.
    pub chunk_fusions: usize,
    /// Runs of stored frames fused from their average.
    pub averaged_runs: usize,
    /// Runs fused frame by frame because their frames disagreed ([`MIN_PAIRED_FRACTION`]).
    pub unaveraged_runs: usize,
    /// Over the runs' middle frames: pixels averaged.
    pub averaged_pixels: usize,
    /// Over the runs' middle frames: valid pixels.
    pub candidate_pixels: usize,
    /// Frames fused live since the start.
    window_frames: usize,
    /// The frame at which it started.
    pub started_at: usize,
    /// Time spent on it, ms (the plan and the fusions).
    pub ms: f64,
    /// The most time it took at one frame, ms (its start included in the first).
    pub longest_ms: f64,
    /// Time of the start not yet counted in a keyframe's share, ms.
    pub start_ms: f64,
    /// Time of the start (the plan), ms.
    pub plan_ms: f64,
}

impl Shadow {
    /// Starts an empty shadow of `live` for `plan`.
    ///
    /// With `stride` above 1, runs of consecutive stored frames standing for up to `stride`
    /// frames are re-fused as the average of their depths, weighing as much as the frames
    /// they stand for ([`super::LoopClosureConfig::reintegration_stride`]); frames fused live
    /// meanwhile are always fused one by one. Frames whose pixels the store thinned out are
    /// skipped: the frame before them stands for them.
    pub fn start(live: &TsdfMap, plan: Plan, frames: &[StoredFrame], started_at: usize, stride: usize) -> Self {
        let rebuilt = plan.rebuild.len();
        let origin = plan.rebuild.into_iter().map(|k| (k, Origin::Rebuilt)).collect();
        let mut queue: VecDeque<Work> = VecDeque::new();
        // The position just past what the last queued frame stands for.
        let mut next = None;
        for frame in plan.work {
            let stands_for = frames[frame].stands_for;
            if frames[frame].pixels.is_none() {
                continue;
            }
            match queue.back_mut() {
                Some(w) if next == Some(frame) && w.weight + stands_for <= stride.max(1) => {
                    w.frames.push(frame);
                    w.weight += stands_for;
                }
                _ => queue.push_back(Work { frames: vec![frame], weight: stands_for, whole: false }),
            }
            next = Some(frame + stands_for);
        }
        Self {
            map: live.empty_successor(REVISION_GAP),
            origin,
            queue,
            rebuilt,
            poses: plan.poses,
            moved: plan.moved,
            fused: 0,
            chunk_fusions: 0,
            averaged_runs: 0,
            unaveraged_runs: 0,
            averaged_pixels: 0,
            candidate_pixels: 0,
            window_frames: 0,
            started_at,
            ms: 0.0,
            longest_ms: 0.0,
            start_ms: 0.0,
            plan_ms: 0.0,
        }
    }

    /// Chunks being rebuilt.
    pub fn rebuilt_chunks(&self) -> usize {
        self.rebuilt
    }

    /// Before the live map fuses a frame into `keys`: copies those chunks the shadow does not
    /// own yet, as they are before the change.
    pub fn before_live_fusion(&mut self, live: &TsdfMap, keys: &[ChunkKey]) {
        self.claim(live, keys);
    }

    /// Takes ownership of `keys` not owned yet: copies of the live map's chunks, or absent.
    fn claim(&mut self, live: &TsdfMap, keys: &[ChunkKey]) {
        let mut copy = Vec::new();
        for &k in keys {
            if let std::collections::hash_map::Entry::Vacant(e) = self.origin.entry(k) {
                if live.chunk(k).is_some() {
                    e.insert(Origin::Copied);
                    copy.push(k);
                } else {
                    e.insert(Origin::Absent);
                }
            }
        }
        if !copy.is_empty() {
            self.map.copy_chunks_from(live, &copy);
        }
    }

    /// A frame fused live since the start (stored at `frame`): queued, to be fused whole at
    /// `pose` after everything before it.
    pub fn push_live_frame(&mut self, frame: usize, pose: Affine3A) {
        debug_assert_eq!(frame, self.poses.len());
        self.poses.push(pose);
        self.window_frames += 1;
        self.queue.push_back(Work { frames: vec![frame], weight: 1, whole: true });
    }

    /// Positions of the stored frames it has yet to fuse (the store keeps their pixels).
    pub fn queued_frames(&self) -> impl Iterator<Item = usize> + '_ {
        self.queue.iter().flat_map(|w| w.frames.iter().copied())
    }

    /// Whether it must complete now: the revision gap would run out (see [`REVISION_GAP`]).
    pub fn must_finish(&self) -> bool {
        self.window_frames as u64 >= REVISION_GAP / 2
    }

    /// Fuses queued frames until `budget` chunk integrations are spent (at least one frame;
    /// all with `None`); returns whether the queue is empty. A frame also costs its chunk
    /// selection, counted as `selection_cost` chunk integrations, so that frames fused into a
    /// few chunks each do not run up seconds of selections at one keyframe.
    pub fn step(
        &mut self,
        live: &TsdfMap,
        frames: &[StoredFrame],
        intrinsics: Intrinsics,
        budget: Option<usize>,
        selection_cost: usize,
    ) -> Result<bool> {
        let t = std::time::Instant::now();
        let mut spent = 0;
        while budget.is_none_or(|b| spent < b) {
            let Some(work) = self.queue.pop_front() else { break };
            // A run's warp costs about a selection per frame of it.
            let overhead = selection_cost * work.frames.len();
            spent += self.fuse(live, frames, intrinsics, work)? + overhead;
        }
        let ms = t.elapsed().as_secs_f64() * 1e3;
        self.ms += ms;
        self.longest_ms = self.longest_ms.max(ms + std::mem::take(&mut self.start_ms));
        Ok(self.queue.is_empty())
    }

    /// Fuses one unit of work at its planned poses; returns the chunks it was fused into.
    fn fuse(&mut self, live: &TsdfMap, frames: &[StoredFrame], intrinsics: Intrinsics, work: Work) -> Result<usize> {
        // The queue holds frames with pixels only (the store keeps them while queued).
        let run: Vec<(usize, Frame)> =
            work.frames.iter().filter_map(|&p| frames[p].frame(intrinsics).map(|f| (p, f))).collect();
        let weight_of = |p: usize| if work.whole { 1.0 } else { frames[p].stands_for as f32 };
        let span_of = |p: usize| frames[p].index..=frames[p].last_index;
        if run.len() < 2 {
            let mut fused = 0;
            for (p, frame) in &run {
                fused += self.fuse_frame(live, frame, *p, work.whole, weight_of(*p), span_of(*p))?;
            }
            return Ok(fused);
        }
        // A run: its middle frame (the least parallax to the others) takes the average of the
        // run's depths, and is fused once weighing the run. Its pixels are averaged over the
        // frames that confirm them, and kept where at least `MIN_PARTNERS` do.
        let middle = run.len() / 2;
        let others: Vec<(&[f32], Affine3A)> = run
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != middle)
            .map(|(_, (p, f))| (f.depth.as_slice(), self.poses[*p]))
            .collect();
        let (middle_position, middle_frame) = &run[middle];
        let pose = self.poses[*middle_position];
        let averaged = averaged_frame(self.map.config(), middle_frame, pose, &others, 0.0, MIN_PARTNERS);
        self.averaged_pixels += averaged.paired;
        self.candidate_pixels += averaged.candidates;
        if (averaged.paired as f64) < MIN_PAIRED_FRACTION * averaged.candidates as f64 {
            // The run's frames disagree (a jump in the poses, a fast turn): each is fused on
            // its own, which is exact.
            self.unaveraged_runs += 1;
            let mut fused = 0;
            for (p, f) in &run {
                fused += self.fuse_frame(live, f, *p, false, weight_of(*p), span_of(*p))?;
            }
            return Ok(fused);
        }
        self.averaged_runs += 1;
        let span = run[0].1.index..=frames[run[run.len() - 1].0].last_index;
        self.fuse_frame(live, &averaged.frame, *middle_position, false, work.weight as f32, span)
    }

    /// Fuses `frame` (stored at `position`) at its planned pose, its observations weighing
    /// `weight` and standing for the frames `span`: whole (`whole`: fused live since the
    /// start), or into the rebuilt and new chunks only.
    fn fuse_frame(
        &mut self,
        live: &TsdfMap,
        frame: &Frame,
        position: usize,
        whole: bool,
        weight: f32,
        span: std::ops::RangeInclusive<usize>,
    ) -> Result<usize> {
        let pose = self.poses[position];
        let selection = self.map.select_chunks(frame, pose)?;
        let keys: Vec<ChunkKey> = if whole {
            self.claim(live, &selection);
            selection
        } else {
            // Chunks neither rebuilt nor new keep what they hold (within the threshold).
            let fresh: Vec<ChunkKey> = selection
                .iter()
                .copied()
                .filter(|k| !self.origin.contains_key(k) && live.chunk(*k).is_none())
                .collect();
            self.claim(live, &fresh);
            selection
                .into_iter()
                .filter(|k| matches!(self.origin.get(k), Some(Origin::Rebuilt | Origin::Absent)))
                .collect()
        };
        if keys.is_empty() {
            return Ok(0);
        }
        self.map.integrate_chunks_weighted(frame, pose, &keys, weight, span)?;
        self.fused += 1;
        self.chunk_fusions += keys.len();
        Ok(keys.len())
    }

    /// Hands the completed shadow to `live`: every chunk it owns takes the shadow's version
    /// (or is freed, where the shadow has none).
    pub fn swap_into(self, live: &mut TsdfMap) {
        let Self { map, origin, .. } = self;
        live.adopt_chunks(map, origin.into_keys());
    }
}
