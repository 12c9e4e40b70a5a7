//! Evaluation for semrecon: how far an estimated camera trajectory is from the ground truth
//! (ATE after a rigid alignment, RPE per second, as the TUM RGB-D benchmark tools and `evo`
//! compute them) and how far a reconstructed surface is from the true one (accuracy,
//! completeness, precision / recall / F-score at distance thresholds).
//!
//! ```text
//! Trajectory (gt), Trajectory (est) --evaluate_trajectory--> TrajectoryErrors
//! LabeledMesh (gt), LabeledMesh (est) --evaluate_mesh--> MeshErrors
//! ```
//!
//! Everything is deterministic: surface sampling uses a seeded RNG per triangle and parallel
//! work is collected in input order, so the numbers are the same for any thread count.
#![warn(missing_docs)]

pub mod error;
pub mod mesh_metrics;
pub mod semantic_labels;
pub mod trajectory_metrics;

pub use error::{EvalError, Result};
pub use mesh_metrics::{
    closest_point_on_triangle, evaluate_mesh, sample_surface, MeshErrors, MeshEvalConfig, SurfaceIndex, SurfaceSamples,
    ThresholdScores,
};
pub use semantic_labels::SurfaceLabeler;
pub use trajectory_metrics::{align_rigid, evaluate_trajectory, TrajectoryErrors, TrajectoryEvalConfig};
