//! Integration tests of the mesh and point-cloud formats: PLY (synthetic, real Replica mesh,
//! property-based round trips and malformed input), S3DIS and ScanNet fixtures in their real
//! layouts.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use proptest::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_data::ply::{mesh_from_ply, mesh_to_ply, Column, PlyFile, Property, PropertyData};
use semrecon_data::s3dis::{find_s3dis_rooms, read_s3dis_room};
use semrecon_data::scannet_mesh::read_scannet_mesh;
use semrecon_data::{read_ply, write_ply, DataError, LabeledMesh, LabeledPointCloud, PlyEncoding, SemanticClass};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn shared_data() -> Option<PathBuf> {
    semrecon_data::shared_data::shared_data_path("")
}

// ---------------------------------------------------------------------------------------
// S3DIS

#[test]
fn s3dis_fixture_room_reads_all_classes() {
    let room = fixtures().join("s3dis/Area_1/office_1");
    let cloud = read_s3dis_room(&room).expect("read room");
    cloud.validate().expect("valid cloud");
    assert_eq!(cloud.len(), 16 + 4 + 16 + 4 + 16 + 9);
    let count = |c: SemanticClass| cloud.labels.iter().filter(|&&l| l == c.id()).count();
    assert_eq!(count(SemanticClass::Ceiling), 16);
    assert_eq!(count(SemanticClass::Floor), 16);
    assert_eq!(count(SemanticClass::Wall), 25);
    assert_eq!(count(SemanticClass::Chair), 4);
    assert_eq!(count(SemanticClass::Clutter), 4, "stairs are clutter");
    // Sorted file order: ceiling_1 first, chair_1 second.
    assert_eq!(cloud.positions[0], Vec3::new(0.0, 0.0, 2.8));
    assert_eq!(cloud.colors[16], [200, 30, 30]);
    assert!(cloud.positions.iter().all(|p| p.z >= 0.0 && p.z <= 2.8));
}

#[test]
fn s3dis_rooms_are_found_from_root_area_or_room() {
    let root = fixtures().join("s3dis");
    let room = root.join("Area_1/office_1");
    for start in [root.clone(), root.join("Area_1"), room.clone()] {
        assert_eq!(find_s3dis_rooms(&start).expect("rooms"), vec![room.clone()], "from {}", start.display());
    }
    let empty = tempfile::tempdir().expect("tempdir");
    let e = find_s3dis_rooms(empty.path()).expect_err("no rooms");
    assert!(matches!(e, DataError::Dataset { .. }), "{e}");
}

#[test]
fn s3dis_errors_name_file_and_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let room = dir.path().join("Area_5/office_19");
    let ann = room.join("Annotations");
    std::fs::create_dir_all(&ann).expect("mkdir");
    std::fs::write(ann.join("wall_1.txt"), "0 0 0 1 2 3\n").expect("write");
    std::fs::write(ann.join("lamp_1.txt"), "0 0 0 1 2 3\n").expect("write");
    let e = read_s3dis_room(&room).expect_err("unknown class").to_string();
    assert!(e.contains("lamp_1.txt") && e.contains("'lamp'"), "{e}");
    std::fs::remove_file(ann.join("lamp_1.txt")).expect("rm");
    std::fs::write(ann.join("ceiling_1.txt"), "1 2 3 4 5 6\n7 8 9 1 2 3\n103.0\u{1e}00 71.8 3.3 1 2 3\n")
        .expect("write");
    let e = read_s3dis_room(&room).expect_err("corrupt line").to_string();
    assert!(e.contains("ceiling_1.txt:3"), "{e}");
    assert_eq!(find_s3dis_rooms(dir.path()).expect("rooms"), vec![room]);
}

// ---------------------------------------------------------------------------------------
// ScanNet

#[test]
fn scannet_fixture_maps_nyu40_labels() {
    let scene = fixtures().join("scannet/scene0000_00");
    let mesh = read_scannet_mesh(&scene).expect("read scene folder");
    assert_eq!(mesh, read_scannet_mesh(scene.join("scene0000_00_vh_clean_2.labels.ply")).expect("read file"));
    mesh.validate().expect("valid");
    assert_eq!(mesh.vertex_count(), 24);
    assert_eq!(mesh.triangle_count(), 12);
    assert!(mesh.triangle_labels.is_empty());
    // Quads in fixture order: floor, wall, chair, picture, blinds, unannotated.
    let expected = [
        SemanticClass::Floor.id(),
        SemanticClass::Wall.id(),
        SemanticClass::Chair.id(),
        SemanticClass::Clutter.id(),
        SemanticClass::Window.id(),
        UNLABELED,
    ];
    for (q, &label) in expected.iter().enumerate() {
        assert_eq!(&mesh.vertex_labels[4 * q..4 * q + 4], &[label; 4], "quad {q}");
    }
    assert_eq!(mesh.colors[8], [200, 30, 30]);
    let cloud = LabeledPointCloud::from_mesh(&mesh);
    cloud.validate().expect("valid cloud");
}

