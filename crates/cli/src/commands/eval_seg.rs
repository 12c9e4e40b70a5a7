//! `semrecon eval seg`: how well a model segments labelled rooms. Every room of the data
//! sources (`synth:A..B`, `s3dis:PATH`, `scannet:PATH`, `ply:PATH`, as for training) is
//! voxelised at the model's voxel size without augmentation, segmented, and compared voxel by
//! voxel with the majority label of its points (voxels without a labelled point are not
//! counted). Prints the per-class IoU in the layout of the paper's Table 3 (classes as
//! columns, then mIoU and overall accuracy), and the mean time per room of the network call
//! (kernel maps included, loading the room left out). `--structure` and `--tta` refine the
//! labels as `semrecon segment` does (the time of the structure step is reported apart).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::SemanticClass;
use semrecon_net::dataset::{load_sample, rooms_of, DataSource};
use semrecon_net::ConfusionMatrix;
use serde::Serialize;

use crate::progress::progress_bar;

/// Arguments of `semrecon eval seg`.
#[derive(clap::Args)]
pub struct SegArgs {
    /// Model file (safetensors); default: the shipped model.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Configuration of a model file that does not store one (s20, s50, live or a file).
    #[arg(long)]
    config: Option<String>,
    /// Labelled rooms: synth:A..B[:styles], s3dis:PATH, scannet:PATH, ply:PATH (several allowed).
    #[arg(long, required = true, num_args = 1..)]
    data: Vec<String>,
    /// Also write the JSON report to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Seed of the surface sampling of meshes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[command(flatten)]
    structure: super::segment::StructureArgs,
}

/// The columns of the paper's Table 3, in its order.
const TABLE_ORDER: [SemanticClass; 13] = [
    SemanticClass::Ceiling,
    SemanticClass::Floor,
    SemanticClass::Wall,
    SemanticClass::Beam,
    SemanticClass::Column,
    SemanticClass::Window,
    SemanticClass::Door,
    SemanticClass::Table,
    SemanticClass::Chair,
    SemanticClass::Sofa,
    SemanticClass::Bookcase,
    SemanticClass::Board,
    SemanticClass::Clutter,
];

#[derive(Serialize)]
struct RoomRow {
    room: String,
    voxels: usize,
    ms: f64,
    structure_ms: f64,
    /// Of the structure step: neighbours and normals, planes, segments and vote.
    structure_ms_parts: [f64; 3],
    miou: f64,
    accuracy: f64,
    floor_z: Option<f32>,
    ceiling_z: Option<f32>,
    segments: usize,
    changed: usize,
}

#[derive(Serialize)]
struct SegReport {
    model: String,
    config: String,
    data: Vec<String>,
    /// Mean IoU over the classes present in the truth or the prediction, 0..1.
    miou: f64,
    /// Class name -> IoU (0..1), `null` for a class absent from both truth and prediction.
    per_class: serde_json::Map<String, serde_json::Value>,
    /// Overall voxel accuracy, 0..1.
    accuracy: f64,
    /// Mean milliseconds of the network call per room (kernel maps included; all `tta` passes).
    ms_per_room: f64,
    /// `--structure`.
    structure: String,
    /// `--tta`: views of test-time augmentation (1: off).
    tta: u32,
    /// `--tta-mean`: what was averaged over the views (probabilities or logits).
    tta_mean: String,
    /// Mean milliseconds of the structure step per room.
    structure_ms_per_room: f64,
    rooms: usize,
    voxels: usize,
    /// Voxel counts over all rooms, `confusion[truth][prediction]` in class-id order (the
    /// last column: predictions outside the classes): where each class's errors go.
    confusion: Vec<Vec<u64>>,
    per_room: Vec<RoomRow>,
}

