//! Scans of generated flats (see [`crate::synth::flat`]): the scan planner's view of a flat
//! (its bounding rectangle as the floor, the walls between rooms as obstacles beside the
//! furniture) and a walk through every room in turn, rendered through the sensor model like
//! a single room's scan ([`super::synthetic`]).

use crate::error::Result;
use crate::render::RenderedScan;
use crate::scan_path::{RoomLayout, ScanPlan, TALL_OBSTACLE_TOP};
use crate::synth::{generate_flat, FlatConfig, FlatKind, SyntheticFlat};

use super::synthetic::SyntheticScanConfig;

/// Clearance a walk through a flat keeps from walls and furniture, metres: less than in one
/// room (0.4 m), so that the way through a 0.9 m doorway, and between the furniture of rooms
/// smaller than the single-room generator's, is wide enough.
pub const FLAT_CLEARANCE: f32 = 0.25;

/// The scan planner's view of a flat: the whole floor plan, walls between rooms among the
/// obstacles, so that the only ways from room to room are the doorways; the walls and the
/// furniture that rises above 1 m are what the gaze keeps its distance from.
pub fn flat_layout(flat: &SyntheticFlat) -> RoomLayout {
    let walls = flat.walls();
    let mut layout = RoomLayout {
        floor_min: flat.floor_min,
        floor_max: flat.floor_max,
        floor_z: 0.0,
        ceiling_height: flat.ceiling_height,
        obstacles: flat.obstacles.clone(),
        interest_points: flat.interest_points.clone(),
        tall_obstacles: Vec::new(),
    };
    layout.find_tall_obstacles(&flat.mesh, TALL_OBSTACLE_TOP);
    layout.obstacles.extend(walls.iter().copied());
    layout.tall_obstacles.extend(walls);
    layout
}

/// A walk round every room of `flat` in its order and back to the start, at `frame_rate`.
pub fn flat_scan_plan(flat: &SyntheticFlat, seed: u64, frame_rate: f64) -> ScanPlan {
    let mut plan = ScanPlan::new(flat_layout(flat), seed);
    plan.frame_rate = frame_rate as f32;
    plan.clearance = FLAT_CLEARANCE;
    plan.rooms = flat.rooms.iter().map(|r| (r.floor_min, r.floor_max)).collect();
    // The two-room loop scans keep their walk as it was (loop closure's tests and figures
    // are pinned to their frames); the homes' walks keep their distance from walls.
    if flat.kind == FlatKind::TwoRooms {
        plan.min_view_distance = 0.0;
    }
    plan
}

