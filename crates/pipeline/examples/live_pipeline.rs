//! The pipeline as a library: feed the frames of a synthetic scan one by one, follow the
//! camera pose, then read the labelled mesh and the per-stage timings.
//!
//! ```text
//! cargo run --release -p semrecon-pipeline --example live_pipeline [-- FRAMES]
//! ```
//!
//! The network here has random weights (a trained one comes from a weight file through
//! `semrecon_net::Weights::load`): the classes are arbitrary, the timings are real.

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{FrameSource, SemanticClass};
use semrecon_net::{NetConfig, Segmenter, Weights};
use semrecon_pipeline::{FrameStatus, Pipeline, PipelineConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let frames: usize = std::env::args().nth(1).map_or(Ok(60), |s| s.parse())?;
    let mut scan_config = SyntheticScanConfig::new(2);
    scan_config.frames = frames;
    let (_room, scan) = synthetic_scan(&scan_config)?;

    let net_config = NetConfig::s20();
    let net = Segmenter::new(Weights::random(&net_config, 7), net_config)?;
    // 1 cm voxels keep the example quick; the default is 5 mm.
    let mut config = PipelineConfig::default();
    config.tsdf.voxel_size = 0.01;
    config.tsdf.truncation_voxels = 5.0;
    let mut pipeline = Pipeline::new(config, scan.intrinsics(), Some(net))?;

    for i in 0..scan.len() {
        let result = pipeline.push_frame(&scan.frame(i)?)?;
        if let FrameStatus::Lost(reason) = result.status {
            println!("frame {i}: tracking lost ({reason:?}), not fused");
        }
        if result.keyframe {
            let t = pipeline.pose().map(|p| p.translation).unwrap_or_default();
            println!(
                "frame {i:>4}: keyframe at ({:.2}, {:.2}, {:.2}) m, semantic pass started: {}",
                t.x, t.y, t.z, result.semantic_pass
            );
        }
    }
    let mesh = pipeline.finish()?;
    println!("\n{} poses, mesh of {} vertices", pipeline.trajectory().len(), mesh.vertex_count());
    let mut counts = [0usize; SemanticClass::COUNT];
    for &l in &mesh.vertex_labels {
        if let Some(c) = counts.get_mut(l as usize) {
            *c += 1;
        }
    }
    for c in SemanticClass::ALL {
        if counts[c.id() as usize] > 0 {
            println!("  {:<9} {:>8} vertices", c.name(), counts[c.id() as usize]);
        }
    }
    if let Some(up) = pipeline.up() {
        println!("up {:?} ({:?}), floor at {:.2} m", up.up, up.source, up.floor_height);
    }
    println!("\n{:<18} {:>9} {:>9} {:>9} {:>6}", "stage", "median ms", "p95 ms", "max ms", "count");
    for (name, s) in pipeline.timings().summaries() {
        println!("{name:<18} {:>9.1} {:>9.1} {:>9.1} {:>6}", s.median_ms, s.p95_ms, s.max_ms, s.count);
    }
    Ok(())
}