#[test]
fn scannet_rejects_non_nyu40_labels() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = fixtures().join("scannet/scene0000_00/scene0000_00_vh_clean_2.labels.ply");
    let mut ply = PlyFile::read(&src).expect("read");
    let vertex = ply.element_mut("vertex").expect("vertex");
    vertex
        .set_property(Property { name: "label".into(), data: PropertyData::Scalar(Column::UShort(vec![1163; 24])) })
        .expect("set");
    let path = dir.path().join("bad.ply");
    ply.write(&path, PlyEncoding::BinaryLittleEndian).expect("write");
    let e = read_scannet_mesh(&path).expect_err("raw ids").to_string();
    assert!(e.contains("bad.ply") && e.contains("1163"), "{e}");
}

// ---------------------------------------------------------------------------------------
// PLY on the real Replica mesh

#[test]
fn replica_office0_mesh_reads_and_round_trips() {
    let Some(data) = shared_data() else { return };
    let path = data.join("replica-office0/office0_mesh.ply");
    let t = Instant::now();
    let mesh = read_ply(&path).expect("read replica mesh");
    println!("read {} in {:.1} ms", path.display(), t.elapsed().as_secs_f64() * 1e3);
    assert_eq!(mesh.vertex_count(), 25_149);
    assert_eq!(mesh.triangle_count(), 50_000);
    assert!(mesh.vertex_labels.is_empty() && mesh.triangle_labels.is_empty() && mesh.normals.is_empty());
    mesh.validate().expect("valid");
    assert!(mesh.colors.iter().any(|c| *c != [128, 128, 128]), "colours were read");
    let (lo, hi) = mesh.bounds().expect("bounds");
    let size = hi - lo;
    assert!(size.min_element() > 1.0 && size.max_element() < 20.0, "room-sized: {size}");

    let dir = tempfile::tempdir().expect("tempdir");
    for enc in [PlyEncoding::BinaryLittleEndian, PlyEncoding::Ascii] {
        let out = dir.path().join("office0.ply");
        write_ply(&out, &mesh, enc).expect("write");
        let again = read_ply(&out).expect("read back");
        assert_eq!(again, mesh, "{enc:?}");
        assert!(again
            .positions
            .iter()
            .zip(&mesh.positions)
            .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)));
    }

    // Low level: add a label and keep alpha and the rest.
    let mut ply = PlyFile::read(&path).expect("read low level");
    let vertex = ply.element_mut("vertex").expect("vertex");
    vertex
        .set_property(Property { name: "label".into(), data: PropertyData::Scalar(Column::UChar(vec![3; 25_149])) })
        .expect("add label");
    let out = dir.path().join("labelled.ply");
    ply.write(&out, PlyEncoding::BinaryLittleEndian).expect("write");
    let again = PlyFile::read(&out).expect("read");
    assert_eq!(again.elements, ply.elements);
    assert!(again.element("vertex").and_then(|v| v.scalar("alpha")).is_some());
    let labelled = read_ply(&out).expect("read labelled");
    assert_eq!(labelled.vertex_labels, vec![3; 25_149]);
    assert_eq!(labelled.triangles, mesh.triangles);
}

#[test]
fn replica_truncations_give_errors() {
    let Some(data) = shared_data() else { return };
    let bytes = std::fs::read(data.join("replica-office0/office0_mesh.ply")).expect("read");
    for cut in [10, 200, 240, 5_000, bytes.len() / 2, bytes.len() - 1] {
        let e = PlyFile::parse(&bytes[..cut], Path::new("cut.ply")).expect_err("truncated");
        assert!(matches!(e, DataError::Parse { .. }), "{e}");
    }
}

// ---------------------------------------------------------------------------------------
// PLY: synthetic

#[test]
fn ply_point_cloud_and_polygons() {
    let text = b"ply\nformat ascii 1.0\nelement vertex 5\nproperty double x\nproperty double y\n\
property double z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty int label\n\
element face 1\nproperty list int uint vertex_index\nend_header\n\
0 0 0 0 0 1 -1\n1 0 0 0 0 1 2\n1 1 0 0 0 1 254\n0 1 0 0 0 1 255\n0.5 1.5 0 0 0 1 3\n5 0 1 2 4 3\n";
    let mesh =
        mesh_from_ply(&PlyFile::parse(text, Path::new("p.ply")).expect("parse"), Path::new("p.ply")).expect("mesh");
    assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 4], [0, 4, 3]]);
    assert_eq!(mesh.vertex_labels, vec![UNLABELED, 2, 254, UNLABELED, 3]);
    assert_eq!(mesh.colors, vec![[128; 3]; 5]);
    assert_eq!(mesh.normals[4], Vec3::Z);

    let cloud = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
