//! Fits the home head (ScanNet's 20 classes and the ceiling, `semrecon_net::home_head`) on
//! the frozen shipped network, from homes and offices furnished with the furniture catalogues
//! (needs Debian's `sweethome3d-furniture`), and scores it on rooms of held-out models.
//!
//! ```text
//! cargo run --release -p semrecon-net --example train_home_head -- \
//!     [--train 0..400] [--val 100000..100060] [--stride 4] [--hidden 64] [--epochs 12] \
//!     [--model IN] [--out OUT] [--evaluate-only]
//! ```
//!
//! Training rooms are `synth-lib` seeds of the training models; validation rooms are other
//! seeds, once with the training models (rooms the head never saw) and once with the held-out
//! models (a whole catalogue and a tenth of the others: furniture the head never saw; it has
//! no beds, counters, curtains, toilets or sinks, so those are scored on the first set only). Each room's surface is sampled as for the S3DIS head's training, labelled with the
//! home classes of its models' fine categories, run through the network once, and every voxel
//! whose home label is an object class becomes a row (every `--stride`-th voxel). With `--out`, the weights of `--model`
//! (default the shipped s20) are written there with the head added (`f16`).
//!
//! `--evaluate-only` scores the head that `--model` carries without fitting one. Prints, for
//! the validation rooms, the pooled IoU per home class with the head and with
//! the S3DIS head's classes mapped alone (clutter as other furniture), and writes the same as
//! JSON beside `--out` (or to `home_head_eval.json`).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use semrecon_data::class::UNLABELED;
use semrecon_data::home_class::HomeClass;
use semrecon_data::library::rooms::{generate_library_room_detailed, LibraryRoomConfig};
use semrecon_data::library::{FurnitureLibrary, Split};
use semrecon_data::LabeledMesh;
use semrecon_net::dataset::points_per_m2;
use semrecon_net::home_head::{floor_level, head_inputs, object_index, shell_class, HomeHead};
use semrecon_net::home_head_training::{fit_home_head, FitConfig};
use semrecon_net::structure::{
    argmax_rows, refine, softmax_rows, BeamFaceParams, PlaneParams, SegmentParams, StructureConfig, StructureMode,
};
use semrecon_net::surface::sample_surface;
use semrecon_net::{shipped, Segmenter, Weights};

/// One room's voxels: head inputs, S3DIS prediction (the network's, and after the structure
/// step as `semrecon segment` runs it, with its segments) and home truth.
struct RoomVoxels {
    inputs: Vec<f32>,
    s3dis: Vec<u8>,
    refined: Vec<u8>,
    segment: Vec<u32>,
    truth: Vec<u8>,
}

fn parse_range(s: &str) -> Result<std::ops::Range<u64>, Box<dyn std::error::Error>> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("range A..B expected, got {s:?}"))?;
    Ok(a.parse()?..b.parse()?)
}

/// The room's mesh with every triangle labelled by the home class its corners agree on
/// (the most common of the three).
fn home_mesh(mesh: &LabeledMesh, home: &[u8]) -> LabeledMesh {
    let mut m = mesh.clone();
    m.vertex_labels = home.to_vec();
    m.triangle_labels = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| home[i as usize]);
            if b == c {
                b
            } else {
                a
            }
        })
        .collect();
    m
}

fn room_voxels(
    net: &mut Segmenter,
    lib: &FurnitureLibrary,
    seed: u64,
    split: Split,
    with_structure: bool,
) -> Result<RoomVoxels, Box<dyn std::error::Error>> {
    let config = LibraryRoomConfig { seed, kind: None, split };
    let room = generate_library_room_detailed(&config, lib)?;
    let voxel = net.config().voxel_size;
    let density = points_per_m2(voxel);
    let cloud = sample_surface(&room.room.mesh, density, seed);
    let truth_cloud = sample_surface(&home_mesh(&room.room.mesh, &room.home_labels), density, seed);
    assert_eq!(cloud.positions, truth_cloud.positions, "the same seed samples the same points");
    let points: Vec<[f32; 3]> = cloud.positions.iter().map(|p| p.to_array()).collect();
    let scores = net.segment_points_with_features(&points, &cloud.colors)?;
    let k = net.config().classes;
    let v = scores.coords.len();
    let s3dis = argmax_rows(&scores.logits, k);
    // Majority of the points' home labels per voxel (unscored points count as a label).
    let mut votes: Vec<BTreeMap<u8, u32>> = vec![BTreeMap::new(); v];
    for (p, &r) in scores.point_to_voxel.iter().enumerate() {
        *votes[r as usize].entry(truth_cloud.labels[p]).or_default() += 1;
    }
    let truth = votes
        .iter()
        .map(|m| m.iter().max_by_key(|(l, c)| (**c, std::cmp::Reverse(**l))).map_or(UNLABELED, |(l, _)| *l))
        .collect();
    let floor = floor_level(&scores.coords, &s3dis);
    let inputs = head_inputs(&scores.coords, &scores.head_features, &scores.logits, k, voxel, floor)?;
    let (refined, segment) = if with_structure {
        let mut probs = scores.logits.clone();
        softmax_rows(&mut probs, k);
        let config = StructureConfig {
            mode: StructureMode::Segments,
            segments: SegmentParams::default(),
            planes: PlaneParams::default(),
            beam_faces: Some(BeamFaceParams::default()),
        };
        let r = refine(&scores.coords, &scores.features, &probs, k, voxel, &config)?;
        (r.labels, r.segment)
    } else {
        (Vec::new(), Vec::new())
    };
    Ok(RoomVoxels { inputs, s3dis, refined, segment, truth })
}

