//! End-to-end tests of the network commands (`segment`, `eval seg`, `make-scans`, `bench
//! net`) with a tiny random-weight model, so that they run in seconds: what is checked is the
//! plumbing (files in and out, properties kept, errors), not the quality of the labels.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::Vec3;
use semrecon_data::ply::{mesh_to_ply, Column, PlyFile, Property, PropertyData};
use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_data::{LabeledMesh, PlyEncoding};
use semrecon_net::{NetConfig, Weights};

use common::{s, semrecon, stderr, stdout};

fn assert_clean_failure(o: &Output, needles: &[&str]) {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure, got success: {}", stdout(o));
    assert!(!err.contains("panicked"), "panic: {err}");
    for needle in needles {
        assert!(err.contains(needle), "error does not mention `{needle}`: {err}");
    }
}

fn tiny() -> NetConfig {
    NetConfig::new("tiny", 3, 4, 0.05)
}

/// A random-weight tiny model written to `dir/tiny.safetensors`.
fn tiny_model(dir: &Path) -> PathBuf {
    let path = dir.join("tiny.safetensors");
    let mut w = Weights::random(&tiny(), 7);
    w.perturb_normalisation(8);
    w.save(&path, &tiny()).expect("save model");
    path
}

/// Part of a generated room (the triangles within 2 m of the origin) as a PLY file with an
/// extra vertex property `quality` and the given position transform.
fn room_ply(path: &Path, transform: impl Fn(Vec3) -> Vec3, with_color: bool) -> LabeledMesh {
    let room = generate_room(&RoomConfig { seed: 4, style: None });
    let mut mesh = LabeledMesh::default();
    let mut map = vec![u32::MAX; room.mesh.positions.len()];
    for t in &room.mesh.triangles {
        if t.iter().all(|&i| room.mesh.positions[i as usize].truncate().length() < 2.0) {
            let tri = t.map(|i| {
                if map[i as usize] == u32::MAX {
                    map[i as usize] = mesh.positions.len() as u32;
                    mesh.positions.push(room.mesh.positions[i as usize]);
                    mesh.colors.push(room.mesh.colors[i as usize]);
                }
                map[i as usize]
            });
            mesh.triangles.push(tri);
        }
    }
    assert!(mesh.triangles.len() > 100, "{} triangles", mesh.triangles.len());
    let mut out = mesh.clone();
    out.positions.iter_mut().for_each(|p| *p = transform(*p));
    let mut ply = mesh_to_ply(&out).expect("ply");
    let vertex = ply.element_mut("vertex").expect("vertex");
    if !with_color {
        for c in ["red", "green", "blue"] {
            vertex.remove_property(c);
        }
    }
    let quality: Vec<f32> = (0..out.positions.len()).map(|i| i as f32 * 0.5).collect();
    vertex
        .set_property(Property { name: "quality".into(), data: PropertyData::Scalar(Column::Float(quality)) })
        .expect("quality");
    ply.write(path, PlyEncoding::BinaryLittleEndian).expect("write ply");
    mesh
}

fn labels_of(path: &Path) -> Vec<u8> {
    let ply = PlyFile::read(path).expect("read output");
    match ply.element("vertex").and_then(|v| v.scalar("label")) {
        Some(Column::UChar(l)) => l.clone(),
        other => panic!("no u8 label column: {other:?}"),
    }
}

