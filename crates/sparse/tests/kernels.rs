//! Every fast kernel against the naive reference, on random and surface-like voxel sets, for
//! every layer kind and pass, plus finite differences, thread-count determinism and bad input.
#![allow(clippy::unwrap_used)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_sparse::{
    reference, rulebook, voxelize, ChunkConfig, ChunkedConv, Coord, KernelMap, MapKind, SparseError, SparseTensor,
};

/// A random sparse set: `n` distinct voxels in a cube of side `side`, two batches.
fn random_set(seed: u64, n: usize, side: i32) -> Vec<Coord> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let coords: Vec<Coord> = (0..n)
        .map(|_| {
            [
                rng.random_range(-side..side),
                rng.random_range(-side..side),
                rng.random_range(-side..side),
                rng.random_range(0..2),
            ]
        })
        .collect();
    let feats = vec![0.0; coords.len()];
    SparseTensor::new(coords, feats, 1).unwrap().coords().to_vec()
}

/// Surface-like sets: a voxelised plane patch, box shell and sphere shell (0.05 m voxels).
fn surface_set(which: usize) -> Vec<Coord> {
    let mut pts = Vec::new();
    let step = 0.02f32;
    match which {
        0 => {
            // A tilted plane.
            for i in 0..60 {
                for j in 0..60 {
                    let (x, y) = (i as f32 * step, j as f32 * step);
                    pts.push([x, y, 0.3 * x + 0.1 * y - 0.4]);
                }
            }
        }
        1 => {
            // The shell of a 0.6 x 0.5 x 0.4 box.
            let (a, b, c) = (0.6f32, 0.5f32, 0.4f32);
            let mut face = |n: usize, m: usize, f: &dyn Fn(f32, f32) -> [f32; 3]| {
                for i in 0..=n {
                    for j in 0..=m {
                        pts.push(f(i as f32 * step, j as f32 * step));
                    }
                }
            };
            let (na, nb, nc) = ((a / step) as usize, (b / step) as usize, (c / step) as usize);
            face(na, nb, &|u, v| [u, v, 0.0]);
            face(na, nb, &|u, v| [u, v, c]);
            face(na, nc, &|u, v| [u, 0.0, v]);
            face(na, nc, &|u, v| [u, b, v]);
            face(nb, nc, &|u, v| [0.0, u, v]);
            face(nb, nc, &|u, v| [a, u, v]);
        }
        _ => {
            // A sphere of radius 0.35 around a negative centre.
            for i in 0..80 {
                let th = std::f32::consts::PI * (i as f32 + 0.5) / 80.0;
                for j in 0..160 {
                    let ph = 2.0 * std::f32::consts::PI * j as f32 / 160.0;
                    pts.push([-0.2 + 0.35 * th.sin() * ph.cos(), -0.1 + 0.35 * th.sin() * ph.sin(), 0.35 * th.cos()]);
                }
            }
        }
    }
    let feats = vec![0.0; pts.len()];
    voxelize(&pts, &feats, 1, 0.05, 0).unwrap().tensor.coords().to_vec()
}

fn values(seed: u64, n: usize) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

/// A layer: kind, input and output voxels, and its kernel map.
struct Layer {
    kind: MapKind,
    input: Vec<Coord>,
    output: Vec<Coord>,
    map: KernelMap,
}

fn layers(set: &[Coord], kernel_size: usize) -> Vec<Layer> {
    let (coarse, down) = KernelMap::downsample(set).unwrap();
    let up = KernelMap::upsample(&coarse, set).unwrap();
    vec![
        Layer {
            kind: MapKind::Submanifold { kernel_size },
            input: set.to_vec(),
            output: set.to_vec(),
            map: KernelMap::submanifold(set, kernel_size).unwrap(),
        },
        Layer { kind: MapKind::Down, input: set.to_vec(), output: coarse.clone(), map: down },
        Layer { kind: MapKind::Up, input: coarse, output: set.to_vec(), map: up },
    ]
}

