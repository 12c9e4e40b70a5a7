//! Bad conditions are errors, never panics or wrong results: a buffer over the device's
//! limit, a lost device. (No adapter at all: tests/no_adapter.rs, its own process.)

#![cfg(feature = "gpu")]

use std::sync::Arc;

use semrecon_gpu::{GpuContext, GpuEngine, GpuError};
use semrecon_sparse::backend_tests::{random_set, surface_set};
use semrecon_sparse::{ConvAlgorithm, ConvBackend};

fn context() -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => Some(c),
        Err(e) => {
            eprintln!("skipping a GPU test: {e}");
            None
        }
    }
}

#[test]
fn buffers_over_the_limit_are_errors() {
    let Some(mut ctx) = context() else { return };
    ctx.set_buffer_limit(16 * 1024);
    let ctx = Arc::new(ctx);
    for algorithm in [ConvAlgorithm::Chunked, ConvAlgorithm::Rulebook] {
        let gpu = GpuEngine::with_context(Arc::clone(&ctx), algorithm);
        // 1,000 voxels: the map fits (hash slots 8 KiB), 32 channels of features do not.
        let coords = random_set(1000, 16, 1);
        match gpu.submanifold(&coords, 3) {
            Err(GpuError::TooLarge { .. }) => {}
            Ok(layer) => {
                let r = gpu.forward(&layer, &vec![1.0; 1000 * 32], 32, &vec![0.0; 27 * 32 * 4], 4);
                assert!(matches!(r, Err(GpuError::TooLarge { .. })), "{algorithm:?}: {r:?}");
            }
            Err(e) => panic!("{algorithm:?}: {e}"),
        }
    }
}

#[test]
fn a_lost_device_is_an_error() {
    let Some(ctx) = context() else { return };
    let gpu = GpuEngine::with_context(Arc::new(ctx), ConvAlgorithm::Chunked);
    let coords = surface_set(4);
    let layer = match gpu.submanifold(&coords, 3) {
        Ok(l) => l,
        Err(e) => panic!("{e}"),
    };
    gpu.context().destroy();
    let r = gpu.forward(&layer, &vec![1.0; coords.len() * 2], 2, &[0.5; 27 * 2 * 2], 2);
    assert!(r.is_err(), "a forward on a destroyed device returned {r:?}");
    eprintln!("forward after destroy: {}", r.err().map(|e| e.to_string()).unwrap_or_default());
}

/// A layer imported for one algorithm's forward runs that forward (and the weight gradient,
/// which reads the same parts) exactly as an engine-made layer does, and the other algorithm
/// is an error naming the missing part.
#[test]
fn imported_layers_hold_their_algorithms_forward_only() {
    let Some(ctx) = context() else { return };
    let ctx = Arc::new(ctx);
    let coords = surface_set(5);
    let map = semrecon_sparse::KernelMap::submanifold(&coords, 3).expect("map");
    let cpu_layer = semrecon_sparse::ChunkedConv::new(map, &coords, &coords, &semrecon_sparse::ChunkConfig::default())
        .expect("plan");
    let (c_in, c_out) = (3, 5);
    let x: Vec<f32> = (0..coords.len() * c_in).map(|i| ((i * 7919) % 23) as f32 / 23.0 - 0.5).collect();
    let w: Vec<f32> = (0..27 * c_in * c_out).map(|i| ((i * 104_729) % 31) as f32 / 31.0 - 0.5).collect();
    for (algorithm, other) in
        [(ConvAlgorithm::Chunked, ConvAlgorithm::Rulebook), (ConvAlgorithm::Rulebook, ConvAlgorithm::Chunked)]
    {
        let gpu = GpuEngine::with_context(Arc::clone(&ctx), algorithm);
        let imported = gpu.import(&cpu_layer).expect("import");
        let made = gpu.submanifold(&coords, 3).expect("layer");
        let a = gpu.forward(&imported, &x, c_in, &w, c_out).expect("forward on the import");
        let b = gpu.forward(&made, &x, c_in, &w, c_out).expect("forward on the made layer");
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
        let diff = a.iter().zip(&b).fold(0f32, |m, (p, q)| m.max((p - q).abs()));
        assert!(diff <= 1e-5 * scale, "{algorithm:?}: {diff} of {scale}");
        let r = gpu.with_algorithm(other).forward(&imported, &x, c_in, &w, c_out);
        assert!(matches!(r, Err(GpuError::LayerPart(_))), "{other:?} on a {algorithm:?} import: {r:?}");
        // The weight gradient reads what the forward reads (the plan, or the pairs).
        let dw = gpu.backward_weight(&imported, &x, c_in, &b, c_out).expect("weight gradient on the import");
        let dw_made = gpu.backward_weight(&made, &x, c_in, &b, c_out).expect("weight gradient");
        assert_eq!(dw, dw_made, "{algorithm:?}: weight gradients differ");
    }
}
