//! Frame-to-model tracking of a whole sequence with every kept frame fused at its tracked
//! pose, and the tracked positions beside the ground truth for the trajectory error: the
//! loop the accuracy and peer benchmarks share.
#![allow(dead_code)]

use glam::Vec3;
use semrecon_data::Frame;
use semrecon_recon::{ate_rmse, GroupedFusion, TrackingResult, TsdfMap};

/// Where the tracker put the frames that have a ground-truth pose.
pub struct TrackedPath {
    /// Tracked camera positions, world frame, metres.
    pub estimated: Vec<Vec3>,
    /// Ground-truth camera positions of the same frames.
    pub ground_truth: Vec<Vec3>,
    /// Frames the tracker did not let fuse.
    pub lost: usize,
}

impl TrackedPath {
    /// RMS position error after a rigid Horn alignment, millimetres (NaN without positions).
    pub fn ate_mm(&self) -> f64 {
        ate_rmse(&self.estimated, &self.ground_truth).map_or(f64::NAN, |e| e * 1e3)
    }
}

/// Tracks every frame against `map` with `track` (the tracker's call, timed or not) and fuses
/// the frames the tracker keeps at their tracked pose.
pub fn track_and_fuse(
    frames: &[Frame],
    map: &mut TsdfMap,
    mut track: impl FnMut(&Frame, &TsdfMap) -> Result<TrackingResult, String>,
) -> Result<TrackedPath, String> {
    let mut path = TrackedPath { estimated: Vec::new(), ground_truth: Vec::new(), lost: 0 };
    // Far chunks from pairs of frames when the map's configuration asks for it.
    let mut fusion = GroupedFusion::for_map(map);
    for f in frames {
        let r = track(f, map)?;
        if !r.should_fuse() {
            path.lost += 1;
            continue;
        }
        fusion.integrate(map, f, r.world_from_camera).map_err(|e| e.to_string())?;
        if let Some(g) = f.world_from_camera {
            path.estimated.push(Vec3::from(r.world_from_camera.translation));
            path.ground_truth.push(Vec3::from(g.translation));
        }
    }
    fusion.flush(map).map_err(|e| e.to_string())?;
    Ok(path)
}
