//! The shared backend suites of crates/sparse (host-slice and resident-tensor interfaces) on
//! the GPU engine, both algorithms. Without a
//! GPU adapter (or without the `gpu` feature) every test prints why and passes as skipped.

mod chunked {
    semrecon_sparse::backend_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Chunked));
}

mod rulebook {
    semrecon_sparse::backend_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Rulebook));
}

mod resident_chunked {
    semrecon_sparse::resident_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Chunked));
}

mod resident_rulebook {
    semrecon_sparse::resident_test_suite!(semrecon_gpu::test_engine(semrecon_sparse::ConvAlgorithm::Rulebook));
}