#[track_caller]
fn assert_close(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() <= 2e-5 * scale * 8.0, "{what}: element {i}: {g} vs {w} (scale {scale})");
    }
}

const SMALL_CHUNKS: ChunkConfig = ChunkConfig { chunk_side: 8, levels: 3, max_region_rows: 24 };

/// All passes of both fast kernels against the reference on one layer.
fn check_layer(layer: &Layer, c_in: usize, c_out: usize, seed: u64, configs: &[ChunkConfig]) {
    let kv = layer.map.kernel_volume();
    let x = values(seed, layer.input.len() * c_in);
    let dy = values(seed + 1, layer.output.len() * c_out);
    let w = values(seed + 2, kv * c_in * c_out);
    let tag = format!("{:?} n={} c_in={c_in} c_out={c_out}", layer.kind, layer.input.len());
    let y_ref = reference::forward(layer.kind, &layer.input, &layer.output, &x, c_in, &w, c_out).unwrap();
    let dx_ref = reference::backward_input(layer.kind, &layer.input, &layer.output, &dy, c_out, &w, c_in).unwrap();
    let dw_ref = reference::backward_weight(layer.kind, &layer.input, &layer.output, &x, c_in, &dy, c_out).unwrap();
    assert_close(
        &rulebook::forward(&layer.map, &x, c_in, &w, c_out).unwrap(),
        &y_ref,
        &format!("rulebook forward {tag}"),
    );
    assert_close(
        &rulebook::backward_input(&layer.map, &dy, c_out, &w, c_in).unwrap(),
        &dx_ref,
        &format!("rulebook dx {tag}"),
    );
    assert_close(
        &rulebook::backward_weight(&layer.map, &x, c_in, &dy, c_out).unwrap(),
        &dw_ref,
        &format!("rulebook dw {tag}"),
    );
    for cfg in configs {
        let conv = ChunkedConv::new(layer.map.clone(), &layer.input, &layer.output, cfg).unwrap();
        assert_close(&conv.forward(&x, c_in, &w, c_out).unwrap(), &y_ref, &format!("chunked forward {tag} {cfg:?}"));
        assert_close(
            &conv.backward_input(&dy, c_out, &w, c_in).unwrap(),
            &dx_ref,
            &format!("chunked dx {tag} {cfg:?}"),
        );
        assert_close(
            &conv.backward_weight(&x, c_in, &dy, c_out).unwrap(),
            &dw_ref,
            &format!("chunked dw {tag} {cfg:?}"),
        );
    }
}

#[test]
fn random_sets_all_layers_all_channel_counts() {
    let set = random_set(1, 300, 6);
    for (i, &(c_in, c_out)) in
        [(1, 1), (3, 16), (16, 3), (32, 32), (64, 64), (96, 96), (7, 13), (64, 96)].iter().enumerate()
    {
        for layer in layers(&set, 3) {
            check_layer(&layer, c_in, c_out, 10 + i as u64, &[SMALL_CHUNKS, ChunkConfig::default()]);
        }
    }
}

#[test]
fn surface_sets_all_layers() {
    for which in 0..3 {
        let set = surface_set(which);
        assert!(set.len() > 100, "surface {which} has {} voxels", set.len());
        for (i, &(c_in, c_out)) in [(16, 16), (32, 64), (3, 32)].iter().enumerate() {
            for layer in layers(&set, 3) {
                check_layer(&layer, c_in, c_out, 100 + i as u64, &[SMALL_CHUNKS, ChunkConfig::default()]);
            }
        }
    }
}

#[test]
fn kernel_sizes_one_and_five() {
    let set = random_set(2, 150, 4);
    for k in [1, 5] {
        let layer = &layers(&set, k)[0];
        check_layer(layer, 5, 17, 7, &[SMALL_CHUNKS]);
    }
}

#[test]
fn chunk_configurations_agree() {
    let set = surface_set(1);
    let layer = &layers(&set, 3)[0];
    let configs: Vec<ChunkConfig> = [(1, 1, 1), (2, 2, 5), (4, 3, 16), (16, 1, 10_000), (32, 4, 64), (64, 3, 100)]
        .iter()
        .map(|&(chunk_side, levels, max_region_rows)| ChunkConfig { chunk_side, levels, max_region_rows })
        .collect();
    check_layer(layer, 8, 24, 3, &configs);
}

