//! The furniture catalogue reader against Debian's installed `sweethome3d-furniture` (tests
//! that need it print a message and pass when it is absent) and against small archives
//! written here (which always run).

use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use semrecon_data::library::{class_table, FurnitureLibrary, LibraryModel, Split, DEFAULT_FURNITURE_DIR};
use semrecon_data::{LabeledMesh, SemanticClass};

/// The installed library, or `None` (with a message) when the package is absent.
fn installed() -> Option<FurnitureLibrary> {
    let dir = semrecon_data::library::default_dir();
    if !dir.is_dir() {
        eprintln!("skipping: {} absent (apt-get install sweethome3d-furniture)", dir.display());
        return None;
    }
    Some(FurnitureLibrary::open(&dir).expect("the installed catalogues open"))
}

fn model<'a>(lib: &'a FurnitureLibrary, id: &str) -> &'a LibraryModel {
    lib.model(id).unwrap_or_else(|| panic!("model {id} is not in the library"))
}

fn assert_size(mesh: &LabeledMesh, size_cm: [f32; 3], what: &str) {
    let (lo, hi) = mesh.bounds().expect("non-empty mesh");
    assert!(lo.abs().max_element() < 1e-3, "{what}: bounds start at {lo}, not 0");
    let want = Vec3::from(size_cm) / 100.0;
    assert!((hi - want).abs().max_element() < 1e-3, "{what}: size {hi} m, catalogue says {want} m");
}

/// "The mapping test": every model of every installed catalogue has exactly one row in
/// `crates/data/furniture_classes.tsv`, and every row of an installed catalogue names a model.
#[test]
fn class_table_maps_every_model_exactly_once() {
    let Some(lib) = installed() else { return };
    let table = class_table().expect("the class table parses");
    let mut rows: HashMap<(&str, &str), usize> = HashMap::new();
    for r in table {
        *rows.entry((r.catalogue.as_str(), r.id.as_str())).or_default() += 1;
    }
    let duplicates: Vec<_> = rows.iter().filter(|(_, &n)| n > 1).map(|(k, _)| k).collect();
    assert!(duplicates.is_empty(), "rows repeated in the class table: {duplicates:?}");
    let mut models: HashSet<(&str, &str)> = HashSet::new();
    let mut missing = Vec::new();
    for cat in &lib.catalogues {
        for e in &cat.entries {
            models.insert((cat.stem.as_str(), e.id.as_str()));
            if !rows.contains_key(&(cat.stem.as_str(), e.id.as_str())) {
                missing.push(format!("{}\t{}\t{}", cat.stem, e.id, e.name));
            }
        }
    }
    assert!(missing.is_empty(), "{} models without a row in the class table:\n{}", missing.len(), missing.join("\n"));
    let installed: HashSet<&str> = lib.catalogues.iter().map(|c| c.stem.as_str()).collect();
    let stale: Vec<_> = rows.keys().filter(|(c, _)| installed.contains(c)).filter(|k| !models.contains(*k)).collect();
    assert!(stale.is_empty(), "rows naming no installed model: {stale:?}");
    for c in ["BlendSwap-CC-0", "BlendSwap-CC-BY", "KatorLegaz", "Reallusion", "Scopia"] {
        if !installed.contains(c) {
            eprintln!("note: catalogue {c} is not installed; its rows are not checked");
        }
    }
    assert!(lib.warnings.is_empty(), "warnings: {:?}", lib.warnings);
}

