//! Recording many small operations (crates/gpu/src/record.rs): thousands of dispatches between
//! read-backs fill several pages of kernel parameters, go to the device in batches, and the
//! pages are reused after a read-back; every dispatch must still run with its own parameters.

#![cfg(feature = "gpu")]

use semrecon_sparse::{ConvAlgorithm, ResidentBackend};

/// Rows of the tensor the operations add to.
const ROWS: usize = 64;
/// Operations per round (a page holds at most 4,096 parameter slots).
const OPS: usize = 5_000;

/// The rows operation `i` adds to: a different count (and so different parameters) each time.
fn rows_of(i: usize) -> usize {
    1 + (i * 7) % ROWS
}

#[test]
fn thousands_of_dispatches_between_read_backs_each_see_their_own_parameters() {
    let Some(gpu) = semrecon_gpu::test_engine(ConvAlgorithm::Chunked) else { return };
    let mut y = gpu.upload(&[0.0; ROWS]).expect("upload");
    let one = gpu.upload(&[1.0]).expect("upload");
    let mut expected = [0f32; ROWS];
    for round in 0..2 {
        for i in 0..OPS {
            let rows = rows_of(i + round * OPS);
            gpu.add_bias(&mut y, rows, &one, 1).expect("add_bias");
            if i == 4 {
                // A submission without a read-back: later batches end inside pages, not at
                // their boundaries (a page then holds words of work not yet submitted).
                gpu.context().flush().expect("flush");
            }
            for e in &mut expected[..rows] {
                *e += 1.0;
            }
        }
        // Counts below 2^24: exact in f32, whatever the order of the additions.
        assert_eq!(gpu.download(&y, ROWS).expect("download"), expected, "round {round}");
    }
}