property float red\nproperty float green\nproperty float blue\nend_header\n0 0 0 1 0.5 0\n1 1 1 0 0 0\n";
    let mesh =
        mesh_from_ply(&PlyFile::parse(cloud, Path::new("c.ply")).expect("parse"), Path::new("c.ply")).expect("mesh");
    assert!(mesh.triangles.is_empty());
    assert_eq!(mesh.colors[0], [255, 128, 0]);
}

#[test]
fn ply_write_errors_name_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mesh = LabeledMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
        colors: vec![[1, 2, 3]; 3],
        triangles: vec![[0, 1, 2]],
        ..Default::default()
    };
    let missing = dir.path().join("no/such/folder/m.ply");
    let e = write_ply(&missing, &mesh, PlyEncoding::BinaryLittleEndian).expect_err("missing folder");
    assert!(matches!(e, DataError::Io { .. }) && e.to_string().contains("m.ply"), "{e}");
    let mut bad = mesh.clone();
    bad.triangles.push([0, 1, 9]);
    let path = dir.path().join("bad.ply");
    let e = write_ply(&path, &bad, PlyEncoding::Ascii).expect_err("invalid mesh").to_string();
    assert!(e.contains("bad.ply") && e.contains("out of range"), "{e}");
    assert!(!path.exists());
    let e = read_ply(dir.path().join("absent.ply")).expect_err("absent");
    assert!(matches!(e, DataError::Io { .. }), "{e}");
}

#[test]
fn ply_large_mesh_speed() {
    // 1M vertices, 2M triangles: a multi-million-element file must stay fast.
    let n = 1000usize;
    let mut mesh = LabeledMesh::default();
    for i in 0..n {
        for j in 0..n {
            mesh.positions.push(Vec3::new(i as f32 * 0.01, j as f32 * 0.01, ((i * j) % 7) as f32 * 0.001));
            mesh.colors.push([(i % 256) as u8, (j % 256) as u8, 7]);
        }
    }
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let v = (i * n + j) as u32;
            let w = v + n as u32;
            mesh.triangles.push([v, v + 1, w]);
            mesh.triangles.push([v + 1, w + 1, w]);
        }
    }
    mesh.vertex_labels = (0..mesh.positions.len()).map(|i| (i % 13) as u8).collect();
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("big.ply");
    let t = Instant::now();
    write_ply(&path, &mesh, PlyEncoding::BinaryLittleEndian).expect("write");
    let write_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let bytes = std::fs::read(&path).expect("read bytes");
    let fs_ms = t.elapsed().as_secs_f64() * 1e3;
    let ply = PlyFile::parse(&bytes, &path).expect("parse");
    let parse_ms = t.elapsed().as_secs_f64() * 1e3 - fs_ms;
    let again = mesh_from_ply(&ply, &path).expect("mesh");
    let read_ms = t.elapsed().as_secs_f64() * 1e3;
    println!("read: fs {fs_ms:.0} ms, parse {parse_ms:.0} ms, total {read_ms:.0} ms");
    println!(
        "binary PLY, {} vertices, {} triangles, {:.1} MB: write {write_ms:.0} ms, read {read_ms:.0} ms",
        mesh.vertex_count(),
        mesh.triangle_count(),
        std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0) as f64 / 1e6
    );
    assert_eq!(again, mesh);
}

// ---------------------------------------------------------------------------------------
// PLY: property-based

fn finite_f32() -> impl Strategy<Value = f32> {
    use proptest::num::f32;
    f32::POSITIVE | f32::NEGATIVE | f32::NORMAL | f32::SUBNORMAL | f32::ZERO
}