#[test]
fn segment_labels_every_vertex_and_keeps_everything_else() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let input = dir.path().join("room.ply");
    let mesh = room_ply(&input, |p| p, true);
    let out = dir.path().join("labelled.ply");
    let o = semrecon(&["segment", "--input", s(&input), "--out", s(&out), "--model", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let labels = labels_of(&out);
    assert_eq!(labels.len(), mesh.positions.len());
    assert!(labels.iter().all(|&l| l < 13), "labels out of range");
    // Everything else is as it was.
    let (a, b) = (PlyFile::read(&input).expect("in"), PlyFile::read(&out).expect("out"));
    let (va, vb) = (a.element("vertex").expect("v"), b.element("vertex").expect("v"));
    for p in &va.properties {
        assert_eq!(Some(p), vb.property(&p.name), "property {} changed", p.name);
    }
    assert_eq!(a.element("face"), b.element("face"));

    // The same room given with y up, rotated back by --up y: the same labels, and the output
    // keeps the input's coordinates.
    let yup = dir.path().join("room_yup.ply");
    room_ply(&yup, |p| Vec3::new(p.x, p.z, -p.y), true);
    let out_yup = dir.path().join("labelled_yup.ply");
    let o = semrecon(&["segment", "--input", s(&yup), "--out", s(&out_yup), "--model", s(&model), "--up", "y"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(labels_of(&out_yup), labels);
    let rotated = PlyFile::read(&out_yup).expect("out");
    assert_eq!(
        rotated.element("vertex").and_then(|v| v.property("y")),
        PlyFile::read(&yup).expect("in").element("vertex").and_then(|v| v.property("y"))
    );

    // A file that records its up direction (as the meshes of `run`, `live` and `demo` do) is
    // turned by it without `--up`, as `--up X,Y,Z` turns one that does not; the output keeps
    // the comment. A tilted up, as 7-Scenes' frame has.
    let tilt = glam::Quat::from_rotation_arc(Vec3::Z, Vec3::new(0.1, 0.9, -0.4).normalize());
    let tilted = dir.path().join("room_tilted.ply");
    room_ply(&tilted, |p| tilt * p, true);
    let up = tilt * Vec3::Z;
    let mut recorded = PlyFile::read(&tilted).expect("tilted");
    recorded.comments.push(format!("semrecon up {} {} {}", up.x, up.y, up.z));
    let recorded_path = dir.path().join("room_recorded.ply");
    recorded.write(&recorded_path, PlyEncoding::BinaryLittleEndian).expect("write");
    let (out_given, out_recorded) = (dir.path().join("given.ply"), dir.path().join("recorded_out.ply"));
    let up_arg = format!("{},{},{}", up.x, up.y, up.z);
    let o =
        semrecon(&["segment", "--input", s(&tilted), "--out", s(&out_given), "--model", s(&model), "--up", &up_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = semrecon(&["segment", "--input", s(&recorded_path), "--out", s(&out_recorded), "--model", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("up: ") && stdout(&o).contains("recorded in"), "{}", stdout(&o));
    assert_eq!(labels_of(&out_recorded), labels_of(&out_given));
    let kept = PlyFile::read(&out_recorded).expect("out");
    assert!(kept.comments.iter().any(|c| c.starts_with("semrecon up ")), "{:?}", kept.comments);
    // Running again on the output replaces the label in place.
    let again = dir.path().join("again.ply");
    let o = semrecon(&["segment", "--input", s(&out), "--out", s(&again), "--model", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(PlyFile::read(&again).expect("again"), PlyFile::read(&out).expect("out"));
}

#[test]
fn segment_warns_without_colour_and_handles_empty_input() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let input = dir.path().join("grey.ply");
    let mesh = room_ply(&input, |p| p, false);
    let out = dir.path().join("grey_out.ply");
    let o = semrecon(&["segment", "--input", s(&input), "--out", s(&out), "--model", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("warning") && stderr(&o).contains("colour"), "{}", stderr(&o));
    assert_eq!(labels_of(&out).len(), mesh.positions.len());

    let empty = dir.path().join("empty.ply");
    std::fs::write(
        &empty,
        "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    )
    .expect("write");
    let out = dir.path().join("empty_out.ply");
    let o = semrecon(&["segment", "--input", s(&empty), "--out", s(&out), "--model", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(labels_of(&out).is_empty());
    let text = std::fs::read_to_string(&out).expect("ascii output");
    assert!(text.contains("element vertex 0") && text.contains("property uchar label"), "{text}");
}

#[test]
fn segment_rejects_bad_models_and_inputs_clearly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let input = dir.path().join("room.ply");
    room_ply(&input, |p| p, true);
    let out = dir.path().join("out.ply");
    let run = |model: &Path, extra: &[&str]| {
        let mut args = vec!["segment", "--input", s(&input), "--out", s(&out), "--model", s(model)];
        args.extend_from_slice(extra);
        semrecon(&args)
    };
    // Weights of another configuration.
    assert_clean_failure(&run(&model, &["--config", "s20"]), &["tiny.safetensors", "levels 3 vs 5", "width 4 vs 32"]);
    // A truncated file.
    let bytes = std::fs::read(&model).expect("model");
    let cut = dir.path().join("cut.safetensors");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("write");
    assert_clean_failure(&run(&cut, &[]), &["cut.safetensors", "truncated", &format!("describes {}", bytes.len())]);
    // No model anywhere.
    let o = Command::new(env!("CARGO_BIN_EXE_semrecon"))
        .args(["segment", "--input", s(&input), "--out", s(&out)])
        .env("SEMRECON_MODEL", dir.path().join("none.safetensors"))
        .output()
        .expect("run");
    assert_clean_failure(&o, &["no shipped model at", "none.safetensors", "semrecon train", "--model"]);
    // A bad up axis, a missing input.
    assert_clean_failure(&run(&model, &["--up", "w"]), &["expected one of x, y, z"]);
    let o = semrecon(&["segment", "--input", "/nonexistent.ply", "--out", s(&out), "--model", s(&model)]);
    assert_clean_failure(&o, &["/nonexistent.ply"]);
    assert!(!out.exists(), "no output on failure");
}

/// `make-scans` at a test's size (8 frames of 80x60, 5 cm voxels) with `extra` arguments.
fn tiny_scans(seeds: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args =
        vec!["make-scans", "--seeds", seeds, "--out", s(out), "--frames", "8", "--size", "80x60", "--voxel", "0.05"];
    args.extend_from_slice(extra);
    semrecon(&args)
}

/// A reconstruction of `make-scans`: a mesh whose vertices nearly all have a class.
fn assert_labelled_scan(path: &Path) {
    let mesh = semrecon_data::read_ply(path).expect("read scan");
    assert!(mesh.positions.len() > 100 && !mesh.triangles.is_empty(), "{}", mesh.positions.len());
    assert_eq!(mesh.vertex_labels.len(), mesh.positions.len());
    let labelled = mesh.vertex_labels.iter().filter(|&&l| l < 13).count();
    assert!(labelled > mesh.positions.len() * 9 / 10, "{labelled} of {}", mesh.positions.len());
}

#[test]
fn make_scans_writes_labelled_reconstructions() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("scans");
    let json = dir.path().join("rows.json");
    let o = tiny_scans("3..5", &out, &["--partial", "--json", s(&json)]);
    assert!(o.status.success(), "{}", stderr(&o));
    for seed in [3, 4] {
        let path = out.join(format!("room_{seed}.ply"));
        assert_labelled_scan(&path);
        let names: Vec<String> = PlyFile::read(&path)
            .expect("ply")
            .element("vertex")
            .expect("v")
            .properties
            .iter()
            .map(|p| p.name.clone())
            .collect();
        assert_eq!(names, ["x", "y", "z", "red", "green", "blue", "label"]);
    }
    let rows: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert_eq!(rows.as_array().map(Vec::len), Some(2));
    assert_eq!(rows[0]["frames_fused"], 2);
    assert_clean_failure(&semrecon(&["make-scans", "--seeds", "5..5", "--out", s(&out)]), &["range is empty"]);
}

#[test]
fn make_scans_library_scans_furnished_rooms_or_says_how_to_install() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("lib_scans");
    let o = tiny_scans("7", &out, &["--library"]);
    if !semrecon_data::library::default_dir().is_dir() {
        eprintln!("skipping the furnished scan: sweethome3d-furniture is not installed");
        assert_clean_failure(&o, &["sweethome3d-furniture"]);
        return;
    }
    assert!(o.status.success(), "{}", stderr(&o));
    assert_labelled_scan(&out.join("room_7.ply"));
    // A style belongs to the procedural rooms.
    assert_clean_failure(&tiny_scans("7", &out, &["--library", "--style", "office"]), &["--style"]);
}

#[test]
fn eval_seg_reports_the_table_and_json_keys() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let json = dir.path().join("seg.json");
    let o = semrecon(&["eval", "seg", "--model", s(&model), "--data", "synth:0..2", "--json", s(&json)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    let header = table.lines().find(|l| l.contains("ceiling")).expect("table header");
    let names: Vec<&str> = header.split_whitespace().collect();
    assert_eq!(
        names,
        [
            "ceiling", "floor", "wall", "beam", "column", "window", "door", "table", "chair", "sofa", "bookcase",
            "board", "clutter", "mIoU", "accuracy"
        ]
    );
    assert!(table.contains("ms"), "{table}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let miou = v["miou"].as_f64().expect("miou");
    let accuracy = v["accuracy"].as_f64().expect("accuracy");
    assert!((0.0..=1.0).contains(&miou) && (0.0..=1.0).contains(&accuracy), "{v}");
    assert!(v["ms_per_room"].as_f64().expect("ms") > 0.0);
    assert_eq!(v["rooms"], 2);
    let per_class = v["per_class"].as_object().expect("per_class");
    assert_eq!(per_class.len(), 13);
    assert!(per_class.values().all(|x| x.is_null() || x.as_f64().is_some_and(|f| (0.0..=1.0).contains(&f))));
    // Walls and floors exist in every room, so their IoU is defined.
    assert!(per_class["wall"].is_f64() && per_class["floor"].is_f64(), "{v}");
    // mIoU is the mean of the defined per-class values.
    let defined: Vec<f64> = per_class.values().filter_map(serde_json::Value::as_f64).collect();
    assert!((defined.iter().sum::<f64>() / defined.len() as f64 - miou).abs() < 1e-9);
    // The confusion matrix: 13 truth rows of 14 columns (the last: out of range), summing to
    // the labelled voxels, its diagonal to the accuracy.
    let confusion: Vec<Vec<u64>> = serde_json::from_value(v["confusion"].clone()).expect("confusion");
    assert_eq!(confusion.len(), 13);
    assert!(confusion.iter().all(|row| row.len() == 14));
    let counted: u64 = confusion.iter().flatten().sum();
    let right: u64 = (0..13).map(|i| confusion[i][i]).sum();
    assert!(counted > 0 && counted <= v["voxels"].as_u64().expect("voxels"), "{v}");
    assert!((right as f64 / counted as f64 - accuracy).abs() < 1e-9, "{v}");

    // The reconstructions of make-scans are valid evaluation data too.
    let scans = dir.path().join("scans");
    let o = semrecon(&[
        "make-scans",
        "--seeds",
        "1",
        "--out",
        s(&scans),
        "--frames",
        "6",
        "--size",
        "80x60",
        "--voxel",
        "0.05",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let data = format!("ply:{}", scans.display());
    let o = semrecon(&["eval", "seg", "--model", s(&model), "--data", &data, "synth:5..6"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("on 2 rooms"), "{}", stdout(&o));

    assert_clean_failure(&semrecon(&["eval", "seg", "--model", s(&model), "--data", "nope:1"]), &["nope:1"]);
    let cut = dir.path().join("cut.safetensors");
    std::fs::write(&cut, b"12345").expect("write");
    assert_clean_failure(&semrecon(&["eval", "seg", "--model", s(&cut), "--data", "synth:0..1"]), &["truncated"]);
}

/// `--tta` on both commands: 1 is the default output, 2, 4 and 8 run, anything else is a
/// clear error.
#[test]
fn tta_runs_on_segment_and_eval_seg_and_rejects_other_view_counts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let input = dir.path().join("room.ply");
    room_ply(&input, |p| p, true);
    let segment = |out: &Path, extra: &[&str]| {
        let mut args = vec!["segment", "--input", s(&input), "--out", s(out), "--model", s(&model)];
        args.extend_from_slice(extra);
        semrecon(&args)
    };
    let (plain, one, eight) = (dir.path().join("plain.ply"), dir.path().join("one.ply"), dir.path().join("eight.ply"));
    for (out, extra) in
        [(&plain, &[][..]), (&one, &["--tta", "1"][..]), (&eight, &["--tta", "8", "--tta-mean", "logits"])]
    {
        let o = segment(out, extra);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert_eq!(labels_of(&one), labels_of(&plain));
    assert_eq!(labels_of(&eight).len(), labels_of(&plain).len());
    assert_clean_failure(&segment(&one, &["--tta", "3"]), &["--tta", "1, 2, 4 or 8"]);

    let json = dir.path().join("tta.json");
    let o = semrecon(&["eval", "seg", "--model", s(&model), "--data", "synth:0..1", "--tta", "4", "--json", s(&json)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert_eq!((v["tta"].as_u64(), v["tta_mean"].as_str()), (Some(4), Some("probabilities")));
    let data = ["eval", "seg", "--model", s(&model), "--data", "synth:0..1", "--tta"];
    assert_clean_failure(&semrecon(&[&data[..], &["0"]].concat()), &["1, 2, 4 or 8"]);
    assert_clean_failure(&semrecon(&[&data[..], &["2", "--tta-mean", "max"]].concat()), &["probabilities or logits"]);
}

#[test]
fn bench_net_compares_the_kernels_and_exports_for_the_peer() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = dir.path().join("tiny.json");
    std::fs::write(&config, tiny().to_json()).expect("config");
    let (json, export) = (dir.path().join("net.json"), dir.path().join("export"));
    let o = semrecon(&[
        "bench",
        "net",
        "--config",
        s(&config),
        "--repeats",
        "1",
        "--json",
        s(&json),
        "--export",
        s(&export),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("chunked is"), "{}", stdout(&o));
    let rows: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert_eq!(rows[0]["kernel"], "chunked");
    assert_eq!(rows[1]["kernel"], "rulebook");
    for r in rows.as_array().expect("rows") {
        assert!(r["ms_per_room"].as_f64().expect("ms") > 0.0 && r["flops"].as_u64().expect("flops") > 0);
        assert!(r["voxels"].as_u64().expect("voxels") > 1000);
    }
    // The export: the model loads, the arrays have the sizes the header says.
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(export.join("net.json")).expect("header")).expect("header");
    let n = header["n"].as_u64().expect("n") as usize;
    let size = |key: &serde_json::Value| {
        std::fs::metadata(export.join(key.as_str().expect("name"))).expect("file").len() as usize
    };
    assert_eq!(size(&header["coords"]), n * 16);
    assert_eq!(size(&header["features"]), n * 12);
    assert_eq!(size(&header["logits"]), n * 13 * 4);
    assert_eq!(header["levels"].as_array().map(Vec::len), Some(3));
    assert_eq!(header["interp"].as_array().map(Vec::len), Some(1));
    let subm = &header["levels"][0]["subm"];
    let pairs = subm["offset_start"].as_array().expect("starts").last().expect("last");
    assert_eq!(size(&subm["in_rows"]), pairs.as_u64().expect("pairs") as usize * 4);
    Weights::load(&export.join("model.safetensors"), &tiny()).expect("exported model");
}

/// Issue 18's target on the one labelled real room, with the shipped model and the default
/// structure (segment vote and beam faces): accuracy at least 80 % and every class of the
/// room at least 50 % IoU. Skips when `../shared/data` is absent.
#[test]
fn the_real_s3dis_fragment_meets_its_target_with_the_shipped_model() {
    let Some(dir) = semrecon_data::shared_data::shared_data_path("s3dis-area1-conferenceRoom1-partial") else {
        eprintln!("skipping: the S3DIS fragment is not in ../shared/data");
        return;
    };
    let tmp = tempfile::tempdir().expect("tempdir");
    let json = tmp.path().join("fragment.json");
    let o = semrecon(&["eval", "seg", "--data", &format!("s3dis:{}", dir.display()), "--json", s(&json)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert!(v["accuracy"].as_f64().expect("accuracy") >= 0.8, "{v}");
    for class in ["wall", "beam", "door", "chair", "board", "clutter"] {
        let iou = v["per_class"][class].as_f64().unwrap_or(0.0);
        assert!(iou >= 0.5, "{class}: {iou} IoU ({})", v["per_class"]);
    }
}

#[test]
fn segment_writes_home_labels_with_a_home_head_and_says_when_the_model_has_none() {
    use semrecon_net::home_head::{HomeHead, OBJECTS};
    let dir = tempfile::tempdir().expect("tempdir");
    let model = tiny_model(dir.path());
    let input = dir.path().join("room.ply");
    let mesh = room_ply(&input, |p| p, true);
    let out = dir.path().join("home.ply");
    let o = semrecon(&["segment", "--input", s(&input), "--out", s(&out), "--model", s(&model), "--labels", "home"]);
    assert_clean_failure(&o, &["--labels home", "no home head"]);
    assert!(!out.exists(), "no output on failure");
    let o = semrecon(&["segment", "--input", s(&input), "--out", s(&out), "--model", s(&model), "--labels", "cats"]);
    assert_clean_failure(&o, &["expected s3dis or home"]);

    // The tiny model with a random home head.
    let inputs = HomeHead::input_width(tiny().channels(0), tiny().classes);
    let hidden = 5;
    let v = |n: usize, k: f32| (0..n).map(|i| ((i as f32 * k).sin()) * 0.5).collect::<Vec<f32>>();
    let head = HomeHead::new(
        inputs,
        hidden,
        v(inputs * hidden, 0.7),
        v(hidden, 1.3),
        v(hidden * OBJECTS, 0.9),
        v(OBJECTS, 2.1),
    )
    .expect("head");
    let mut w = Weights::load(&model, &tiny()).expect("load");
    for (name, t) in head.tensors() {
        w.tensors_mut().insert(name, t);
    }
    let with_head = dir.path().join("tiny_home.safetensors");
    w.save(&with_head, &tiny()).expect("save");
    let o =
        semrecon(&["segment", "--input", s(&input), "--out", s(&out), "--model", s(&with_head), "--labels", "home"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let labels = labels_of(&out);
    assert_eq!(labels.len(), mesh.positions.len());
    assert!(labels.iter().all(|&l| (l as usize) < semrecon_data::HomeClass::COUNT), "labels out of range");
    // The S3DIS labels of the same model are unchanged by the head it carries.
    let (a, b) = (dir.path().join("a.ply"), dir.path().join("b.ply"));
    assert!(semrecon(&["segment", "--input", s(&input), "--out", s(&a), "--model", s(&model)]).status.success());
    assert!(semrecon(&["segment", "--input", s(&input), "--out", s(&b), "--model", s(&with_head)]).status.success());
    assert_eq!(labels_of(&a), labels_of(&b));
    // snapshot draws them in the home colours.
    let png = dir.path().join("home.png");
    let o = semrecon(&["snapshot", s(&out), "--out", s(&png), "--classes", "--labels", "home", "--width", "160"]);
    assert!(o.status.success() && png.exists(), "{}", stderr(&o));
}