/// Pooled confusion over the home classes: `[truth][prediction]`.
type Confusion = Vec<[u64; HomeClass::COUNT]>;

fn add(conf: &mut Confusion, truth: &[u8], pred: &[u8]) {
    for (&t, &p) in truth.iter().zip(pred) {
        if (t as usize) < HomeClass::COUNT && (p as usize) < HomeClass::COUNT {
            conf[t as usize][p as usize] += 1;
        }
    }
}

fn ious(conf: &Confusion) -> Vec<Option<f64>> {
    (0..HomeClass::COUNT)
        .map(|c| {
            let tp = conf[c][c];
            let fn_: u64 = conf[c].iter().sum::<u64>() - tp;
            let fp: u64 = (0..HomeClass::COUNT).map(|t| conf[t][c]).sum::<u64>() - tp;
            (conf[c].iter().sum::<u64>() > 0).then(|| tp as f64 / (tp + fn_ + fp).max(1) as f64)
        })
        .collect()
}

/// Prints the IoU table of one validation set, returns it as JSON.
fn print_table(name: &str, with_head: &Confusion, mapped: &Confusion) -> serde_json::Value {
    let (a, b) = (ious(with_head), ious(mapped));
    println!("\n{name}\n{:<16} {:>9} {:>9} {:>10}", "class", "head", "S3DIS", "voxels");
    let mut json = serde_json::Map::new();
    let (mut sum_a, mut sum_b, mut n) = (0.0, 0.0, 0);
    for c in HomeClass::ALL {
        let i = c.id() as usize;
        let count: u64 = with_head[i].iter().sum();
        let f = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{:.1}", v * 100.0));
        println!("{:<16} {:>9} {:>9} {:>10}", c.name(), f(a[i]), f(b[i]), count);
        if let (Some(x), Some(y)) = (a[i], b[i]) {
            if c != HomeClass::Ceiling {
                sum_a += x;
                sum_b += y;
                n += 1;
            }
        }
        json.insert(c.name().into(), serde_json::json!({"iou_head": a[i], "iou_s3dis_mapped": b[i], "voxels": count}));
    }
    let (ma, mb) = (sum_a / n.max(1) as f64, sum_b / n.max(1) as f64);
    println!(
        "mIoU over the {n} ScanNet classes present: head {:.1} %, S3DIS head mapped {:.1} %",
        ma * 100.0,
        mb * 100.0
    );
    serde_json::json!({"miou_head": ma, "miou_s3dis_mapped": mb, "scannet_classes_present": n, "classes": json})
}