/// Generates the flat of `flat_config` and renders the walk through it that `config`
/// describes (frames, camera, sensor, frame rate, sweep; `config.style` is not used).
pub fn synthetic_flat_scan(
    flat_config: &FlatConfig,
    config: &SyntheticScanConfig,
    name: impl Into<String>,
) -> Result<(SyntheticFlat, RenderedScan)> {
    let flat = generate_flat(flat_config)?;
    let mut plan = flat_scan_plan(&flat, config.seed, config.frame_rate);
    plan.vertical_sweep_deg = config.vertical_sweep_deg;
    let poses = plan.poses(config.frames)?;
    let scan = RenderedScan::new(name, &flat.mesh, poses, config.intrinsics, config.sensor.clone(), config.frame_rate)?;
    Ok((flat, scan))
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Vec2};

    use super::*;
    use crate::frame::FrameSource;

    /// Rooms visited, in order of first visit, and whether every position is walkable and
    /// keeps its distance from walls and furniture.
    fn check_walk(flat: &SyntheticFlat, poses: &[Affine3A]) -> Vec<usize> {
        let layout = flat_layout(flat);
        let mut visited = Vec::new();
        for p in poses {
            let xy = p.translation.truncate();
            assert!(flat.is_walkable(xy), "camera at {xy} is inside a wall");
            let clearance = layout
                .obstacles
                .iter()
                .map(|(lo, hi)| (*lo - xy).max(xy - *hi).max(Vec2::ZERO).length())
                .fold(f32::INFINITY, f32::min);
            // The plan's clearance, less a grid cell (smoothing's tolerance) and the hand's jitter.
            assert!(clearance > FLAT_CLEARANCE - 0.075, "camera at {xy} is {clearance} m from a wall or obstacle");
            if let Some(r) = flat.room_at(xy, 0.0) {
                if !visited.contains(&r) {
                    visited.push(r);
                }
            }
        }
        visited
    }

    #[test]
    fn a_walk_through_a_home_visits_every_room_through_the_doorways() {
        for seed in [1, 2] {
            let flat = generate_flat(&FlatConfig { seed, kind: FlatKind::Home }).expect("flat");
            // 5 minutes at 10 fps: the same route as at 30 fps, fewer poses to check.
            let plan = flat_scan_plan(&flat, seed, 10.0);
            let poses = plan.poses(3000).expect("walk");
            let mut visited = check_walk(&flat, &poses);
            // The hall first; the way to a room may pass through another.
            assert_eq!(visited[0], 0);
            visited.sort();
            assert_eq!(visited, vec![0, 1, 2, 3, 4], "seed {seed}: rooms walked through");
            // Goes through doorways (at least four of the five: the way into the living room
            // may be through the kitchen), and nowhere else from room to room.
            let passed = flat
                .doorways
                .iter()
                .filter(|d| {
                    poses.iter().any(|p| {
                        let xy = p.translation.truncate();
                        xy.cmpge(d.min).all() && xy.cmple(d.max).all()
                    })
                })
                .count();
            assert!(passed >= 4, "seed {seed}: passed {passed} doorways");
            // Handheld speeds, and back at the start.
            for w in poses.windows(2) {
                assert!((w[1].translation - w[0].translation).length() * 10.0 < 0.6);
            }
            assert!((poses[0].translation - poses[poses.len() - 1].translation).length() < 0.01);
            assert_eq!(poses, plan.poses(3000).expect("walk"), "seed {seed}: not deterministic");
        }
    }

    #[test]
    fn a_minute_long_loop_goes_through_both_rooms_and_back() {
        for seed in 0..5 {
            let flat = generate_flat(&FlatConfig { seed, kind: FlatKind::TwoRooms }).expect("flat");
            let plan = flat_scan_plan(&flat, seed, 30.0);
            let poses = plan.poses(1800).expect("walk");
            assert_eq!(check_walk(&flat, &poses), vec![0, 1], "seed {seed}");
            let d = flat.doorways[0].centre();
            // Through the doorway and back: twice near its middle, at least a second apart.
            let near: Vec<usize> =
                (0..poses.len()).filter(|&i| poses[i].translation.truncate().distance(d) < 0.25).collect();
            assert!(near.last().zip(near.first()).is_some_and(|(l, f)| l - f > 30), "seed {seed}: {near:?}");
            assert!((poses[0].translation - poses[1799].translation).length() < 0.01);
        }
    }

    #[test]
    fn a_walk_through_a_home_does_not_stare_at_a_wall_from_inside_the_sensors_range() {
        // With 0.25 m of clearance the walk passes walls closely; before the gaze kept its
        // distance, the flat of seed 1 faced a wall from 0.28-0.43 m for 10 s on end
        // (frames 4,850-5,020 at 30 fps), where the sensor model (0.4 m minimum) gives no depth.
        for seed in [1, 2] {
            let flat = generate_flat(&FlatConfig { seed, kind: FlatKind::Home }).expect("flat");
            let plan = flat_scan_plan(&flat, seed, 30.0);
            // The default five minutes at 30 fps.
            let poses = plan.poses(9000).expect("walk");
            let ranges = plan.view_ranges(&poses, 5.0);
            let near = ranges.iter().filter(|&&r| r < 0.45).count();
            assert!(
                near * 100 < ranges.len(),
                "seed {seed}: {near} of {} poses face a wall within 0.45 m",
                ranges.len()
            );
            let mut run = 0;
            for (i, &r) in ranges.iter().enumerate() {
                run = if r < 0.4 { run + 1 } else { 0 };
                // At most a second on end (a turn away from a door leaf met in passing).
                assert!(run <= 30, "seed {seed}: poses up to {i} face a wall within 0.4 m for {run} frames");
            }
            // Without the rule, the same walk stares at walls from close.
            let mut without = plan.clone();
            without.min_view_distance = 0.0;
            let before = without.view_ranges(&without.poses(9000).expect("walk"), 5.0);
            let near_before = before.iter().filter(|&&r| r < 0.45).count();
            assert!(near_before > near, "seed {seed}: {near_before} poses within 0.45 m without the rule, {near} with");
            if seed == 1 {
                assert!(near_before > 300, "seed 1 without the rule: {near_before}");
            }
        }
    }

    #[test]
    fn a_flat_scan_renders_labelled_frames() {
        let mut config = SyntheticScanConfig::new(4);
        config.frames = 3;
        config.intrinsics = config.intrinsics.scaled(80, 60);
        let (_flat, scan) =
            synthetic_flat_scan(&FlatConfig { seed: 4, kind: FlatKind::TwoRooms }, &config, "synth-loop:4")
                .expect("scan");
        assert_eq!(scan.name(), "synth-loop:4");
        let f = scan.frame(2).expect("frame");
        f.validate().expect("valid frame");
        assert!(f.depth.iter().filter(|&&d| d > 0.0).count() > f.depth.len() / 2);
    }
}
