//! `synth:SEED`: a generated room (see [`crate::synth`]) scanned along a generated handheld
//! trajectory (see [`crate::scan_path`]) and rendered on the fly through the sensor model —
//! a dataset with exact ground truth (poses, depth, per-pixel classes) that needs no files.

use glam::Affine3A;

use crate::camera::Intrinsics;
use crate::error::Result;
use crate::render::RenderedScan;
use crate::scan_path::{RoomLayout, ScanPlan, TALL_OBSTACLE_TOP};
use crate::sensor::SensorModel;
use crate::synth::{generate_room, RoomConfig, RoomStyle, SyntheticRoom};

/// Everything that defines a synthetic scan; `SyntheticScanConfig::new(seed)` gives the
/// defaults `synth:SEED` uses.
#[derive(Debug, Clone)]
pub struct SyntheticScanConfig {
    /// Seed of the room, the trajectory and the sensor noise.
    pub seed: u64,
    /// Room style; drawn from the seed when `None`.
    pub style: Option<RoomStyle>,
    /// Number of frames.
    pub frames: usize,
    /// Camera (default: 640x480, fx = fy = 525, the PrimeSense / Kinect v1 depth camera).
    pub intrinsics: Intrinsics,
    /// Sensor model (default: [`SensorModel::kinect`] seeded with `seed`).
    pub sensor: SensorModel,
    /// Frame rate of the trajectory, Hz.
    pub frame_rate: f64,
    /// Nod of the gaze, degrees (see [`ScanPlan::vertical_sweep_deg`]; 0 = none).
    pub vertical_sweep_deg: f32,
}

impl SyntheticScanConfig {
    /// Frames of `synth:SEED`: 10 s at 30 fps.
    pub const DEFAULT_FRAMES: usize = 300;

    /// The defaults for `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            style: None,
            frames: Self::DEFAULT_FRAMES,
            intrinsics: Intrinsics { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 },
            sensor: SensorModel::kinect().with_seed(seed),
            frame_rate: 30.0,
            vertical_sweep_deg: 0.0,
        }
    }
}

/// The scan planner's view of a generated room.
pub fn room_layout(room: &SyntheticRoom) -> RoomLayout {
    let mut layout = RoomLayout {
        floor_min: room.floor_min,
        floor_max: room.floor_max,
        floor_z: 0.0,
        ceiling_height: room.ceiling_height,
        obstacles: room.obstacles.clone(),
        interest_points: room.interest_points.clone(),
        tall_obstacles: Vec::new(),
    };
    layout.find_tall_obstacles(&room.mesh, TALL_OBSTACLE_TOP);
    layout
}

/// The scan planner's defaults for `room` at `frame_rate`.
fn room_scan_plan(room: &SyntheticRoom, seed: u64, frame_rate: f64) -> ScanPlan {
    let mut plan = ScanPlan::new(room_layout(room), seed);
    plan.frame_rate = frame_rate as f32;
    plan
}

/// A handheld-like trajectory of `frames` poses through `room` at `frame_rate`.
pub fn room_scan_poses(room: &SyntheticRoom, seed: u64, frames: usize, frame_rate: f64) -> Result<Vec<Affine3A>> {
    room_scan_plan(room, seed, frame_rate).poses(frames)
}

/// Generates the room and the scan of `config`; the room is returned too (ground-truth mesh).
pub fn synthetic_scan(config: &SyntheticScanConfig) -> Result<(SyntheticRoom, RenderedScan)> {
    let room = generate_room(&RoomConfig { seed: config.seed, style: config.style });
    synthetic_scan_of(room, config)
}

/// The scan of `config` through a room generated elsewhere (a room furnished from the
/// furniture catalogues, [`crate::library::rooms`]); `config.style` is not used.
pub fn synthetic_scan_of(room: SyntheticRoom, config: &SyntheticScanConfig) -> Result<(SyntheticRoom, RenderedScan)> {
    let mut plan = room_scan_plan(&room, config.seed, config.frame_rate);
    plan.vertical_sweep_deg = config.vertical_sweep_deg;
    let poses = plan.poses(config.frames)?;
    let scan = RenderedScan::new(
        format!("synth:{}", config.seed),
        &room.mesh,
        poses,
        config.intrinsics,
        config.sensor.clone(),
        config.frame_rate,
    )?;
    Ok((room, scan))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameSource;

    #[test]
    fn a_single_rooms_walk_rarely_needs_the_minimum_view_distance() {
        // The gaze's minimum view distance is for walks that pass walls closely (a flat's
        // 0.25 m of clearance); a single room's 0.4 m keeps the camera far enough from its
        // walls, and only once from tall furniture: the demo's scans (seeds 1-10) and all but
        // one of the seeds its settings are chosen on (11-40; seed 25) are the same poses
        // with and without the rule, so the figures measured on them stand.
        let mut changed = Vec::new();
        for seed in 1..=40 {
            let room = generate_room(&RoomConfig { seed, style: None });
            let with = room_scan_plan(&room, seed, 30.0);
            let mut without = with.clone();
            without.min_view_distance = 0.0;
            if with.poses(300).expect("walk") != without.poses(300).expect("walk") {
                changed.push(seed);
            }
        }
        assert_eq!(changed, vec![25]);
    }

    #[test]
    fn a_synthetic_scan_has_ground_truth_and_labels() {
        let mut config = SyntheticScanConfig::new(5);
        config.frames = 3;
        config.intrinsics = config.intrinsics.scaled(160, 120);
        let (_room, scan) = synthetic_scan(&config).expect("scan");
        assert_eq!(scan.len(), 3);
        assert!(scan.has_ground_truth());
        let f = scan.frame(1).expect("frame");
        f.validate().expect("valid frame");
        assert!(f.world_from_camera.is_some());
        let labels = f.labels.as_ref().expect("labels");
        assert!(labels.iter().filter(|&&l| l < 13).count() > labels.len() / 2);
        assert!(f.depth.iter().filter(|&&d| d > 0.0).count() > f.depth.len() / 2);
    }
}
