//! The GPU engine's tests that open a device, in one test binary: each links the whole of
//! wgpu, so one binary instead of five saves four long links in every build of the `gpu`
//! feature, and a GPU bundle (bench/gpu_bundle.sh) carries one binary instead of five.
//! Without a GPU adapter (or without the `gpu` feature) every test prints why and passes as
//! skipped. No adapter at all is tests/no_adapter.rs, its own process.

mod errors;
mod hierarchy;
mod recording;
mod suite;
mod tiles;