#[test]
fn empty_input_works() {
    for layer in layers(&[], 3) {
        check_layer(&layer, 4, 5, 1, &[ChunkConfig::default()]);
        let conv = ChunkedConv::new(layer.map.clone(), &[], &[], &ChunkConfig::default()).unwrap();
        assert!(conv.forward(&[], 4, &vec![0.0; layer.map.kernel_volume() * 20], 5).unwrap().is_empty());
    }
}

#[test]
fn single_voxel_and_zero_channels() {
    let set = vec![[3, -2, 1, 1]];
    for layer in layers(&set, 3) {
        check_layer(&layer, 2, 3, 5, &[ChunkConfig::default()]);
        check_layer(&layer, 0, 3, 5, &[ChunkConfig::default()]);
    }
}

/// Loss `L = sum(y . g)`: its gradients are `backward_input(g)` and `backward_weight(x, g)`.
#[test]
fn finite_differences_match_both_gradients() {
    let set = random_set(3, 40, 2);
    for layer in layers(&set, 3) {
        let (c_in, c_out) = (3, 2);
        let kv = layer.map.kernel_volume();
        let conv = ChunkedConv::new(layer.map.clone(), &layer.input, &layer.output, &SMALL_CHUNKS).unwrap();
        let x = values(1, layer.input.len() * c_in);
        let w = values(2, kv * c_in * c_out);
        let g = values(3, layer.output.len() * c_out);
        let loss = |x: &[f32], w: &[f32]| -> f64 {
            let y = conv.forward(x, c_in, w, c_out).unwrap();
            y.iter().zip(&g).map(|(&a, &b)| f64::from(a) * f64::from(b)).sum()
        };
        let dx = conv.backward_input(&g, c_out, &w, c_in).unwrap();
        let dw = conv.backward_weight(&x, c_in, &g, c_out).unwrap();
        let eps = 1e-2f32;
        for i in (0..x.len()).step_by(7) {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[i] += eps;
            xm[i] -= eps;
            let fd = (loss(&xp, &w) - loss(&xm, &w)) / (2.0 * f64::from(eps));
            assert!((fd - f64::from(dx[i])).abs() < 1e-3, "{:?} dx[{i}]: fd {fd} vs {}", layer.kind, dx[i]);
        }
        for i in (0..w.len()).step_by(5) {
            let (mut wp, mut wm) = (w.clone(), w.clone());
            wp[i] += eps;
            wm[i] -= eps;
            let fd = (loss(&x, &wp) - loss(&x, &wm)) / (2.0 * f64::from(eps));
            assert!((fd - f64::from(dw[i])).abs() < 1e-3, "{:?} dw[{i}]: fd {fd} vs {}", layer.kind, dw[i]);
        }
    }
}

#[test]
fn same_bits_for_one_two_and_four_threads() {
    let set = surface_set(2);
    let (c_in, c_out) = (32, 48);
    let run = |layer: &Layer| {
        let conv = ChunkedConv::new(layer.map.clone(), &layer.input, &layer.output, &SMALL_CHUNKS).unwrap();
        let kv = layer.map.kernel_volume();
        let x = values(1, layer.input.len() * c_in);
        let w = values(2, kv * c_in * c_out);
        let dy = values(3, layer.output.len() * c_out);
        vec![
            conv.forward(&x, c_in, &w, c_out).unwrap(),
            conv.backward_input(&dy, c_out, &w, c_in).unwrap(),
            conv.backward_weight(&x, c_in, &dy, c_out).unwrap(),
            rulebook::forward(&layer.map, &x, c_in, &w, c_out).unwrap(),
            rulebook::backward_input(&layer.map, &dy, c_out, &w, c_in).unwrap(),
            rulebook::backward_weight(&layer.map, &x, c_in, &dy, c_out).unwrap(),
        ]
    };
    for layer in layers(&set, 3) {
        let results: Vec<Vec<Vec<u32>>> = [1, 2, 4]
            .iter()
            .map(|&t| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
                pool.install(|| run(&layer)).into_iter().map(|v| v.iter().map(|f| f.to_bits()).collect()).collect()
            })
            .collect();
        assert_eq!(results[0], results[1], "{:?}: 1 vs 2 threads", layer.kind);
        assert_eq!(results[0], results[2], "{:?}: 1 vs 4 threads", layer.kind);
    }
}

