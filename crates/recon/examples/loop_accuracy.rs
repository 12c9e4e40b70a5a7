//! How exact loop verification is on a generated scan, whose true poses are known: pairs of
//! frames are aligned by [`LoopDetector::verify`] from their true relative pose and from one
//! perturbed by a few centimetres, and the result is compared with the truth.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example loop_accuracy -- SPEC NEW:OLD [NEW:OLD ...]
//! ```
//!
//! `SPEC` is a dataset with ground truth (`synth-loop:2`); each pair names two frame indices.

use glam::{DAffine3, DVec3};
use semrecon_data::{open_dataset, DatasetSpec};
use semrecon_recon::pose_graph::{pose_distance, rotation_exp};
use semrecon_recon::{LoopConfig, LoopDetector};

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (spec, pairs) = args.split_first().ok_or("usage: loop_accuracy SPEC NEW:OLD ...")?;
    let spec: DatasetSpec = spec.parse().map_err(|e| format!("{spec}: {e}"))?;
    let source = open_dataset(&spec).map_err(|e| e.to_string())?;
    let drift =
        DAffine3 { matrix3: rotation_exp(DVec3::new(0.0, 0.005, 0.0)), translation: DVec3::new(0.015, -0.01, 0.008) };
    for pair in pairs {
        let (new, old) = pair.split_once(':').ok_or_else(|| format!("{pair}: expected NEW:OLD"))?;
        let parse = |s: &str| s.parse::<usize>().map_err(|e| format!("{pair}: {e}"));
        let (new, old) = (parse(new)?, parse(old)?);
        let mut detector = LoopDetector::new(LoopConfig::default());
        let mut poses = Vec::new();
        for i in [old, new] {
            let frame = source.frame(i).map_err(|e| e.to_string())?;
            poses.push(frame.world_from_camera.ok_or("no ground truth")?.as_daffine3());
            detector.add(&frame);
        }
        let truth = poses[0].inverse() * poses[1];
        for (name, start) in [("truth", truth), ("drifted", truth * drift)] {
            match detector.verify(0, 1, start) {
                Some(v) => {
                    let (t, r) = pose_distance(&v.old_from_new, &truth);
                    let e = v.old_from_new.translation - truth.translation;
                    println!(
                        "{new}:{old} from {name}: {} error {:.1} mm ({:+.1} {:+.1} {:+.1} in the old camera), {:.3} deg; overlap {:.2}, residual {:.1} mm",
                        if v.accepted() { "accepted" } else { "rejected" },
                        t * 1e3,
                        e.x * 1e3,
                        e.y * 1e3,
                        e.z * 1e3,
                        r.to_degrees(),
                        v.overlap,
                        v.residual_rms * 1e3
                    );
                    if std::env::var_os("LOOP_ACCURACY_HESSIAN").is_some() {
                        println!("  hessian {:?}", v.hessian);
                    }
                }
                None => println!("{new}:{old} from {name}: no verdict"),
            }
        }
    }
    Ok(())
}

fn main() {
    if let Err(e) = run() {
        eprintln!("loop_accuracy: {e}");
        std::process::exit(1);
    }
}