fn vec3() -> impl Strategy<Value = Vec3> {
    (finite_f32(), finite_f32(), finite_f32()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

fn random_mesh() -> impl Strategy<Value = LabeledMesh> {
    (1usize..24, 0usize..24, any::<bool>(), any::<bool>(), any::<bool>()).prop_flat_map(|(n, t, normals, vl, tl)| {
        (
            prop::collection::vec(vec3(), n),
            prop::collection::vec(any::<[u8; 3]>(), n),
            prop::collection::vec(vec3(), if normals { n } else { 0 }),
            prop::collection::vec(any::<u8>(), if vl { n } else { 0 }),
            prop::collection::vec(prop::array::uniform3(0..n as u32), t),
            prop::collection::vec(any::<u8>(), if tl { t } else { 0 }),
        )
            .prop_map(|(positions, colors, normals, vertex_labels, triangles, triangle_labels)| LabeledMesh {
                positions,
                colors,
                normals,
                vertex_labels,
                triangles,
                triangle_labels,
            })
    })
}

fn round_trip(mesh: &LabeledMesh, enc: PlyEncoding) -> LabeledMesh {
    let bytes = mesh_to_ply(mesh).expect("to ply").to_bytes(enc).expect("encode");
    let ply = PlyFile::parse(&bytes, Path::new("rt.ply")).expect("parse");
    mesh_from_ply(&ply, Path::new("rt.ply")).expect("mesh")
}

fn bits(v: &[Vec3]) -> Vec<[u32; 3]> {
    v.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
}

/// The low-level file must never panic, and a parsed file must convert (or fail) cleanly.
fn parse_any(bytes: &[u8]) -> Result<LabeledMesh, DataError> {
    let ply = PlyFile::parse(bytes, Path::new("fuzz.ply"))?;
    mesh_from_ply(&ply, Path::new("fuzz.ply"))
}

proptest! {
    #[test]
    fn ply_binary_round_trip_is_exact(mesh in random_mesh()) {
        let again = round_trip(&mesh, PlyEncoding::BinaryLittleEndian);
        prop_assert_eq!(bits(&again.positions), bits(&mesh.positions));
        prop_assert_eq!(bits(&again.normals), bits(&mesh.normals));
        prop_assert_eq!(again, mesh);
    }

    #[test]
    fn ply_ascii_round_trip_is_exact(mesh in random_mesh()) {
        // `{}` of an f32 prints the shortest text that parses back to the same bits.
        let again = round_trip(&mesh, PlyEncoding::Ascii);
        prop_assert_eq!(bits(&again.positions), bits(&mesh.positions));
        prop_assert_eq!(bits(&again.normals), bits(&mesh.normals));
        prop_assert_eq!(again, mesh);
    }

    #[test]
    fn ply_random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        prop_assert!(parse_any(&bytes).is_err());
        let mut with_header = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n".to_vec();
        with_header.extend_from_slice(&bytes);
        let _ = parse_any(&with_header);
    }

    #[test]
    fn ply_truncations_fail(mesh in random_mesh(), cut in 0.0f64..1.0) {
        let bytes = mesh_to_ply(&mesh).expect("ply").to_bytes(PlyEncoding::BinaryLittleEndian).expect("bytes");
        let cut = ((bytes.len() as f64) * cut) as usize;
        let e = parse_any(&bytes[..cut]);
        prop_assert!(matches!(e, Err(DataError::Parse { .. })), "{:?}", e);
        let text = mesh_to_ply(&mesh).expect("ply").to_bytes(PlyEncoding::Ascii).expect("bytes");
        let cut = cut.min(text.len());
        // A cut inside the last number of an ASCII file can leave a valid shorter number.
        let _ = parse_any(&text[..cut]);
    }

    #[test]
    fn ply_header_mutations_never_panic(
        mesh in random_mesh(),
        ascii in any::<bool>(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..4),
    ) {
        let enc = if ascii { PlyEncoding::Ascii } else { PlyEncoding::BinaryLittleEndian };
        let mut bytes = mesh_to_ply(&mesh).expect("ply").to_bytes(enc).expect("bytes");
        let header_len = bytes.windows(11).position(|w| w == b"end_header\n").map_or(bytes.len(), |p| p + 11);
        for (at, byte, op) in edits {
            let i = at.index(header_len.min(bytes.len()).max(1));
            match op {
                0 if i < bytes.len() => bytes[i] = byte,
                1 => bytes.insert(i.min(bytes.len()), byte),
                _ if i < bytes.len() => { bytes.remove(i); }
                _ => {}
            }
        }
        let _ = parse_any(&bytes);
    }

    #[test]
    fn ply_header_words_never_panic(
        words in prop::collection::vec(prop::sample::select(vec![
            "ply", "format", "ascii", "binary_little_endian", "binary_big_endian", "1.0", "element",
            "vertex", "face", "property", "list", "uchar", "int", "float", "double", "x", "y", "z",
            "vertex_indices", "label", "end_header", "\n", "0", "3", "4294967295", "99999999999999",
        ]), 0..40),
        body in prop::collection::vec(any::<u8>(), 0..64),
    ) {
        let mut bytes = b"ply\n".to_vec();
        bytes.extend_from_slice(words.join(" ").as_bytes());
        bytes.extend_from_slice(b"\nend_header\n");
        bytes.extend_from_slice(&body);
        let _ = parse_any(&bytes);
    }
}