/// Scores `head` on the validation rooms of both splits; writes the JSON beside `out`.
fn evaluate(
    net: &mut Segmenter,
    lib: &FurnitureLibrary,
    head: &HomeHead,
    val: std::ops::Range<u64>,
    out: Option<&std::path::Path>,
    info: serde_json::Value,
) -> Result<(), Box<dyn std::error::Error>> {
    let mut report = serde_json::Map::new();
    for (split, name) in [(Split::Train, "unseen_rooms_training_furniture"), (Split::HeldOut, "unseen_furniture")] {
        let mut with_head: Confusion = vec![[0; HomeClass::COUNT]; HomeClass::COUNT];
        let mut voted: Confusion = vec![[0; HomeClass::COUNT]; HomeClass::COUNT];
        let mut mapped: Confusion = vec![[0; HomeClass::COUNT]; HomeClass::COUNT];
        for seed in val.clone() {
            let r = room_voxels(net, lib, seed, split, true)?;
            let pred = head.home_labels(&r.inputs, &r.s3dis)?;
            add(&mut with_head, &r.truth, &pred);
            // What `semrecon segment --labels home` does: the structure step's S3DIS labels,
            // the head voted over its segments.
            let pred = head.home_labels_voted(&r.inputs, &r.refined, Some(&r.segment))?;
            add(&mut voted, &r.truth, &pred);
            let alone: Vec<u8> = r
                .refined
                .iter()
                .map(|&l| {
                    shell_class(l)
                        .or_else(|| semrecon_data::SemanticClass::from_id(l).and_then(HomeClass::from_s3dis))
                        .unwrap_or(HomeClass::OtherFurniture)
                        .id()
                })
                .collect();
            add(&mut mapped, &r.truth, &alone);
        }
        report.insert(name.into(), print_table(name, &with_head, &mapped));
        report.insert(
            format!("{name}_structure_and_vote"),
            print_table(&format!("{name}, structure step and segment vote"), &voted, &mapped),
        );
    }
    let mut summary = info;
    summary["val_seeds"] = serde_json::json!([val.start, val.end]);
    summary["sets"] = serde_json::Value::Object(report);
    let json_path = out.map_or(PathBuf::from("home_head_eval.json"), |o| o.with_extension("eval.json"));
    std::fs::write(&json_path, serde_json::to_string_pretty(&summary)?)?;
    eprintln!("wrote {}", json_path.display());

    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut train = 0..400u64;
    let mut val = 100_000..100_060u64;
    let mut fit = FitConfig::default();
    let mut model: Option<PathBuf> = None;
    let mut out: Option<PathBuf> = None;
    let mut stride = 4usize;
    let mut evaluate_only = false;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    while i < args.len() {
        if args[i] == "--evaluate-only" {
            evaluate_only = true;
            i += 1;
            continue;
        }
        let value = args.get(i + 1).ok_or_else(|| format!("{} needs a value", args[i]))?;
        match args[i].as_str() {
            "--train" => train = parse_range(value)?,
            "--val" => val = parse_range(value)?,
            "--hidden" => fit.hidden = value.parse()?,
            "--epochs" => fit.epochs = value.parse()?,
            "--model" => model = Some(value.into()),
            "--out" => out = Some(value.into()),
            "--stride" => stride = value.parse::<usize>()?.max(1),
            other => return Err(format!("unknown argument {other}").into()),
        }
        i += 2;
    }
    let model_path = model.unwrap_or_else(shipped::default_model_path);
    let mut net = shipped::load(&model_path, None)?;
    let lib = FurnitureLibrary::open_default()?;
    if evaluate_only {
        let head = net.home_head().cloned().ok_or("--evaluate-only: the model has no home head")?;
        return evaluate(
            &mut net,
            &lib,
            &head,
            val,
            None,
            serde_json::json!({"model": model_path.display().to_string()}),
        );
    }
    let t = Instant::now();
    let mut rows = Vec::new();
    let mut targets = Vec::new();
    for seed in train.clone() {
        let r = room_voxels(&mut net, &lib, seed, Split::Train, false)?;
        let w = r.inputs.len() / r.truth.len().max(1);
        for (v, &l) in r.truth.iter().enumerate().step_by(stride) {
            if let Some(o) = object_index(l) {
                rows.extend_from_slice(&r.inputs[v * w..(v + 1) * w]);
                targets.push(o as u8);
            }
        }
        if seed % 25 == 0 {
            eprintln!("room {seed}: {} rows so far, {:.0} s", targets.len(), t.elapsed().as_secs_f64());
        }
    }
    let width = HomeHead::input_width(net.config().channels(0), net.config().classes);
    eprintln!(
        "{} rows of {width} inputs from {} rooms in {:.0} s",
        targets.len(),
        train.end - train.start,
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let head = fit_home_head(&rows, &targets, width, &fit)?;
    eprintln!("fitted in {:.1} s", t.elapsed().as_secs_f64());
    let head = {
        // Evaluate what will be shipped: the f16-rounded head.
        let w = Weights::from_tensors(head.tensors().into_iter().collect()).rounded_to_f16();
        HomeHead::from_weights(&w)?.ok_or("no head")?
    };

    let info = serde_json::json!({
        "train_seeds": [train.start, train.end], "rows": targets.len(), "row_stride": stride,
        "hidden": fit.hidden, "epochs": fit.epochs,
    });
    evaluate(&mut net, &lib, &head, val, out.as_deref(), info)?;

    if let Some(out) = out {
        let config = Weights::read_config(&model_path)?.ok_or("the model file stores no configuration")?;
        let mut weights = Weights::load(&model_path, &config)?;
        for (name, tensor) in head.tensors() {
            weights.tensors_mut().insert(name, tensor);
        }
        weights.save(&out, &config)?;
        eprintln!("wrote {} (the network of {} with the home head)", out.display(), model_path.display());
    }
    Ok(())
}