#[test]
fn class_table_values_are_valid_and_a_catalogue_is_held_out() {
    let table = class_table().expect("the class table parses (class names, use, split)");
    assert!(table.len() >= 820, "{} rows", table.len());
    for r in table {
        assert!(
            !r.fine.is_empty() && r.fine.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'),
            "fine category {:?} of {} is not snake_case",
            r.fine,
            r.id
        );
        assert!(SemanticClass::from_name(r.class.name()).is_some());
        if r.catalogue == "Reallusion" {
            assert!(!r.used, "{}: people are not furniture", r.id);
        }
    }
    let kator: Vec<_> = table.iter().filter(|r| r.catalogue == "KatorLegaz").collect();
    assert!(!kator.is_empty() && kator.iter().all(|r| r.split == Split::HeldOut), "KatorLegaz is held out whole");
    // Elsewhere about a tenth of the used models is held out, and every class present in
    // training keeps most of its models there.
    let others: Vec<_> = table.iter().filter(|r| r.catalogue != "KatorLegaz" && r.used).collect();
    let held = others.iter().filter(|r| r.split == Split::HeldOut).count();
    let share = held as f64 / others.len() as f64;
    assert!((0.05..=0.15).contains(&share), "{held} of {} held out", others.len());
    let mut by_fine: HashMap<&str, (usize, usize)> = HashMap::new();
    for r in &others {
        let e = by_fine.entry(r.fine.as_str()).or_default();
        e.0 += 1;
        e.1 += (r.split == Split::Train) as usize;
    }
    for (fine, (n, train)) in by_fine {
        if n >= 3 {
            assert!(train * 3 >= n * 2, "{fine}: only {train} of {n} models in train");
        }
    }
}

#[test]
fn models_have_metadata_in_metres() {
    let Some(lib) = installed() else { return };
    assert!(lib.models.len() > 400, "{} used models", lib.models.len());
    let bed = model(&lib, "Blend Swap CC-0#bed1");
    assert_eq!(bed.name, "Bed");
    assert_eq!(bed.category, "Bedroom");
    assert_eq!(bed.fine, "bed");
    assert_eq!(bed.class, SemanticClass::Clutter.id());
    assert!((bed.size - Vec3::new(1.407, 2.08, 0.955)).abs().max_element() < 1e-6);
    assert_eq!(bed.catalogue, "BlendSwap-CC-0");
    assert_eq!(bed.creator, "Blend Swap");
    assert_eq!(model(&lib, "Blend Swap CC-0#desk").class, SemanticClass::Table.id());
    assert_eq!(model(&lib, "Blend Swap CC-0#whiteBoard").class, SemanticClass::Board.id());
    assert_eq!(model(&lib, "Blend Swap CC-0#bookcase").class, SemanticClass::Bookcase.id());
    let door = model(&lib, "Scopia#door");
    assert!(door.door_or_window && door.class == SemanticClass::Door.id());
    // Models come in catalogue file order, then properties order.
    assert_eq!(lib.models[0].id, "Blend Swap CC-0#armchair");
    assert!(lib.models.iter().all(|m| m.size.min_element() > 0.0 && m.elevation >= 0.0));
    // Not furniture: never listed.
    assert!(lib.model("Reallusion#female01").is_none());
    assert!(lib.model("Scopia#acacia").is_none());
    // Scopia's properties carry Latin-1 and \u escapes.
    assert_eq!(lib.entry("Scopia#frame2").map(|e| e.name.as_str()), Some("Frame H\u{f4}i An"));
}

#[test]
fn meshes_have_the_catalogue_size() {
    let Some(lib) = installed() else { return };
    for (id, size) in [
        ("Blend Swap CC-0#bed1", [140.7, 208.0, 95.5]),
        ("Blend Swap CC-0#armchair", [59.4, 62.7, 105.0]),
        // modelRotation (a quarter turn about y) applied before sizing:
        ("Scopia#beige_sofa_2seats", [158.86, 73.5, 86.6]),
        ("Scopia#chair", [42.0, 47.4, 88.0]),
        ("Scopia#door", [96.0, 17.5, 210.0]),
    ] {
        let mesh = lib.load_mesh(model(&lib, id)).expect("loads");
        assert_size(&mesh, size, id);
    }
}