/// Runs `semrecon eval seg`.
pub fn run(args: SegArgs) -> anyhow::Result<()> {
    let sources = args.data.iter().map(|s| DataSource::parse(s)).collect::<Result<Vec<_>, _>>()?;
    let rooms = rooms_of(&sources)?;
    anyhow::ensure!(!rooms.is_empty(), "the data sources {} hold no room", args.data.join(" "));
    let mut net = super::segment::load_model(args.model.as_deref(), args.config.as_deref())?;
    let model_name = args
        .model
        .as_ref()
        .map_or_else(|| semrecon_net::shipped::default_model_path().display().to_string(), |p| p.display().to_string());
    let voxel = net.config().voxel_size;
    let classes = net.config().classes;
    let mut total = ConfusionMatrix::new(classes);
    let mut per_room = Vec::new();
    let bar = progress_bar(rooms.len() as u64, "rooms");
    for room in &rooms {
        let sample = load_sample(room, voxel, None, args.seed).with_context(|| format!("loading {}", room.name))?;
        let t = Instant::now();
        let logits =
            net.segment(&sample.coords, &sample.features).with_context(|| format!("segmenting {}", room.name))?;
        let first_ms = t.elapsed().as_secs_f64() * 1e3;
        let (refinement, network_s, structure_s) =
            super::segment::voxel_labels(&mut net, &sample.coords, &sample.features, Some(logits), &args.structure)
                .with_context(|| format!("segmenting {}", room.name))?;
        let ms = first_ms + network_s * 1e3;
        let prediction = &refinement.labels;
        let mut m = ConfusionMatrix::new(classes);
        m.add(&sample.labels, prediction);
        total.merge(&m);
        per_room.push(RoomRow {
            room: room.name.clone(),
            voxels: sample.len(),
            ms,
            structure_ms: structure_s * 1e3,
            structure_ms_parts: [refinement.timing.normals, refinement.timing.planes, refinement.timing.segments]
                .map(|d| d.as_secs_f64() * 1e3),
            miou: m.miou(),
            accuracy: m.accuracy(),
            floor_z: refinement.floor_z,
            ceiling_z: refinement.ceiling_z,
            segments: refinement.segments,
            changed: refinement.changed,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();

    let iou = total.iou();
    let mut per_class = serde_json::Map::new();
    for class in SemanticClass::ALL {
        let v = iou.get(class.id() as usize).copied().flatten();
        per_class.insert(class.name().to_string(), v.map_or(serde_json::Value::Null, serde_json::Value::from));
    }
    let report = SegReport {
        model: model_name,
        config: net.config().summary(),
        data: args.data.clone(),
        miou: total.miou(),
        per_class,
        accuracy: total.accuracy(),
        ms_per_room: per_room.iter().map(|r| r.ms).sum::<f64>() / per_room.len() as f64,
        structure: args.structure.structure.to_string(),
        tta: args.structure.tta,
        tta_mean: args.structure.tta_mean.to_string(),
        structure_ms_per_room: per_room.iter().map(|r| r.structure_ms).sum::<f64>() / per_room.len() as f64,
        rooms: per_room.len(),
        voxels: per_room.iter().map(|r| r.voxels).sum(),
        confusion: (0..classes).map(|t| (0..=classes).map(|p| total.count(t, p)).collect()).collect(),
        per_room,
    };

    println!(
        "{} on {} rooms ({} voxels of {} cm) of {}; model {}",
        net.config().summary(),
        report.rooms,
        report.voxels,
        voxel * 100.0,
        args.data.join(" "),
        report.model
    );
    println!("per-class IoU % (voxels; - : class in neither truth nor prediction)");
    let mut head = String::new();
    let mut line = String::new();
    for class in TABLE_ORDER {
        head += &format!("{:>9}", class.name());
        line += &match iou.get(class.id() as usize).copied().flatten() {
            Some(v) => format!("{:>9.1}", 100.0 * v),
            None => format!("{:>9}", "-"),
        };
    }
    println!("{head}{:>9}{:>9}", "mIoU", "accuracy");
    println!("{line}{:>9.1}{:>9.1}", 100.0 * report.miou, 100.0 * report.accuracy);
    let part = |i: usize| report.per_room.iter().map(|r| r.structure_ms_parts[i]).sum::<f64>() / report.rooms as f64;
    println!(
        "mean time per room: {:.1} ms (network call, kernel maps included, tta {} {}), structure {}: {:.1} ms \
         (normals {:.1}, planes {:.1}, segments {:.1})",
        report.ms_per_room,
        report.tta,
        report.tta_mean,
        report.structure,
        report.structure_ms_per_room,
        part(0),
        part(1),
        part(2)
    );
    if let Some(path) = &args.json {
        write_atomic(path, serde_json::to_string_pretty(&report)?.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
