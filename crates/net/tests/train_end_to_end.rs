//! End to end training of a tiny CBSCN on two small synthetic rooms: the loss falls, the
//! output folder holds the documented files, and a resumed run continues where the first
//! stopped. Needs the `train` feature (burn).
#![cfg(feature = "train")]
#![allow(clippy::unwrap_used)]

use semrecon_net::dataset::{Augment, DataSource};
use semrecon_net::train::{train, TrainOptions, TrainState};
use semrecon_net::{NetConfig, Weights};

#[test]
fn tiny_training_learns_and_resumes() {
    let config = NetConfig::new("tiny", 3, 8, 0.1);
    let rooms = DataSource::parse("synth:1..3").unwrap().rooms().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut opts = TrainOptions::new(config.clone(), rooms.clone(), rooms[..1].to_vec(), dir.path().to_path_buf());
    opts.steps = 40;
    opts.batch = 1;
    opts.augment = Augment::none();
    opts.max_voxels = 3000;
    opts.lr = 5e-3;
    opts.warmup_steps = 0;
    opts.val_every_steps = 40;
    opts.checkpoint_every_steps = 20;
    let mut losses = Vec::new();
    let state = train(&opts, &mut |p| losses.push(p.loss)).unwrap();
    assert_eq!(state.step, 40);
    assert_eq!(losses.len(), 40);
    let first: f32 = losses[..5].iter().sum::<f32>() / 5.0;
    let last: f32 = losses[35..].iter().sum::<f32>() / 5.0;
    assert!(last < 0.8 * first, "loss did not fall: {first} -> {last}");
    for f in ["last.safetensors", "best.safetensors", "state.json", "adam.bin", "log.jsonl"] {
        assert!(dir.path().join(f).exists(), "{f} missing");
    }
    assert!(state.best_miou.is_some());
    let saved: TrainState =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("state.json")).unwrap()).unwrap();
    // serde_json does not promise exact float round trips: compare the counters exactly.
    assert_eq!((saved.step, saved.samples, saved.best_step), (state.step, state.samples, state.best_step));
    assert!((saved.elapsed_secs - state.elapsed_secs).abs() < 1e-9);
    Weights::load(&dir.path().join("best.safetensors"), &config).unwrap();

    opts.resume = true;
    opts.steps = 45;
    let mut steps = Vec::new();
    let resumed = train(&opts, &mut |p| steps.push(p.step)).unwrap();
    assert_eq!(steps, vec![41, 42, 43, 44, 45]);
    assert_eq!(resumed.step, 45);
    assert!(resumed.elapsed_secs >= state.elapsed_secs);

    // A checkpoint of another configuration is refused with a message naming both.
    opts.config = NetConfig::new("other", 3, 4, 0.1);
    let err = train(&opts, &mut |_| {}).unwrap_err().to_string();
    assert!(err.contains("last.safetensors") && err.contains("M=4"), "{err}");
}
