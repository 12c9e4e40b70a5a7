//! Pose-graph benchmark: the optimisation a keyframe triggers, on graphs the size of a
//! 7-Scenes clip (50 keyframes) up to a 2-minute and a 5-minute scan (360 and 900
//! keyframes): a drifting ring of keyframes with odometry edges and a loop edge every
//! `--loop-every` keyframes back to where the ring passed before. Prints the median and
//! largest wall time of `optimise` over `--repeat` runs, the iterations, and the non-zeros of
//! the normal matrix (blocks in use over a dense one).
//!
//! ```text
//! cargo run --release -p semrecon-recon --example pose_graph_bench -- [--repeat N] [--loop-every K]
//! ```

use std::time::Instant;

use glam::{DAffine3, DVec3};
use semrecon_recon::pose_graph::{isotropic_information, rotation_exp};
use semrecon_recon::{EdgeKind, PoseEdge, PoseGraph, PoseGraphConfig};

fn flag(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Keyframe `i` of `n` on two laps of a ring of radius 2 m (the second lap revisits the
/// first).
fn truth(i: usize, n: usize) -> DAffine3 {
    let a = 2.0 * i as f64 / n as f64 * std::f64::consts::TAU;
    DAffine3 {
        matrix3: rotation_exp(DVec3::new(0.0, 0.0, a)),
        translation: DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.0),
    }
}

fn main() {
    let repeat = flag("--repeat", 20).max(1);
    let loop_every = flag("--loop-every", 5).max(1);
    println!(
        "{:>9} {:>6} {:>12} {:>10} {:>10} {:>12}",
        "keyframes", "loops", "median ms", "max ms", "iterations", "H filled"
    );
    for n in [50, 360, 900] {
        let drift = DAffine3 {
            matrix3: rotation_exp(DVec3::new(0.0, 0.0, 0.0008)),
            translation: DVec3::new(0.002, 0.001, 0.0),
        };
        let mut g = PoseGraph::new();
        let mut pose = truth(0, n);
        g.add_pose(pose).expect("finite");
        for i in 1..n {
            let z = truth(i - 1, n).inverse() * truth(i, n) * drift;
            pose *= z;
            g.add_pose(pose).expect("finite");
            g.add_edge(PoseEdge {
                from: i - 1,
                to: i,
                from_from_to: z,
                information: isotropic_information(0.005, 0.004),
                kind: EdgeKind::Odometry,
            })
            .expect("edge");
        }
        // Second lap: keyframe i sees keyframe i - n/2 again.
        let mut loops = 0;
        for i in (n / 2..n).step_by(loop_every) {
            let j = i - n / 2;
            g.add_edge(PoseEdge {
                from: j,
                to: i,
                from_from_to: truth(j, n).inverse() * truth(i, n),
                information: isotropic_information(0.004, 0.003),
                kind: EdgeKind::Loop,
            })
            .expect("edge");
            loops += 1;
        }
        let config =
            PoseGraphConfig { max_translation_change: 100.0, max_rotation_change: 10.0, ..PoseGraphConfig::default() };
        let mut times = Vec::new();
        let mut iterations = 0;
        for _ in 0..repeat {
            let mut h = g.clone();
            let t = Instant::now();
            let r = h.optimise(&config).expect("optimised");
            times.push(t.elapsed().as_secs_f64() * 1e3);
            iterations = r.iterations;
        }
        times.sort_by(f64::total_cmp);
        // Non-zero 6x6 blocks: the diagonal, and one per edge pair of distinct free poses.
        let blocks = (n - 1) + g.edges().iter().filter(|e| e.from != 0 && e.to != 0).count();
        let fill = (blocks * 2 - (n - 1)) as f64 / ((n - 1) * (n - 1)) as f64;
        println!(
            "{n:>9} {loops:>6} {:>12.2} {:>10.2} {iterations:>10} {:>11.1}%",
            times[times.len() / 2],
            times[times.len() - 1],
            fill * 100.0
        );
    }
}