/// Chairs and sofas have their backrest at the back: the front (-y) part of the model is
/// lower than the back part. This holds for nearly all of them and fails for nearly all if
/// the depth axis were flipped.
#[test]
fn fronts_face_minus_y() {
    let Some(lib) = installed() else { return };
    let seats: Vec<&LibraryModel> = lib
        .models
        .iter()
        .filter(|m| {
            (m.class == SemanticClass::Sofa.id() || m.class == SemanticClass::Chair.id())
                && !["stool", "beanbag", "bench", "lounge_chair"].contains(&m.fine.as_str())
        })
        .collect();
    let mut wrong = Vec::new();
    for m in &seats {
        let mesh = lib.load_mesh(m).expect("loads");
        let top = |lo: f32, hi: f32| {
            mesh.positions
                .iter()
                .filter(|p| p.y >= lo * m.size.y && p.y <= hi * m.size.y)
                .map(|p| p.z)
                .fold(0.0f32, f32::max)
        };
        let (front, back) = (top(0.0, 0.25), top(0.75, 1.0));
        if front >= back {
            wrong.push(format!("{} ({}): front top {front:.2} m, back top {back:.2} m", m.id, m.name));
        }
    }
    eprintln!(
        "{} of {} seats with a lower front; the others:\n{}",
        seats.len() - wrong.len(),
        seats.len(),
        wrong.join("\n")
    );
    assert!(wrong.len() * 10 <= seats.len(), "seats facing the wrong way:\n{}", wrong.join("\n"));
    for id in ["Blend Swap CC-0#couch", "Scopia#beige_sofa_2seats", "Scopia#chair", "Blend Swap CC-BY#sofa3"] {
        assert!(!wrong.iter().any(|w| w.starts_with(id)), "{id} faces the wrong way");
    }
}

fn check_labels(m: &LibraryModel, mesh: &LabeledMesh) {
    mesh.validate().unwrap_or_else(|e| panic!("{}: {e}", m.id));
    assert!(mesh.triangle_count() > 0, "{}: no triangle", m.id);
    assert_eq!(mesh.triangle_labels.len(), mesh.triangle_count());
    assert_eq!(mesh.vertex_labels.len(), mesh.vertex_count());
    assert_eq!(mesh.normals.len(), mesh.vertex_count());
    assert!(mesh.triangle_labels.iter().chain(&mesh.vertex_labels).all(|&l| l == m.class), "{}: labels", m.id);
    let (lo, hi) = mesh.bounds().expect("non-empty");
    assert!(lo.min_element() > -1e-3 && (hi - m.size).max_element() < 1e-3, "{}: bounds {lo} {hi}", m.id);
}

#[test]
fn meshes_are_labelled_and_valid() {
    let Some(lib) = installed() else { return };
    // One model in seven keeps this quick; the ignored test below loads them all.
    for m in lib.models.iter().step_by(7) {
        let mesh = lib.load_mesh(m).unwrap_or_else(|e| panic!("{e}"));
        check_labels(m, &mesh);
    }
    // Cached: the same Arc comes back.
    let m = &lib.models[0];
    assert!(std::sync::Arc::ptr_eq(&lib.load_mesh(m).expect("loads"), &lib.load_mesh(m).expect("loads")));
}

/// Loads every used model (4-9 s on 2 cores in release) and prints the numbers: run with
/// `cargo test --release -p semrecon-data --test library -- --ignored --nocapture`.
#[test]
#[ignore]
fn every_used_model_loads() {
    use rayon::prelude::*;
    let t = Instant::now();
    let Some(lib) = installed() else { return };
    eprintln!("opening the catalogues: {:.3} s", t.elapsed().as_secs_f64());
    let t = Instant::now();
    let loaded: Vec<_> = lib.models.par_iter().map(|m| (m, lib.load_mesh(m))).collect();
    eprintln!("loading {} models: {:.1} s", loaded.len(), t.elapsed().as_secs_f64());
    let mut per_class: HashMap<&str, (usize, usize)> = HashMap::new();
    let (mut tris, mut failed) = (0, Vec::new());
    for (m, r) in &loaded {
        match r {
            Ok(mesh) => {
                check_labels(m, mesh);
                tris += mesh.triangle_count();
                let name = SemanticClass::from_id(m.class).map_or("?", |c| c.name());
                let e = per_class.entry(name).or_default();
                e.0 += 1;
                e.1 += (m.split == Split::Train) as usize;
            }
            Err(e) => failed.push(e.to_string()),
        }
    }
    let mut classes: Vec<_> = per_class.into_iter().collect();
    classes.sort();
    eprintln!("{tris} triangles; models per class (all, train): {classes:?}");
    assert!(failed.is_empty(), "models that failed to load:\n{}", failed.join("\n"));
}

