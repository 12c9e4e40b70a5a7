//! The voxel hierarchy built on the device (`GpuEngine::build_hierarchy`) against the host's:
//! every level's voxels (same order), submanifold table, strided tables and parents equal to
//! `semrecon_sparse::KernelMap`'s, on random sets (negative coordinates, two batches) and
//! surfaces, in Z-order and shuffled; the interpolation tables against a plain trilinear
//! reference written from the coordinates alone; a forward through the device layers equal to
//! the CPU engine's; and bad input (duplicates, no levels) as errors.

#![cfg(feature = "gpu")]
#![allow(clippy::unwrap_used)]

use std::collections::HashMap;

use semrecon_gpu::{test_engine, GpuEngine, HostLevel};
use semrecon_sparse::backend_tests::{random_set, surface_set, Rng};
use semrecon_sparse::morton::morton_order;
use semrecon_sparse::{ConvAlgorithm, ConvBackend, Coord, CpuEngine, KernelMap, ResidentBackend};

/// The host's levels of `coords`, as the network's host geometry builds them.
fn host_levels(coords: &[Coord], levels: usize) -> Vec<HostLevel> {
    let mut out = Vec::new();
    let mut current = coords.to_vec();
    for i in 0..levels {
        let subm = KernelMap::submanifold_table(&current, 3).unwrap();
        let (next, down, parent) = if i + 1 < levels {
            let (coarse, map) = KernelMap::downsample(&current).unwrap();
            let mut parent = vec![0u32; current.len()];
            let mut down = vec![u32::MAX; coarse.len() * 8];
            let mut up = vec![u32::MAX; current.len() * 8];
            for k in 0..8 {
                let (ins, outs) = map.pairs(k);
                for (&f, &c) in ins.iter().zip(outs) {
                    parent[f as usize] = c;
                    down[c as usize * 8 + k] = f;
                    up[f as usize * 8 + k] = c;
                }
            }
            (coarse, Some((down, up)), Some(parent))
        } else {
            (Vec::new(), None, None)
        };
        out.push(HostLevel { coords: std::mem::replace(&mut current, next), subm, down, parent });
    }
    out
}

fn shuffled(mut v: Vec<Coord>, seed: u64) -> Vec<Coord> {
    let mut rng = Rng::new(seed);
    for i in (1..v.len()).rev() {
        let j = rng.below(i as u64 + 1) as usize;
        v.swap(i, j);
    }
    v
}

fn z_ordered(v: &[Coord]) -> Vec<Coord> {
    morton_order(v).unwrap().iter().map(|&r| v[r as usize]).collect()
}

fn sets() -> Vec<(&'static str, Vec<Coord>)> {
    let random = random_set(3000, 24, 7);
    let surface = surface_set(11);
    vec![
        ("random, z-order", z_ordered(&random)),
        ("random, shuffled", shuffled(random, 8)),
        ("surface, z-order", z_ordered(&surface)),
        ("surface, shuffled", shuffled(surface, 9)),
        ("one voxel", vec![[-3, 5, -7, 1]]),
    ]
}

#[test]
fn device_levels_equal_the_hosts() {
    let Some(gpu) = test_engine(ConvAlgorithm::Chunked) else { return };
    for (name, coords) in sets() {
        let levels = 4;
        let want = host_levels(&coords, levels);
        let h = gpu.build_hierarchy(&coords, levels).unwrap();
        assert_eq!(h.levels.len(), levels, "{name}");
        for (i, w) in want.iter().enumerate() {
            let got = gpu.download_level(&h, i).unwrap();
            assert_eq!(got.coords, w.coords, "{name}: level {i} voxels");
            assert_eq!(got.subm, w.subm, "{name}: level {i} submanifold table");
            assert_eq!(got.down, w.down, "{name}: level {i} strided tables");
            assert_eq!(got.parent, w.parent, "{name}: level {i} parents");
            let pairs = w.subm.iter().filter(|&&r| r != u32::MAX).count();
            assert_eq!(h.levels[i].neighbour_pairs(), pairs, "{name}: level {i} pairs");
            assert_eq!(h.levels[i].rows(), w.coords.len());
        }
    }
}

/// Trilinear weights written from the coordinates: the fine voxel's centre in coarse units,
/// the 2x2x2 coarse centres around it, weights of absent ones dropped and the rest
/// renormalised; corners in z, y, x order, absent corners carry the ancestor's row.
fn reference_interpolation(fine: &[Coord], coarse: &[Coord], shift: u32) -> (Vec<u32>, Vec<f32>) {
    let index: HashMap<Coord, u32> = coarse.iter().enumerate().map(|(r, &c)| (c, r as u32)).collect();
    let scale = f64::from(1u32 << shift);
    let (mut rows, mut weights) = (Vec::new(), Vec::new());
    for &c in fine {
        let anc = [c[0] >> shift, c[1] >> shift, c[2] >> shift, c[3]];
        let a = index[&anc];
        let mut corner = Vec::new();
        let pos: Vec<f64> = (0..3).map(|d| (f64::from(c[d]) + 0.5) / scale - 0.5).collect();
        let base: Vec<i32> = pos.iter().map(|p| p.floor() as i32).collect();
        for dz in 0..2 {
            for dy in 0..2 {
                for dx in 0..2 {
                    let q = [base[0] + dx, base[1] + dy, base[2] + dz, c[3]];
                    let w: f64 = (0..3)
                        .map(|d| {
                            let t = pos[d] - f64::from(base[d]);
                            if q[d] == base[d] {
                                1.0 - t
                            } else {
                                t
                            }
                        })
                        .product();
                    corner.push(index.get(&q).map_or((a, 0.0), |&r| (r, w)));
                }
            }
        }
        let total: f64 = corner.iter().map(|c| c.1).sum();
        for (r, w) in corner {
            rows.push(r);
            weights.push((w / total) as f32);
        }
    }
    (rows, weights)
}

