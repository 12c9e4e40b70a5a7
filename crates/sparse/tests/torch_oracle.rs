//! The independent oracle: outputs and gradients computed once by PyTorch's dense `conv3d` /
//! `conv_transpose3d` on the densified grid (`tools/make_conv_fixtures.py`, float64, stored
//! as f32), checked against every kernel of the engine. Unlike `kernels.rs`, which compares
//! the fast kernels with our own reference, this catches a convention shared by all of them
//! (offset numbering, weight layout, cross-correlation vs convolution, the floor of the
//! strided layers) being wrong.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;
use std::path::PathBuf;

use semrecon_sparse::{reference, rulebook, ChunkConfig, ChunkedConv, Coord, KernelMap, MapKind};
use serde_json::Value;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

struct Case {
    name: String,
    kind: MapKind,
    c_in: usize,
    c_out: usize,
    in_coords: Vec<Coord>,
    out_coords: Vec<Coord>,
    arrays: HashMap<String, Vec<f32>>,
}

fn coords(v: &Value) -> Vec<Coord> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let c: Vec<i32> = c.as_array().unwrap().iter().map(|x| x.as_i64().unwrap() as i32).collect();
            [c[0], c[1], c[2], c[3]]
        })
        .collect()
}

fn load() -> Vec<Case> {
    let dir = fixtures();
    let meta: Value = serde_json::from_slice(&std::fs::read(dir.join("torch_oracle.json")).unwrap()).unwrap();
    let blob = std::fs::read(dir.join("torch_oracle.bin")).unwrap();
    let floats: Vec<f32> = blob.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    meta["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let kind = match c["kind"].as_str().unwrap() {
                "submanifold" => MapKind::Submanifold { kernel_size: 3 },
                "down" => MapKind::Down,
                "up" => MapKind::Up,
                k => panic!("unknown kind {k}"),
            };
            let arrays = c["arrays"]
                .as_object()
                .unwrap()
                .iter()
                .map(|(k, v)| {
                    let off = v[0].as_u64().unwrap() as usize;
                    let len = v[1].as_u64().unwrap() as usize;
                    (k.clone(), floats[off..off + len].to_vec())
                })
                .collect();
            Case {
                name: c["name"].as_str().unwrap().to_string(),
                kind,
                c_in: c["c_in"].as_u64().unwrap() as usize,
                c_out: c["c_out"].as_u64().unwrap() as usize,
                in_coords: coords(&c["in_coords"]),
                out_coords: coords(&c["out_coords"]),
                arrays,
            }
        })
        .collect()
}

/// Relative to the largest magnitude of the expected array: the oracle is float64 rounded
/// to f32, the engine accumulates in f32.
#[track_caller]
fn assert_close(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    let worst = got.iter().zip(want).map(|(g, w)| (g - w).abs() / scale).fold(0f32, f32::max);
    assert!(worst <= 1e-4, "{what}: worst relative error {worst:e} (scale {scale})");
}

/// Rows of `rows` (`[coords.len(), c]`, in the fixture's order of `coords`) reordered to
/// `order`.
fn reorder(rows: &[f32], c: usize, coords: &[Coord], order: &[Coord]) -> Vec<f32> {
    let at: HashMap<Coord, usize> = coords.iter().enumerate().map(|(i, &p)| (p, i)).collect();
    order
        .iter()
        .flat_map(|p| {
            let i = at[p];
            rows[i * c..(i + 1) * c].iter().copied()
        })
        .collect()
}

#[test]
fn every_kernel_matches_pytorch_dense_convolution() {
    let cases = load();
    assert!(cases.len() >= 6, "fixtures hold {} cases", cases.len());
    let kinds: Vec<MapKind> = cases.iter().map(|c| c.kind).collect();
    assert!(kinds.contains(&MapKind::Down) && kinds.contains(&MapKind::Up));
    for case in &cases {
        let (c_in, c_out) = (case.c_in, case.c_out);
        let a = |k: &str| case.arrays[k].as_slice();
        // The engine's own output set: the down layer orders its coarse voxels itself.
        let (out_coords, map) = match case.kind {
            MapKind::Submanifold { kernel_size } => {
                (case.in_coords.clone(), KernelMap::submanifold(&case.in_coords, kernel_size).unwrap())
            }
            MapKind::Down => KernelMap::downsample(&case.in_coords).unwrap(),
            MapKind::Up => (case.out_coords.clone(), KernelMap::upsample(&case.in_coords, &case.out_coords).unwrap()),
        };
        assert_eq!(out_coords.len(), case.out_coords.len(), "{}: output set", case.name);
        let y = reorder(a("y"), c_out, &case.out_coords, &out_coords);
        let dy = reorder(a("dy"), c_out, &case.out_coords, &out_coords);
        let (x, w, dx, dw) = (a("x"), a("w"), a("dx"), a("dw"));
        let name = &case.name;

        let rin = &case.in_coords;
        assert_close(
            &reference::forward(case.kind, rin, &out_coords, x, c_in, w, c_out).unwrap(),
            &y,
            &format!("{name} reference forward"),
        );
        assert_close(
            &reference::backward_input(case.kind, rin, &out_coords, &dy, c_out, w, c_in).unwrap(),
            dx,
            &format!("{name} reference dx"),
        );
        assert_close(
            &reference::backward_weight(case.kind, rin, &out_coords, x, c_in, &dy, c_out).unwrap(),
            dw,
            &format!("{name} reference dw"),
        );

        assert_close(&rulebook::forward(&map, x, c_in, w, c_out).unwrap(), &y, &format!("{name} rulebook forward"));
        assert_close(&rulebook::backward_input(&map, &dy, c_out, w, c_in).unwrap(), dx, &format!("{name} rulebook dx"));
        assert_close(
            &rulebook::backward_weight(&map, x, c_in, &dy, c_out).unwrap(),
            dw,
            &format!("{name} rulebook dw"),
        );

        // The default plan and one with tiny chunks (many splits, regions crossing chunks).
        let tiny = ChunkConfig { chunk_side: 4, levels: 3, max_region_rows: 8 };
        for cfg in [ChunkConfig::default(), tiny] {
            let conv = ChunkedConv::new(map.clone(), rin, &out_coords, &cfg).unwrap();
            assert_close(&conv.forward(x, c_in, w, c_out).unwrap(), &y, &format!("{name} chunked forward {cfg:?}"));
            assert_close(&conv.backward_input(&dy, c_out, w, c_in).unwrap(), dx, &format!("{name} chunked dx {cfg:?}"));
            assert_close(
                &conv.backward_weight(x, c_in, &dy, c_out).unwrap(),
                dw,
                &format!("{name} chunked dw {cfg:?}"),
            );
        }
        // The up layer as the transpose of the down layer's plan, as the network builds it.
        if case.kind == MapKind::Up {
            let (coarse, down) = KernelMap::downsample(&case.out_coords).unwrap();
            let down = ChunkedConv::new(down, &case.out_coords, &coarse, &ChunkConfig::default()).unwrap();
            let up = down.transposed().unwrap();
            let xu = reorder(x, c_in, &case.in_coords, &coarse);
            let dxu = reorder(dx, c_in, &case.in_coords, &coarse);
            assert_close(&up.forward(&xu, c_in, w, c_out).unwrap(), &y, &format!("{name} transposed-plan forward"));
            assert_close(&up.backward_input(&dy, c_out, w, c_in).unwrap(), &dxu, &format!("{name} transposed-plan dx"));
            assert_close(
                &up.backward_weight(&xu, c_in, &dy, c_out).unwrap(),
                dw,
                &format!("{name} transposed-plan dw"),
            );
        }
    }
}
