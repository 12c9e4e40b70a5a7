//! The network on the GPU engine against the CPU: logits within 1e-4 of the scale and the same
//! labels, with random weights (both algorithms) and with the shipped model on a corner of a
//! generated room; and the transfers of a forward (weights once per model, one input upload
//! and one read-back per call). Runs on lavapipe in CI (`cargo test -p semrecon-net --features gpu --test
//! gpu`); skips with a message when no GPU adapter exists.

#![cfg(feature = "gpu")]
#![allow(clippy::unwrap_used)]

use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_net::inference::Device;
use semrecon_net::{reference, ConvKernel, GpuGeometry, NetConfig, Segmenter, Weights};
use semrecon_sparse::backend_tests::{random_set, Rng};
use semrecon_sparse::ConvAlgorithm;

fn gpu() -> Option<Device> {
    semrecon_gpu::test_engine(ConvAlgorithm::Chunked).map(Device::Gpu)
}

fn max_abs(v: &[f32]) -> f32 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn argmax(v: &[f32]) -> Vec<usize> {
    v.chunks(13).map(|r| (0..13).fold(0, |b, c| if r[c] > r[b] { c } else { b })).collect()
}

/// Largest difference, and labels that differ where the CPU's best two scores are further
/// apart than the error (a real disagreement, not a near-tie flipped by rounding).
fn compare(what: &str, gpu: &[f32], cpu: &[f32]) {
    let scale = max_abs(cpu).max(1.0);
    let err = gpu.iter().zip(cpu).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(err <= 1e-4 * scale, "{what}: max error {err} (scale {scale})");
    let (lg, lc) = (argmax(gpu), argmax(cpu));
    let mut flips = 0;
    for (v, (a, b)) in lg.iter().zip(&lc).enumerate() {
        if a != b {
            let row = &cpu[v * 13..(v + 1) * 13];
            assert!(
                (row[*a] - row[*b]).abs() <= 2.0 * err,
                "{what}: voxel {v} labelled {a} on the GPU, {b} on the CPU"
            );
            flips += 1;
        }
    }
    eprintln!("{what}: {} voxels, max error {err:e} (scale {scale}), {flips} near-tie label flips", lc.len());
}

#[test]
fn gpu_network_matches_the_cpu_and_the_reference() {
    let Some(device) = gpu() else { return };
    for (levels, width, seed) in [(3, 4, 1u64), (4, 8, 2), (1, 5, 3)] {
        let config = NetConfig::new("t", levels, width, 0.05);
        let mut w = Weights::random(&config, seed);
        w.perturb_normalisation(seed + 1);
        let coords = random_set(1500, 18, seed);
        let feats = Rng::new(seed).values(coords.len() * 3);
        let want = reference::forward(&config, &w, &coords, &feats).unwrap();
        let mut net = Segmenter::new(w, config).unwrap();
        let cpu = net.segment(&coords, &feats).unwrap();
        net.set_device(device.clone());
        for (kernel, geometry) in [
            (ConvKernel::Chunked, GpuGeometry::Device),
            (ConvKernel::Chunked, GpuGeometry::Host),
            (ConvKernel::Rulebook, GpuGeometry::Host),
        ] {
            net.set_kernel(kernel);
            net.set_gpu_geometry(geometry);
            let got = net.segment(&coords, &feats).unwrap();
            compare(&format!("L={levels} M={width} {kernel:?} {geometry:?} vs reference"), &got, &want);
            compare(&format!("L={levels} M={width} {kernel:?} {geometry:?} vs cpu"), &got, &cpu);
            assert_eq!(net.level_stats().len(), levels, "stats of every level");
        }
        net.set_kernel(ConvKernel::Chunked);
        net.set_gpu_geometry(GpuGeometry::Device);
        // Empty input on the GPU too.
        assert!(net.segment(&[], &[]).unwrap().is_empty());
    }
}