#[test]
fn interpolation_tables_match_the_trilinear_reference() {
    let Some(gpu) = test_engine(ConvAlgorithm::Chunked) else { return };
    for (name, coords) in sets() {
        let levels = 4;
        let h = gpu.build_hierarchy(&coords, levels).unwrap();
        let host = host_levels(&coords, levels);
        for t in 0..levels - 1 {
            for j in t + 1..levels {
                let g = gpu.interpolation(&h, t, j).unwrap();
                let (rows, weights) = gpu.download_gather(&g).unwrap();
                let (want_rows, want_weights) =
                    reference_interpolation(&host[t].coords, &host[j].coords, (j - t) as u32);
                assert_eq!(rows.len(), want_rows.len(), "{name}: {t} <- {j}");
                for (e, ((r, w), (wr, ww))) in
                    rows.iter().zip(&weights).zip(want_rows.iter().zip(&want_weights)).enumerate()
                {
                    // Absent corners (weight 0) may name any row; present ones the same row.
                    if *ww > 0.0 {
                        assert_eq!(r, wr, "{name}: {t} <- {j}, entry {e}");
                    }
                    assert!((w - ww).abs() <= 1e-6, "{name}: {t} <- {j}, entry {e}: {w} vs {ww}");
                }
            }
        }
        assert!(gpu.interpolation(&h, 2, 2).is_err());
        assert!(gpu.interpolation(&h, 0, levels).is_err());
    }
}

/// A convolution through each device layer equals the CPU engine's on the host's maps.
#[test]
fn device_layers_convolve_like_the_cpu_engine() {
    let Some(gpu) = test_engine(ConvAlgorithm::Chunked) else { return };
    let cpu = CpuEngine::default();
    let coords = z_ordered(&random_set(2500, 20, 3));
    let h = gpu.build_hierarchy(&coords, 2).unwrap();
    let (coarse, _) = KernelMap::downsample(&coords).unwrap();
    let (c_in, c_out) = (5, 7);
    let check = |what: &str, layer: &semrecon_gpu::GpuLayer, host: &<CpuEngine as ConvBackend>::Layer, kv: usize| {
        let (n_in, n_out) = gpu.layer_rows(layer);
        let x = Rng::new(n_in as u64).values(n_in * c_in);
        let w = Rng::new(kv as u64).values(kv * c_in * c_out);
        let want = cpu.forward(host, &x, c_in, &w, c_out).unwrap();
        let xt = gpu.upload(&x).unwrap();
        let wt = gpu.upload(&w).unwrap();
        let mut y = gpu.upload(&vec![0.0; n_out * c_out]).unwrap();
        gpu.conv(layer, &xt, c_in, None, &wt, c_out, &mut y, false).unwrap();
        let got = gpu.download(&y, n_out * c_out).unwrap();
        let top = want.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        let diff = got.iter().zip(&want).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(diff <= 1e-5 * top, "{what}: {diff} of {top}");
    };
    let level = &h.levels[0];
    check("submanifold", &level.subm, &cpu.submanifold(&coords, 3).unwrap(), 27);
    check("pointwise", &level.point, &cpu.submanifold(&coords, 1).unwrap(), 1);
    let (down, up) = level.down.as_ref().unwrap();
    check("down", down, &cpu.downsample(&coords).unwrap().1, 8);
    check("up", up, &cpu.upsample(&coarse, &coords).unwrap(), 8);
}

#[test]
fn bad_input_is_an_error() {
    let Some(gpu) = test_engine(ConvAlgorithm::Chunked) else { return };
    let err = gpu.build_hierarchy(&[[1, 2, 3, 0], [4, 5, 6, 0], [1, 2, 3, 0]], 3).unwrap_err();
    assert!(err.to_string().contains("duplicate"), "{err}");
    assert!(gpu.build_hierarchy(&[[1, 2, 3, 0]], 0).is_err());
    let err = gpu.build_hierarchy(&[[0, 0, 0, 0], [i32::MAX, 0, 0, 0]], 2).unwrap_err();
    assert!(err.to_string().contains("row 1"), "{err}");
    // Empty input: levels of no voxels.
    let h = gpu.build_hierarchy(&[], 3).unwrap();
    assert!(h.levels.iter().all(|l| l.rows() == 0));
    let _: &GpuEngine = &gpu;
}