#[test]
fn bad_shapes_are_errors_not_panics() {
    let set = random_set(4, 50, 3);
    let map = KernelMap::submanifold(&set, 3).unwrap();
    let conv = ChunkedConv::new(map.clone(), &set, &set, &ChunkConfig::default()).unwrap();
    let x = vec![0.0; set.len() * 4];
    let w = vec![0.0; 27 * 4 * 5];
    assert!(matches!(conv.forward(&x[1..], 4, &w, 5), Err(SparseError::FeatureShape { .. })));
    assert!(matches!(conv.forward(&x, 4, &w[1..], 5), Err(SparseError::WeightShape { .. })));
    assert!(matches!(rulebook::forward(&map, &x, 4, &w, 4), Err(SparseError::WeightShape { .. })));
    assert!(matches!(conv.backward_input(&x[2..], 4, &w, 5), Err(SparseError::FeatureShape { .. })));
    assert!(matches!(conv.backward_input(&x, 4, &w, 6), Err(SparseError::WeightShape { .. })));
    assert!(matches!(conv.backward_weight(&x, 4, &x[..8], 4), Err(SparseError::FeatureShape { .. })));
    assert!(matches!(rulebook::backward_weight(&map, &x[4..], 4, &x, 4), Err(SparseError::FeatureShape { .. })));
    assert!(matches!(
        ChunkedConv::new(map.clone(), &set[1..], &set, &ChunkConfig::default()),
        Err(SparseError::CoordCount { .. })
    ));
    let bad = ChunkConfig { chunk_side: 3, ..ChunkConfig::default() };
    assert!(ChunkedConv::new(map, &set, &set, &bad).is_err());
    assert!(matches!(KernelMap::submanifold(&[[1 << 20, 0, 0, 0]], 3), Err(SparseError::CoordOutOfRange { .. })));
    assert!(matches!(KernelMap::downsample(&[[0, 0, 0, 2]]), Err(SparseError::CoordOutOfRange { .. })));
    assert!(matches!(
        reference::forward(MapKind::Submanifold { kernel_size: 3 }, &set, &set, &x, 4, &w, 3),
        Err(SparseError::WeightShape { .. })
    ));
}

#[test]
fn transposed_strided_layer_reuses_the_plans() {
    let set = surface_set(1);
    let ls = layers(&set, 3);
    let (down, up) = (&ls[1], &ls[2]);
    let down_conv = ChunkedConv::new(down.map.clone(), &down.input, &down.output, &SMALL_CHUNKS).unwrap();
    let up_conv = down_conv.transposed().unwrap();
    assert_eq!(up_conv.map(), &up.map);
    let (c_in, c_out) = (24, 16);
    let x = values(1, up.input.len() * c_in);
    let w = values(2, 8 * c_in * c_out);
    let dy = values(3, up.output.len() * c_out);
    let y_ref = reference::forward(MapKind::Up, &up.input, &up.output, &x, c_in, &w, c_out).unwrap();
    assert_close(&up_conv.forward(&x, c_in, &w, c_out).unwrap(), &y_ref, "up via transposed");
    let dx_ref = reference::backward_input(MapKind::Up, &up.input, &up.output, &dy, c_out, &w, c_in).unwrap();
    assert_close(&up_conv.backward_input(&dy, c_out, &w, c_in).unwrap(), &dx_ref, "up dx via transposed");
    let dw_ref = reference::backward_weight(MapKind::Up, &up.input, &up.output, &x, c_in, &dy, c_out).unwrap();
    assert_close(&up_conv.backward_weight(&x, c_in, &dy, c_out).unwrap(), &dw_ref, "up dw via transposed");
    let sub = ChunkedConv::new(ls[0].map.clone(), &set, &set, &SMALL_CHUNKS).unwrap();
    assert!(sub.transposed().is_none());
}

