//! One module per subcommand: argument parsing (clap derive) and the code that runs it.

pub mod ar;
pub mod bench;
pub mod bench_net;
pub mod calibrate_depth;
pub mod demo;
pub mod eval;
pub mod eval_seg;
pub mod info;
pub mod live;
pub mod make_scans;
pub mod run;
pub mod segment;
pub mod snapshot;
pub mod synth;
pub mod throw;
pub mod train;
pub mod view;
