//! `tracking.csv`: one row per frame of what the tracker measured, written beside
//! `trajectory.txt` by `run` and `demo`, so that a scan that drifted can be read frame by
//! frame: where the alignment left the motion prediction (`departure_m`), how well the view
//! held the motion (`condition`, `constrained`) and how well it fitted (`inlier_ratio`,
//! `residual_rms_m`), and which directions no surface in view held (`support`, `unheld`). A drift seen in the ATE is found here as a run of large departures or
//! small conditions.

use std::fmt::Write as _;
use std::path::Path;

use semrecon_pipeline::{FrameResult, FrameStatus};
use semrecon_recon::LostReason;

/// The rows gathered so far.
#[derive(Default)]
pub struct TrackingLog {
    rows: String,
}

/// The column names, first line of the file.
const HEADER: &str = "frame,status,x_m,y_m,z_m,departure_m,condition,translation_sigma_m,constrained,inlier_ratio,residual_rms_m,colour_fallback,support,unheld,keyframe\n";

impl TrackingLog {
    /// Adds the row of one pushed frame; frames without a tracker's result (ground-truth
    /// poses) leave their measurement columns empty.
    pub fn record(&mut self, r: &FrameResult) {
        let status = match r.status {
            FrameStatus::Initialized => "initialized",
            FrameStatus::Fused => "tracked",
            FrameStatus::Relocalised => "relocalised",
            FrameStatus::NoPose => "no_pose",
            FrameStatus::Lost(reason) => match reason {
                LostReason::NoDepth => "lost_no_depth",
                LostReason::NoModel => "lost_no_model",
                LostReason::FewInliers => "lost_few_inliers",
                LostReason::LargeResidual => "lost_large_residual",
                LostReason::PoseJump => "lost_pose_jump",
                LostReason::Degenerate => "lost_degenerate",
            },
        };
        let _ = write!(self.rows, "{},{status},", r.index);
        match r.pose {
            Some(p) => {
                let t = p.translation;
                let _ = write!(self.rows, "{:.5},{:.5},{:.5},", t.x, t.y, t.z);
            }
            None => self.rows.push_str(",,,"),
        }
        match &r.tracking {
            Some(t) => {
                let _ = write!(
                    self.rows,
                    "{:.5},{:.3e},{:.3e},{},{:.4},{:.6},{},{:.4},{}",
                    t.departure_m,
                    t.condition,
                    t.translation_sigma_m,
                    t.constrained,
                    t.inlier_ratio,
                    t.residual_rms,
                    u8::from(t.colour_fallback),
                    t.support,
                    t.unheld
                );
            }
            None => self.rows.push_str(",,,,,,,,"),
        }
        let _ = writeln!(self.rows, ",{}", u8::from(r.keyframe));
    }

    /// Writes `dir/tracking.csv` (atomically).
    pub fn write(&self, dir: &Path) -> anyhow::Result<()> {
        let path = dir.join("tracking.csv");
        semrecon_data::atomic_file::write_atomic_with(&path, |w| {
            w.write_all(HEADER.as_bytes())?;
            w.write_all(self.rows.as_bytes())
        })?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Affine3A;

    #[test]
    fn rows_have_every_column() {
        let mut log = TrackingLog::default();
        let base = FrameResult {
            index: 3,
            status: FrameStatus::NoPose,
            pose: None,
            keyframe: false,
            semantic_pass: false,
            tracking: None,
        };
        log.record(&base);
        log.record(&FrameResult {
            index: 4,
            status: FrameStatus::Fused,
            pose: Some(Affine3A::from_translation(glam::Vec3::new(1.0, 2.0, 3.0))),
            keyframe: true,
            ..base
        });
        let columns = HEADER.trim_end().split(',').count();
        for line in log.rows.lines() {
            assert_eq!(line.split(',').count(), columns, "{line}");
        }
        assert!(log.rows.starts_with("3,no_pose,,,,"));
        assert!(log.rows.contains("4,tracked,1.00000,2.00000,3.00000,"));
    }
}
