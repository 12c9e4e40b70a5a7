//! The shared backend suite of crates/sparse on the GPU engine, both algorithms. Without a
//! GPU adapter (or without the `gpu` feature) every test prints why and passes as skipped.

mod chunked {
    semrecon_sparse::backend_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Chunked));
}

mod rulebook {
    semrecon_sparse::backend_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Rulebook));
}
