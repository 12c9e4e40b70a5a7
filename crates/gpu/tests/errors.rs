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
