//! The fused inference against the plain reference forward, and its contract: any row order,
//! empty input, bad input, determinism across thread counts.

#![allow(clippy::unwrap_used)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_net::{reference, NetConfig, Segmenter, Weights};
use semrecon_sparse::Coord;

/// The surface of a box-shaped room (walls, floor, ceiling) with a table-like slab inside,
/// shifted so that negative coordinates occur, plus a few isolated voxels; random features.
fn room(seed: u64, channels: usize) -> (Vec<Coord>, Vec<f32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (sx, sy, sz) = (rng.random_range(8..13), rng.random_range(6..10), rng.random_range(5..8));
    let off = [rng.random_range(-6..2), rng.random_range(-6..2), rng.random_range(-3..2)];
    let mut set = std::collections::BTreeSet::new();
    for x in 0..sx {
        for y in 0..sy {
            for z in 0..sz {
                let surface = x == 0 || y == 0 || z == 0 || x == sx - 1 || y == sy - 1 || z == sz - 1;
                let slab = z == 2 && (3..6).contains(&x) && (2..5).contains(&y);
                if (surface && rng.random_bool(0.9)) || slab {
                    set.insert([x + off[0], y + off[1], z + off[2], 0]);
                }
            }
        }
    }
    for _ in 0..5 {
        set.insert([rng.random_range(-20..20), rng.random_range(-20..20), rng.random_range(-20..20), 0]);
    }
    // A second scene in batch 1 that overlaps the first in space: batches must not mix.
    let first: Vec<Coord> = set.iter().take(40).copied().collect();
    set.extend(first.into_iter().map(|c| [c[0], c[1], c[2], 1]));
    let mut coords: Vec<Coord> = set.into_iter().collect();
    // Shuffle: the fused path must not depend on the caller's order.
    for i in (1..coords.len()).rev() {
        coords.swap(i, rng.random_range(0..=i));
    }
    let feats = (0..coords.len() * channels).map(|_| rng.random_range(-1.0..1.0)).collect();
    (coords, feats)
}

fn weights(config: &NetConfig, seed: u64) -> Weights {
    let mut w = Weights::random(config, seed);
    w.perturb_normalisation(seed + 1);
    w
}

fn max_abs(v: &[f32]) -> f32 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

#[test]
fn fused_forward_matches_the_reference() {
    for (levels, width, seed) in [(3, 4, 1u64), (4, 6, 2), (4, 8, 3), (1, 4, 4), (2, 5, 5)] {
        let config = NetConfig::new("t", levels, width, 0.05);
        let w = weights(&config, seed);
        let (coords, feats) = room(seed, 3);
        let want = reference::forward(&config, &w, &coords, &feats).unwrap();
        let mut net = Segmenter::new(w, config.clone()).unwrap();
        let got = net.segment(&coords, &feats).unwrap();
        assert_eq!(got.len(), coords.len() * 13);
        let scale = max_abs(&want).max(1.0);
        let err = got.iter().zip(&want).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-4 * scale, "L={levels} M={width}: max error {err} (scale {scale}), {} voxels", coords.len());
        eprintln!("L={levels} M={width}: err {err:e} scale {scale} stats {:?}", net.level_stats());
        net.set_kernel(semrecon_net::ConvKernel::Rulebook);
        let rb = net.segment(&coords, &feats).unwrap();
        let err = rb.iter().zip(&want).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-4 * scale, "rulebook: max error {err}");
        assert_eq!(net.level_stats().len(), levels);
        assert_eq!(net.level_stats()[0].voxels, coords.len());
    }
}

#[test]
fn deterministic_for_one_and_two_threads_and_reusable() {
    let config = NetConfig::new("t", 4, 8, 0.05);
    let (coords, feats) = room(7, 3);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut net = Segmenter::new(weights(&config, 9), config.clone()).unwrap();
            let a = net.segment(&coords, &feats).unwrap();
            // A second, smaller input and the first again: the workspace is reused.
            net.segment(&coords[..coords.len() / 2], &feats[..coords.len() / 2 * 3]).unwrap();
            let b = net.segment(&coords, &feats).unwrap();
            assert_eq!(a, b);
            // Released, the workspace is made again with the same outputs.
            assert!(net.workspace_bytes() > 0);
            net.release_workspace();
            assert_eq!(net.workspace_bytes(), 0);
            assert_eq!(net.segment(&coords, &feats).unwrap(), a);
            a
        })
    };
    let one = run(1);
    let two = run(2);
    assert!(one.iter().zip(&two).all(|(a, b)| a.to_bits() == b.to_bits()));
}

