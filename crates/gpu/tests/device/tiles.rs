//! Every tile shape of the chunked kernel (`CHUNKED_TILES`), forced, against the rulebook
//! kernel (itself held to the plain reference by the shared suite): the default policy only
//! reaches each shape at some widths, so each is checked here at widths below, at and above
//! its tile, with a fused batch norm and a residual. Likewise the chunked weight gradient's
//! channel blocks.

#![cfg(feature = "gpu")]

use std::sync::Arc;

use semrecon_gpu::{GpuContext, GpuEngine, CHUNKED_TILES};
use semrecon_sparse::backend_tests::surface_set;
use semrecon_sparse::{BnRelu, ConvAlgorithm, ConvBackend};

/// The device, or `None` after saying why the test is skipped.
fn context() -> Option<Arc<GpuContext>> {
    match GpuContext::new() {
        Ok(c) => Some(Arc::new(c)),
        Err(e) => {
            eprintln!("skipping a GPU test: {e}");
            None
        }
    }
}

fn values(n: usize, seed: usize) -> Vec<f32> {
    (0..n).map(|i| (((i + seed) * 7919) % 101) as f32 / 101.0 - 0.5).collect()
}

#[test]
fn every_tile_shape_matches_the_rulebook_kernel() {
    let Some(ctx) = context() else { return };
    let coords = surface_set(5);
    let n = coords.len();
    let rulebook = GpuEngine::with_context(Arc::clone(&ctx), ConvAlgorithm::Rulebook);
    let layer = rulebook.submanifold(&coords, 3).expect("layer");
    for (c_in, c_out) in [(3, 5), (17, 33), (33, 70), (20, 131)] {
        let x = values(n * c_in, 1);
        let w = values(27 * c_in * c_out, 2);
        let (scale, shift) = (values(c_in, 3), values(c_in, 4));
        let bn = Some(BnRelu { scale: &scale, shift: &shift });
        let mut expected = values(n * c_out, 5);
        rulebook.forward_into(&layer, &x, c_in, bn, &w, c_out, &mut expected, true).expect("rulebook");
        let top = expected.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
        for (t, shape) in CHUNKED_TILES.iter().enumerate() {
            let chunked =
                GpuEngine::with_context(Arc::clone(&ctx), ConvAlgorithm::Chunked).with_tile(Some(t)).expect("tile");
            let mut got = values(n * c_out, 5);
            chunked.forward_into(&layer, &x, c_in, bn, &w, c_out, &mut got, true).expect("chunked");
            let diff = got.iter().zip(&expected).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(diff <= 1e-4 * top, "tile {shape:?}, {c_in} -> {c_out}: {diff} of {top}");
        }
    }
    let gpu = GpuEngine::with_context(ctx, ConvAlgorithm::Chunked);
    assert!(gpu.with_tile(Some(CHUNKED_TILES.len())).is_err());
}

/// Splits (partial sums over ranges of (offset, channel step) pairs, added in order) against
/// the rulebook kernel: forced to one, to two, to an uneven five, to 27, to one split per step
/// and more, and by size; with a fused batch norm, a residual, and on strided layers.
#[test]
fn splits_match_the_rulebook_kernel() {
    let Some(ctx) = context() else { return };
    let fine = surface_set(6);
    let rulebook = GpuEngine::with_context(Arc::clone(&ctx), ConvAlgorithm::Rulebook);
    let sub = rulebook.submanifold(&fine, 3).expect("layer");
    let (_, down) = rulebook.downsample(&fine).expect("down");
    for (name, layer, kv) in [("submanifold", &sub, 27), ("down", &down, 8)] {
        let (n_in, n_out) = rulebook.layer_rows(layer);
        let (c_in, c_out) = (13, 37);
        let x = values(n_in * c_in, 1);
        let w = values(kv * c_in * c_out, 2);
        let (scale, shift) = (values(c_in, 3), values(c_in, 4));
        let bn = Some(BnRelu { scale: &scale, shift: &shift });
        let mut expected = values(n_out * c_out, 5);
        rulebook.forward_into(layer, &x, c_in, bn, &w, c_out, &mut expected, true).expect("rulebook");
        let top = expected.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
        for splits in [Some(1), Some(2), Some(5), Some(27), Some(1000), None] {
            let chunked =
                GpuEngine::with_context(Arc::clone(&ctx), ConvAlgorithm::Chunked).with_splits(splits).expect("splits");
            let mut got = values(n_out * c_out, 5);
            chunked.forward_into(layer, &x, c_in, bn, &w, c_out, &mut got, true).expect("chunked");
            let diff = got.iter().zip(&expected).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(diff <= 1e-4 * top, "{name}, {splits:?} splits: {diff} of {top}");
        }
    }
    let gpu = GpuEngine::with_context(ctx, ConvAlgorithm::Chunked);
    assert!(gpu.with_splits(Some(0)).is_err());
}

/// The chunked weight gradient (blocks of 16 input x 64 output channels) against the
/// rulebook's, at widths that cut partial blocks both ways, on submanifold and strided layers.
#[test]
fn chunked_weight_gradient_matches_the_rulebook_kernel() {
    let Some(ctx) = context() else { return };
    let coords = surface_set(5);
    let rulebook = GpuEngine::with_context(Arc::clone(&ctx), ConvAlgorithm::Rulebook);
    let chunked = GpuEngine::with_context(ctx, ConvAlgorithm::Chunked);
    let (coarse, _) = chunked.downsample(&coords).expect("coarse set");
    for (c_in, c_out) in [(3, 5), (17, 33), (33, 70), (20, 131)] {
        let layers = [
            (chunked.submanifold(&coords, 3).expect("layer"), rulebook.submanifold(&coords, 3).expect("layer")),
            (chunked.downsample(&coords).expect("down").1, rulebook.downsample(&coords).expect("down").1),
            (chunked.upsample(&coarse, &coords).expect("up"), rulebook.upsample(&coarse, &coords).expect("up")),
        ];
        for (a, b) in &layers {
            let (n_in, n_out) = chunked.layer_rows(a);
            let x = values(n_in * c_in, 6);
            let dy = values(n_out * c_out, 7);
            let got = chunked.backward_weight(a, &x, c_in, &dy, c_out).expect("chunked");
            let expected = rulebook.backward_weight(b, &x, c_in, &dy, c_out).expect("rulebook");
            let top = expected.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
            let diff = got.iter().zip(&expected).fold(0f32, |m, (p, q)| m.max((p - q).abs()));
            assert!(diff <= 1e-4 * top, "{:?}, {c_in} -> {c_out}: {diff} of {top}", a.kind());
        }
    }
}