#[test]
fn shipped_model_labels_a_room_corner_alike_on_gpu_and_cpu() {
    let Some(device) = gpu() else { return };
    let mut net = match semrecon_net::shipped::load_default() {
        Ok(n) => n,
        Err(e) => {
            eprintln!("skipping: {e}");
            return;
        }
    };
    let room = generate_room(&RoomConfig { seed: 1, style: None });
    let cloud = semrecon_net::surface::sample_surface(&room.mesh, 400.0, 1);
    // A 1.6 m corner (walls, floor, some furniture): a few thousand voxels, seconds on lavapipe.
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.positions[i].max_element() < 1.6).collect();
    let points: Vec<[f32; 3]> = keep.iter().map(|&i| cloud.positions[i].to_array()).collect();
    let colors: Vec<[u8; 3]> = keep.iter().map(|&i| cloud.colors[i]).collect();
    let cpu = net.segment_points_scores(&points, &colors).unwrap();
    let cpu_labels = net.segment_points(&points, &colors).unwrap();
    net.set_device(device);
    let gpu = net.segment_points_scores(&points, &colors).unwrap();
    assert_eq!(gpu.coords, cpu.coords);
    compare("shipped s20, room corner", &gpu.logits, &cpu.logits);
    assert_eq!(argmax(&gpu.logits), argmax(&cpu.logits), "labels differ");
    // The labels-only path (an argmax on the device) gives the same labels per point.
    assert_eq!(net.segment_points(&points, &colors).unwrap(), cpu_labels, "point labels differ");
}

/// Weight tensors of a network of `l` levels: input, four per residual block (two folded
/// batch norms, two convolutions), two per strided layer, seven per decoder step, one per
/// fusion pair, three in the head.
fn weight_tensors(l: usize) -> u64 {
    let fuse: usize = (0..l.saturating_sub(2)).map(|t| l - 2 - t).sum();
    (1 + 4 * l + 2 * (l - 1) + 7 * (l - 1) + fuse + 3) as u64
}

#[test]
fn weights_go_up_once_and_each_forward_uploads_once_and_reads_back_once() {
    let Some(engine) = semrecon_gpu::test_engine(ConvAlgorithm::Chunked) else { return };
    let config = NetConfig::new("t", 4, 5, 0.05);
    let coords = random_set(900, 16, 11);
    let feats = Rng::new(11).values(coords.len() * 3);
    let mut net = Segmenter::new(Weights::random(&config, 11), config).unwrap();
    let cpu = net.segment(&coords, &feats).unwrap();
    net.set_device(Device::Gpu(engine.clone()));
    let ctx = engine.context();
    let mut calls = Vec::new();
    for kernel in [ConvKernel::Chunked, ConvKernel::Chunked, ConvKernel::Rulebook] {
        net.set_kernel(kernel);
        let before = ctx.transfers();
        let got = net.segment(&coords, &feats).unwrap();
        calls.push(ctx.transfers().since(&before));
        compare(&format!("transfers test, {kernel:?}"), &got, &cpu);
    }
    eprintln!("transfers per call: {calls:?}");
    assert_eq!(calls[0].tensor_uploads, weight_tensors(4) + 1, "first call: the weights and the input");
    for (i, c) in calls.iter().enumerate() {
        if i > 0 {
            assert_eq!(c.tensor_uploads, 1, "call {i}: only the input goes up");
            assert_eq!(c.tensor_bytes, feats.len() as u64 * 4, "call {i}: the input's bytes");
        }
        assert_eq!(c.readbacks, 1, "call {i}: one read-back");
        assert_eq!(c.readback_bytes, cpu.len() as u64 * 4, "call {i}: the logits' bytes");
        assert!(c.geometry_uploads > 0, "call {i}: the geometry of the input goes up");
        // Building the geometry on the device waits once per level for its voxel count.
        let waits = if i < 2 { 4 } else { 0 };
        assert_eq!(c.status_reads, waits, "call {i}: status reads");
    }
    // The labels-only path reads back one word per voxel.
    let before = ctx.transfers();
    let points: Vec<[f32; 3]> =
        (0..500).map(|i| [(i % 10) as f32 * 0.05, (i / 10 % 10) as f32 * 0.05, (i / 100) as f32 * 0.05]).collect();
    let colors: Vec<[u8; 3]> =
        (0..500).map(|i| [(i * 7 % 256) as u8, (i * 13 % 256) as u8, (i * 29 % 256) as u8]).collect();
    let labels = net.segment_points(&points, &colors).unwrap();
    let t = ctx.transfers().since(&before);
    net.set_device(Device::Cpu);
    assert_eq!(labels, net.segment_points(&points, &colors).unwrap(), "labels on the CPU");
    let voxels = net.segment_points_scores(&points, &colors).unwrap().coords.len() as u64;
    assert_eq!((t.tensor_uploads, t.readbacks, t.readback_bytes), (1, 1, voxels * 4), "labels only: {t:?}");
    // A new device (here the same one again) gets the weights again.
    net.set_device(Device::Gpu(engine.clone()));
    let before = ctx.transfers();
    net.segment(&coords, &feats).unwrap();
    assert_eq!(ctx.transfers().since(&before).tensor_uploads, weight_tensors(4) + 1);
}