#[test]
fn plan_arrays_cover_every_output_once() {
    let set = surface_set(0);
    let map = KernelMap::submanifold(&set, 3).unwrap();
    let conv = ChunkedConv::new(map.clone(), &set, &set, &SMALL_CHUNKS).unwrap();
    let plan = conv.forward_plan();
    let a = plan.arrays();
    assert_eq!(a.dst_start.len(), plan.num_chunks() + 1);
    let mut seen = vec![false; set.len()];
    for &d in a.dst_rows {
        assert!(!seen[d as usize]);
        seen[d as usize] = true;
    }
    assert!(seen.iter().all(|&s| s));
    assert_eq!(a.pair_src.len(), map.num_pairs());
    assert_eq!(*a.pair_start.last().unwrap() as usize, map.num_pairs());
    // The region of every chunk starts with its own rows (identity centre).
    let centre = plan.centre().unwrap();
    for c in 0..plan.num_chunks() {
        let dst = plan.chunk_dst(c);
        assert_eq!(&plan.chunk_src(c)[..dst.len()], dst);
        let (ps, pd) = plan.chunk_pairs(c, centre);
        assert_eq!(ps, pd);
        assert_eq!(ps.len(), dst.len());
    }
}

/// Submanifold pairs by brute force: per offset, every output looked up in a std `HashMap`.
fn brute_force_pairs(set: &[Coord], kernel_size: usize) -> Vec<Vec<(u32, u32)>> {
    let index: std::collections::HashMap<Coord, u32> = set.iter().enumerate().map(|(r, &c)| (c, r as u32)).collect();
    let (ks, r) = (kernel_size as i32, kernel_size as i32 / 2);
    (0..ks * ks * ks)
        .map(|k| {
            let o = [k % ks - r, (k / ks) % ks - r, k / (ks * ks) - r];
            set.iter()
                .enumerate()
                .filter_map(|(u, c)| index.get(&[c[0] + o[0], c[1] + o[1], c[2] + o[2], c[3]]).map(|&i| (i, u as u32)))
                .collect()
        })
        .collect()
}

