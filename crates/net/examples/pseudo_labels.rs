//! Pseudo-labels for real, unlabelled scans: the self-training half of "real rooms"
//! (docs/model.md, leg 8).
//!
//! ```text
//! cargo run --release -p semrecon-net --example pseudo_labels -- MODEL OUT_DIR SCAN.ply...
//! ```
//!
//! Every scan (a PLY point cloud or mesh, z up, coloured) is labelled by `MODEL` with
//! test-time augmentation (the four quarter turns about z, each also mirrored: eight passes
//! whose class probabilities are averaged per point, so a label does not hang on one voxel
//! grid's phase or orientation). A point keeps its label only when it is confident: its mean
//! probability is at least `MIN_CONFIDENCE`, and it lies in the more confident half of the
//! points given its class (a per-class quantile, so that walls and floors, which the network
//! is sure of everywhere, do not crowd out the furniture). Other points get 255 (unlabelled,
//! ignored by the loss). The result, `OUT_DIR/NAME.ply`, is a labelled point cloud that
//! `semrecon train --data ply:OUT_DIR` reads. Faces of meshes are dropped: vertices are
//! enough at the 5 cm voxels of s20 when the scan is dense (ScanNet's `vh_clean_2`, Replica).

use std::path::Path;

use semrecon_data::class::UNLABELED;
use semrecon_data::{read_ply, write_ply, LabeledMesh, PlyEncoding};
use semrecon_net::structure::softmax_rows;

/// Smallest mean probability a pseudo-label needs.
const MIN_CONFIDENCE: f32 = 0.7;
/// Share of each class's points (the most confident ones) that keep their label.
const CLASS_QUANTILE_KEPT: f32 = 0.5;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: pseudo_labels MODEL OUT_DIR SCAN.ply...".into());
    }
    let mut net = semrecon_net::shipped::load(Path::new(&args[0]), None)?;
    let out = Path::new(&args[1]);
    std::fs::create_dir_all(out)?;
    for scan in &args[2..] {
        let mesh = read_ply(scan)?;
        let n = mesh.positions.len();
        let k = 13;
        let mut probs = vec![0.0f32; n * k];
        for pass in 0..8 {
            let (angle, mirror) = (pass as f32 * std::f32::consts::FRAC_PI_2, pass >= 4);
            let (s, c) = angle.sin_cos();
            let points: Vec<[f32; 3]> = mesh
                .positions
                .iter()
                .map(|p| {
                    let x = if mirror { -p.x } else { p.x };
                    [c * x - s * p.y, s * x + c * p.y, p.z]
                })
                .collect();
            let scores = net.segment_points_scores(&points, &mesh.colors)?;
            let mut voxel_probs = scores.logits;
            softmax_rows(&mut voxel_probs, k);
            for (i, &v) in scores.point_to_voxel.iter().enumerate() {
                let row = &voxel_probs[v as usize * k..(v as usize + 1) * k];
                for (acc, p) in probs[i * k..(i + 1) * k].iter_mut().zip(row) {
                    *acc += p / 8.0;
                }
            }
        }
        let (labels, confidence): (Vec<u8>, Vec<f32>) = probs
            .chunks_exact(k)
            .map(|row| {
                let (best, p) = row
                    .iter()
                    .enumerate()
                    .fold((0, f32::MIN), |(bi, bp), (i, &p)| if p > bp { (i, p) } else { (bi, bp) });
                (best as u8, p)
            })
            .unzip();
        // Per-class confidence threshold: the (1 - kept) quantile of the class's points.
        let mut threshold = [f32::MAX; 13];
        for (class, t) in threshold.iter_mut().enumerate() {
            let mut c: Vec<f32> =
                labels.iter().zip(&confidence).filter(|(&l, _)| l as usize == class).map(|(_, &p)| p).collect();
            if c.is_empty() {
                continue;
            }
            c.sort_by(f32::total_cmp);
            let q = c[((c.len() as f32 * (1.0 - CLASS_QUANTILE_KEPT)) as usize).min(c.len() - 1)];
            *t = q.max(MIN_CONFIDENCE);
        }
        let kept: Vec<u8> = (0..n)
            .map(|i| if confidence[i] >= threshold[labels[i] as usize] { labels[i] } else { UNLABELED })
            .collect();
        let mut histogram = [0usize; 13];
        for &l in kept.iter().filter(|&&l| l != UNLABELED) {
            histogram[l as usize] += 1;
        }
        let labelled = LabeledMesh {
            positions: mesh.positions.clone(),
            colors: mesh.colors.clone(),
            normals: Vec::new(),
            vertex_labels: kept,
            triangles: Vec::new(),
            triangle_labels: Vec::new(),
        };
        let name = Path::new(scan).file_name().ok_or("scan path without a file name")?;
        let path = out.join(name);
        write_ply(&path, &labelled, PlyEncoding::BinaryLittleEndian)?;
        let total: usize = histogram.iter().sum();
        println!("{}: {} of {} points labelled; per class {:?}", path.display(), total, n, histogram);
    }
    Ok(())
}
