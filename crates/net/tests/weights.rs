//! Weight files: f16 round trip, and clear errors for truncated or mismatched files.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;

use safetensors::tensor::{Dtype, TensorView};
use semrecon_net::{NetConfig, NetError, Weights};

fn config() -> NetConfig {
    NetConfig::new("small", 3, 4, 0.05)
}

#[test]
fn round_trip_stores_f16_values() {
    let cfg = config();
    let mut w = Weights::random(&cfg, 3);
    w.perturb_normalisation(4);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    w.save(&path, &cfg).unwrap();
    let back = Weights::load(&path, &cfg).unwrap();
    let rounded = w.rounded_to_f16();
    assert_eq!(back.tensors(), rounded.tensors());
    assert_ne!(rounded.tensors(), w.tensors());
    assert_eq!(Weights::read_config(&path).unwrap(), Some(cfg.clone()));
    // f16 halves the file: 2 bytes per value plus a header.
    let values: usize = w.tensors().values().map(|t| t.data.len()).sum();
    let size = std::fs::metadata(&path).unwrap().len() as usize;
    assert!(size < values * 2 + 20_000, "{size} bytes for {values} values");
    assert!(!dir.path().read_dir().unwrap().any(|e| e.unwrap().file_name().to_string_lossy().contains("tmp")));
}

#[test]
fn truncated_and_mismatched_files_are_named_errors() {
    let cfg = config();
    let w = Weights::random(&cfg, 3);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    w.save(&path, &cfg).unwrap();
    let bytes = std::fs::read(&path).unwrap();

    let cut = dir.path().join("cut.safetensors");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let e = Weights::load(&cut, &cfg).unwrap_err();
    assert!(matches!(e, NetError::WeightFile { .. }), "{e}");
    assert!(e.to_string().contains("cut.safetensors"), "{e}");
    std::fs::write(&cut, &bytes[..5]).unwrap();
    assert!(Weights::load(&cut, &cfg).unwrap_err().to_string().contains("cut.safetensors"));

    let other = NetConfig::new("big", 4, 4, 0.05);
    let e = Weights::load(&path, &other).unwrap_err();
    assert!(matches!(e, NetError::ConfigMismatch { .. }), "{e}");
    assert!(e.to_string().contains("L=3") && e.to_string().contains("L=4"), "{e}");
    assert!(Weights::load(&dir.path().join("none"), &cfg).is_err());

    // Hand-made files without the stored configuration.
    let write = |name: &str, tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>| {
        let p = dir.path().join(name);
        let views: Vec<(String, TensorView)> =
            tensors.iter().map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap())).collect();
        let data = safetensors::tensor::serialize(views, None::<HashMap<String, String>>).unwrap();
        std::fs::write(&p, data).unwrap();
        p
    };
    let as_f32 = |skip: &str, shape_of: &str, dtype_of: &str| {
        w.tensors()
            .iter()
            .filter(|(n, _)| n.as_str() != skip)
            .map(|(n, t)| {
                let mut shape = t.shape.clone();
                let mut bytes: Vec<u8> = t.data.iter().flat_map(|v| v.to_le_bytes()).collect();
                let mut dtype = Dtype::F32;
                if n == shape_of {
                    shape = vec![t.data.len()];
                }
                if n == dtype_of {
                    dtype = Dtype::I32;
                    bytes = vec![0; t.data.len() * 4];
                }
                (n.clone(), dtype, shape, bytes)
            })
            .collect::<Vec<_>>()
    };
    let p = write("f32.safetensors", as_f32("", "", ""));
    assert_eq!(Weights::load(&p, &cfg).unwrap().tensors(), w.tensors());
    let p = write("missing.safetensors", as_f32("extract.1.conv2.weight", "", ""));
    let e = Weights::load(&p, &cfg).unwrap_err().to_string();
    assert!(e.contains("missing.safetensors") && e.contains("extract.1.conv2.weight") && e.contains("missing"), "{e}");
    let p = write("shape.safetensors", as_f32("", "up.0.skip.weight", ""));
    let e = Weights::load(&p, &cfg).unwrap_err().to_string();
    assert!(e.contains("shape.safetensors") && e.contains("up.0.skip.weight") && e.contains("[4, 4]"), "{e}");
    let p = write("dtype.safetensors", as_f32("", "", "head.linear.bias"));
    let e = Weights::load(&p, &cfg).unwrap_err().to_string();
    assert!(e.contains("dtype.safetensors") && e.contains("head.linear.bias") && e.contains("I32"), "{e}");
    let mut extra = as_f32("", "", "");
    extra.push(("stray".into(), Dtype::F32, vec![1], vec![0; 4]));
    let p = write("extra.safetensors", extra);
    let e = Weights::load(&p, &cfg).unwrap_err().to_string();
    assert!(e.contains("stray"), "{e}");
}