/// The table-built submanifold maps, the one-table layer constructor, the run-based
/// downsampling of Z-ordered sets and the coordinate-free pointwise layer against plain
/// constructions, on blocky (surface) and scattered sets, Z-ordered and shuffled.
#[test]
fn fast_geometry_paths_match_the_plain_ones() {
    let mut sets = vec![random_set(5, 300, 12), surface_set(0), surface_set(2)];
    let mut shuffled = surface_set(1);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, rng.random_range(0..=i));
    }
    sets.push(shuffled);
    for (s, set) in sets.iter().enumerate() {
        for ks in [1, 3, 5] {
            let map = KernelMap::submanifold(set, ks).unwrap();
            for (k, want) in brute_force_pairs(set, ks).iter().enumerate() {
                let (ins, outs) = map.pairs(k);
                let got: Vec<(u32, u32)> = ins.iter().zip(outs).map(|(&i, &o)| (i, o)).collect();
                assert_eq!(&got, want, "set {s}, kernel {ks}, offset {k}");
            }
        }
        for config in [ChunkConfig::default(), SMALL_CHUNKS] {
            let layer = ChunkedConv::submanifold(set, 3, &config).unwrap();
            let plain = ChunkedConv::new(KernelMap::submanifold(set, 3).unwrap(), set, set, &config).unwrap();
            assert_eq!(layer.map(), plain.map(), "set {s}");
            assert_eq!(layer.forward_plan(), plain.forward_plan(), "set {s}");
        }
        // Downsampling: first-appearance parents, pairs per offset sorted by coarse row.
        let (coarse, down) = KernelMap::downsample(set).unwrap();
        let mut want_coarse: Vec<Coord> = Vec::new();
        let mut parent_row = Vec::new();
        for c in set {
            let p = [c[0] >> 1, c[1] >> 1, c[2] >> 1, c[3]];
            let row = want_coarse.iter().position(|&q| q == p).unwrap_or_else(|| {
                want_coarse.push(p);
                want_coarse.len() - 1
            });
            parent_row.push(row as u32);
        }
        assert_eq!(coarse, want_coarse, "set {s}");
        for k in 0..8 {
            let mut want: Vec<(u32, u32)> = (0..set.len())
                .filter(|&u| {
                    let c = set[u];
                    ((c[0] & 1) + 2 * (c[1] & 1) + 4 * (c[2] & 1)) as usize == k
                })
                .map(|u| (u as u32, parent_row[u]))
                .collect();
            want.sort_by_key(|&(u, p)| (p, u));
            let (ins, outs) = down.pairs(k);
            let got: Vec<(u32, u32)> = ins.iter().zip(outs).map(|(&i, &o)| (i, o)).collect();
            assert_eq!(got, want, "set {s}, down offset {k}");
        }
        // Pointwise: a linear map of every row.
        let (c_in, c_out) = (5, 7);
        let x = values(s as u64, set.len() * c_in);
        let w = values(100 + s as u64, c_in * c_out);
        let y = ChunkedConv::pointwise(set.len()).unwrap().forward(&x, c_in, &w, c_out).unwrap();
        let mut want = vec![0f32; set.len() * c_out];
        for u in 0..set.len() {
            for o in 0..c_out {
                want[u * c_out + o] = (0..c_in).map(|i| x[u * c_in + i] * w[i * c_out + o]).sum();
            }
        }
        assert_close(&y, &want, "pointwise");
    }
}

/// The batch norm + ReLU folded into the chunked gather gives the bits of a separate pass
/// followed by the plain forward; with `accumulate` the result lands on top of `y`. Shuffled
/// rows exercise the non-contiguous (chunk buffer) path.
#[test]
fn fused_bn_relu_forward_matches_separate_passes() {
    let mut shuffled = surface_set(2);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, rng.random_range(0..=i));
    }
    for set in [surface_set(0), shuffled] {
        let (coarse, down) = KernelMap::downsample(&set).unwrap();
        let layers = [
            ChunkedConv::submanifold(&set, 3, &SMALL_CHUNKS).unwrap(),
            ChunkedConv::new(down, &set, &coarse, &SMALL_CHUNKS).unwrap(),
            ChunkedConv::pointwise(set.len()).unwrap(),
        ];
        for (q, layer) in layers.iter().enumerate() {
            let (c_in, c_out) = (6, 9);
            let x = values(q as u64, layer.n_in() * c_in);
            let w = values(10 + q as u64, layer.map().kernel_volume() * c_in * c_out);
            let scale = values(20 + q as u64, c_in);
            let shift = values(30 + q as u64, c_in);
            let normed: Vec<f32> = x
                .chunks_exact(c_in)
                .flat_map(|r| r.iter().zip(&scale).zip(&shift).map(|((x, s), b)| (x * s + b).max(0.0)))
                .collect();
            let want = layer.forward(&normed, c_in, &w, c_out).unwrap();
            let mut got = vec![f32::NAN; want.len()];
            layer.forward_bn_relu_into(&x, c_in, &scale, &shift, &w, c_out, &mut got, false).unwrap();
            assert_eq!(got, want, "layer {q}");
            let base = values(40 + q as u64, want.len());
            let mut acc = base.clone();
            layer.forward_bn_relu_into(&x, c_in, &scale, &shift, &w, c_out, &mut acc, true).unwrap();
            let sum: Vec<f32> = base.iter().zip(&want).map(|(a, b)| a + b).collect();
            assert_close(&acc, &sum, "accumulated");
            assert!(layer.forward_bn_relu_into(&x, c_in, &scale[1..], &shift, &w, c_out, &mut acc, true).is_err());
        }
    }
}