#[test]
fn a_corrupt_archive_is_skipped_with_a_warning() {
    let good = Path::new(DEFAULT_FURNITURE_DIR).join("BlendSwap-CC-0.sh3f");
    if !good.is_file() {
        eprintln!("skipping: {} absent (apt-get install sweethome3d-furniture)", good.display());
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    std::os::unix::fs::symlink(&good, dir.path().join("BlendSwap-CC-0.sh3f")).expect("symlink");
    std::fs::write(dir.path().join("Broken.sh3f"), b"this is not a zip archive at all").expect("write");
    let lib = FurnitureLibrary::open(dir.path()).expect("the good catalogue opens");
    assert_eq!(lib.catalogues.len(), 1);
    assert!(!lib.models.is_empty());
    assert!(lib.warnings.iter().any(|w| w.contains("Broken.sh3f")), "{:?}", lib.warnings);
}

#[test]
fn a_missing_folder_says_how_to_install_the_package() {
    let err = FurnitureLibrary::open(Path::new("/nonexistent/furniture")).expect_err("no such folder");
    let msg = err.to_string();
    assert!(msg.contains("apt-get install sweethome3d-furniture"), "{msg}");
    assert!(msg.contains("SEMRECON_FURNITURE_DIR"), "{msg}");
    let empty = tempfile::tempdir().expect("temp dir");
    let msg = FurnitureLibrary::open(empty.path()).expect_err("no catalogue").to_string();
    assert!(msg.contains("apt-get install sweethome3d-furniture"), "{msg}");
}

// ---- A small catalogue written here: independent of the package. ----

/// A unit cube whose +z face (Sweet Home 3D's front) has Kd red and a green texture, every
/// other face white, and a fin at the back (z = 0) reaching up to y = 2: a model 1 wide,
/// 2 high and 1 deep in OBJ units, sized here to 200 x 50 x 100 cm.
const CUBE_OBJ: &str = "mtllib cube.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
v 0 2 0
v 1 2 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
g front
usemtl front
f 5/1 6/2 7/3 8/4
g rest
usemtl white
f 1 4 3 2
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
f 4 9 10 3
";

const CUBE_MTL: &str = "newmtl front
Kd 1 0 0
map_Kd tex.png
newmtl white
Kd 1 1 1
";

fn write_catalogue(dir: &Path) -> PathBuf {
    let path = dir.join("Test.sh3f");
    let file = std::fs::File::create(&path).expect("create");
    let mut zip = zip::ZipWriter::new(file);
    let opts = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
    let props = "# test catalogue\nid=Test\nlicense=CC-0\n\
        id#1=Test#cube\nname#1=Cube \\u00e9\ncategory#1=Test\nmodel#1=/test/cube/cube.obj\n\
        width#1=200\ndepth#1=50\nheight#1=100\ncreator#1=Me\n\
        id#2=Test#broken\nname#2=Broken\nmodel#2=/test/broken/broken.obj\nwidth#2=10\ndepth#2=10\nheight#2=10\n\
        id#3=Test#missing\nname#3=Missing\nmodel#3=/test/missing/missing.obj\nwidth#3=10\ndepth#3=10\nheight#3=10\n";
    let mut png = Vec::new();
    // A 2x2 green texture.
    image::RgbImage::from_pixel(2, 2, image::Rgb([0, 200, 0]))
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("png");
    for (name, bytes) in [
        ("PluginFurnitureCatalog.properties", props.as_bytes()),
        ("test/cube/cube.obj", CUBE_OBJ.as_bytes()),
        ("test/cube/cube.mtl", CUBE_MTL.as_bytes()),
        ("test/cube/tex.png", png.as_slice()),
        ("test/broken/broken.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n".as_slice()),
    ] {
        zip.start_file(name, opts).expect("start");
        zip.write_all(bytes).expect("write");
    }
    zip.finish().expect("finish");
    path
}

fn test_model(lib: &FurnitureLibrary, id: &str) -> LibraryModel {
    let e = lib.entry(id).expect("entry");
    LibraryModel {
        catalogue: e.catalogue.clone(),
        id: e.id.clone(),
        name: e.name.clone(),
        category: e.category.clone(),
        fine: "test".into(),
        class: SemanticClass::Table.id(),
        size: e.size,
        elevation: e.elevation,
        door_or_window: e.door_or_window,
        creator: e.creator.clone(),
        split: Split::Train,
    }
}

#[test]
fn a_written_model_is_rotated_scaled_coloured_and_subdivided() {
    let dir = tempfile::tempdir().expect("temp dir");
    write_catalogue(dir.path());
    let lib = FurnitureLibrary::open(dir.path()).expect("opens");
    // The test models have no row in the class table: listed in entries, not in models.
    assert!(lib.models.is_empty());
    assert_eq!(lib.warnings.len(), 3, "{:?}", lib.warnings);
    assert_eq!(lib.catalogues[0].license, "CC-0");
    let cube = test_model(&lib, "Test#cube");
    assert_eq!(cube.name, "Cube \u{e9}");
    let mesh = lib.load_mesh(&cube).expect("loads");
    mesh.validate().expect("valid");
    assert_size(&mesh, [200.0, 50.0, 100.0], "cube");
    assert!(mesh.triangle_labels.iter().all(|&l| l == SemanticClass::Table.id()));
    // Subdivided: no edge longer than 10 cm.
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        assert!((a - b).length().max((b - c).length()).max((c - a).length()) <= 0.1 + 1e-5);
    }
    // OBJ +z (the textured green face) is our y = 0 side; the wedge (OBJ y up to 2) is at the top.
    let front: Vec<usize> = (0..mesh.vertex_count()).filter(|&i| mesh.positions[i].y < 1e-4).collect();
    assert!(!front.is_empty());
    let greens = front.iter().filter(|&&i| mesh.colors[i] == [0, 200, 0]).count();
    assert!(greens * 2 > front.len(), "{greens} of {} front vertices are texture green", front.len());
    let back_white = (0..mesh.vertex_count())
        .filter(|&i| mesh.positions[i].y > 0.5 - 1e-4)
        .all(|i| mesh.colors[i] == [255, 255, 255]);
    assert!(back_white);
    // Outward normals: the front face's normals point to -y.
    let n: Vec3 = front.iter().filter(|&&i| mesh.colors[i] == [0, 200, 0]).map(|&i| mesh.normals[i]).sum();
    assert!(n.y < 0.0, "front normals sum {n}");
}

#[test]
fn a_broken_model_is_an_error_naming_archive_and_entry() {
    let dir = tempfile::tempdir().expect("temp dir");
    write_catalogue(dir.path());
    let lib = FurnitureLibrary::open(dir.path()).expect("opens");
    for (id, entry) in [("Test#broken", "test/broken/broken.obj"), ("Test#missing", "test/missing/missing.obj")] {
        let msg = lib.load_mesh(&test_model(&lib, id)).expect_err("broken").to_string();
        assert!(msg.contains("Test.sh3f") && msg.contains(entry), "{msg}");
    }
}