#[test]
fn empty_and_bad_inputs() {
    let config = NetConfig::new("t", 3, 4, 0.05);
    let mut net = Segmenter::new(Weights::random(&config, 1), config.clone()).unwrap();
    assert!(net.segment(&[], &[]).unwrap().is_empty());
    assert!(net.segment_points(&[], &[]).unwrap().is_empty());
    let e = net.segment(&[[0, 0, 0, 0]], &[1.0]).unwrap_err().to_string();
    assert!(e.contains("feature"), "{e}");
    assert!(net.segment(&[[0, 0, 0, 0], [0, 0, 0, 0]], &[0.0; 6]).is_err());
    assert!(net.segment_points(&[[0.0; 3]], &[]).is_err());
    assert!(net.segment_points(&[[f32::NAN, 0.0, 0.0]], &[[0, 0, 0]]).is_err());
    // Weights of another configuration.
    let other = NetConfig::new("o", 3, 8, 0.05);
    let e = Segmenter::new(Weights::random(&other, 1), config).unwrap_err().to_string();
    assert!(e.contains("input.conv.weight") && e.contains("shape"), "{e}");
}

#[test]
fn points_are_labelled_through_their_voxels() {
    let config = NetConfig::new("t", 3, 4, 0.1);
    let w = weights(&config, 3);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let points: Vec<[f32; 3]> = (0..400)
        .map(|_| [rng.random_range(0.0..1.0), rng.random_range(0.0..1.0), rng.random_range(0.0..0.2)])
        .collect();
    let colors: Vec<[u8; 3]> = (0..400).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
    let mut net = Segmenter::new(w.clone(), config.clone()).unwrap();
    let labels = net.segment_points(&points, &colors).unwrap();
    assert_eq!(labels.len(), points.len());
    // Same answer through voxelize + segment + argmax by hand.
    let feats = semrecon_net::color_features(&colors);
    let v = semrecon_sparse::voxelize(&points, &feats, 3, 0.1, 0).unwrap();
    let logits = reference::forward(&config, &w, v.tensor.coords(), v.tensor.features()).unwrap();
    let mut agree = 0;
    for (p, &l) in labels.iter().enumerate() {
        let row = &logits[v.point_to_voxel[p] as usize * 13..][..13];
        let best = (0..13).fold(0, |b, c| if row[c] > row[b] { c } else { b });
        agree += usize::from(best == usize::from(l));
    }
    // Near-ties may flip by rounding; all but a handful must agree.
    assert!(agree + 3 >= labels.len(), "{agree} of {}", labels.len());
}

#[test]
fn prebuilt_geometry_gives_the_same_scores() {
    let config = NetConfig::new("t", 4, 4, 0.05);
    let (coords, feats) = room(11, 3);
    let geo = semrecon_net::NetGeometry::build(coords.clone(), &config, &Default::default()).unwrap();
    assert_eq!(geo.levels(), 4);
    assert_eq!(geo.coords(0), coords.as_slice());
    assert!(geo.down(3).is_none() && geo.up(2).is_some());
    for (t, j) in [(0, 1), (0, 2), (1, 2)] {
        let (rows, w) = geo.interpolation(t, j).unwrap();
        assert_eq!(rows.len(), geo.coords(t).len() * 8);
        for r in w.chunks(8) {
            assert!((r.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        assert!(rows.iter().all(|&r| (r as usize) < geo.coords(j).len()));
    }
    assert!(geo.interpolation(0, 3).is_none());
    let mut net = Segmenter::new(weights(&config, 2), config.clone()).unwrap();
    let a = net.segment(&coords, &feats).unwrap();
    let b = net.segment_geometry(&geo, &feats).unwrap();
    let err = a.iter().zip(&b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(err <= 1e-4 * max_abs(&a).max(1.0), "{err}");
    let other =
        semrecon_net::NetGeometry::build(coords, &NetConfig::new("t", 3, 4, 0.05), &Default::default()).unwrap();
    assert!(net.segment_geometry(&other, &feats).is_err());
}
