//! Tests of PLY reading and writing: round trips in every encoding, and malformed files.

use super::mesh::{write_mesh_streamed, STREAM_BLOCK_ROWS};
use super::*;

fn parse(text: &[u8]) -> Result<PlyFile> {
    PlyFile::parse(text, Path::new("test.ply"))
}

fn mesh_of(text: &[u8]) -> Result<LabeledMesh> {
    mesh_from_ply(&parse(text)?, Path::new("test.ply"))
}

const QUAD: &[u8] = b"ply\nformat ascii 1.0\ncomment hello world\nelement vertex 4\nproperty float x\n\
property float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
property uchar alpha\nproperty ushort label\nelement face 1\nproperty list uint8 int32 vertex_indices\n\
property int label\nend_header\n0 0 0 255 0 0 9 1\n1 0 0 0 255 0 9 300\n1 1 0 0 0 255 9 2\n0 1 0 1 2 3 9 3\n4 0 1 2 3 7\n";

#[test]
fn ascii_quad_is_fan_triangulated_with_labels() {
    let m = mesh_of(QUAD).expect("parse");
    assert_eq!(m.positions.len(), 4);
    assert_eq!(m.colors[1], [0, 255, 0]);
    assert_eq!(m.vertex_labels, vec![1, UNLABELED, 2, 3]);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.triangle_labels, vec![7, 7]);
    let ply = parse(QUAD).expect("parse");
    assert_eq!(ply.comments, vec!["hello world".to_string()]);
    assert_eq!(ply.element("vertex").and_then(|e| e.line_of_row(2)), Some(19));
}

#[test]
fn big_endian_matches_little_endian() {
    let ply = parse(QUAD).expect("parse");
    let mut be = Vec::new();
    ply.write_unchecked(&mut be, PlyFormat::BinaryBigEndian).expect("write");
    let mut le = Vec::new();
    ply.write_unchecked(&mut le, PlyFormat::BinaryLittleEndian).expect("write");
    let a = parse(&be).expect("be");
    let b = parse(&le).expect("le");
    assert_eq!(a.elements, b.elements);
    assert_eq!(a.elements, ply.elements);
}

#[test]
fn errors_name_the_line() {
    let cases: &[(&[u8], usize, &str)] = &[
        (b"plx\n", 1, "first line"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n", 4, "unknown property type"),
        (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", 3, "before any"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", 5, "end_header"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1.5\n2.x\n", 7, "not a valid float"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1.5\n", 7, "end of file"),
        (b"ply\nformat ascii 1.0\nelement vertex -2\nend_header\n", 3, "count"),
        (b"ply\nformat ascii 1.0\nfoo\nend_header\n", 3, "unknown header keyword"),
        (b"ply\nformat ascii 1.0\ncomment \xff\nend_header\n", 3, "UTF-8"),
    ];
    for (text, line, what) in cases {
        let e = parse(text).expect_err("must fail");
        match &e {
            DataError::Parse { line: l, message, .. } => {
                assert_eq!(*l, Some(*line), "{e}");
                assert!(message.contains(what), "{e}");
            }
            other => panic!("unexpected {other}"),
        }
    }
}

#[test]
fn semantic_errors() {
    let bad_index = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
    let e = mesh_of(bad_index).expect_err("index").to_string();
    assert!(e.contains("test.ply:13") && e.contains("out of range"), "{e}");
    let nan = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
property float z\nend_header\n0 0 0\n1 nan 0\n";
    let e = mesh_of(nan).expect_err("nan").to_string();
    assert!(e.contains("test.ply:9") && e.contains("non-finite"), "{e}");
    let no_z = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n";
    assert!(mesh_of(no_z).expect_err("z").to_string().contains("'z'"));
}

#[test]
fn huge_counts_fail_without_allocating() {
    let text = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\n\
element face 1000000000000\nproperty list uchar int vertex_indices\nend_header\n\x00\x00\x00\x00";
    assert!(parse(text).expect_err("truncated").to_string().contains("truncated"));
    let text = b"ply\nformat binary_little_endian 1.0\nelement face 1000000000000\n\
property list uchar int vertex_indices\nend_header\n\x03\x00\x00\x00\x00";
    assert!(parse(text).expect_err("truncated").to_string().contains("truncated"));
    let text = b"ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\nend_header\n1\n";
    assert!(parse(text).expect_err("eof").to_string().contains("end of file"));
}

#[test]
fn set_property_keeps_the_others() {
    let mut ply = parse(QUAD).expect("parse");
    let v = ply.element_mut("vertex").expect("vertex");
    v.set_property(Property { name: "label".into(), data: PropertyData::Scalar(Column::UChar(vec![5; 4])) })
        .expect("set");
    assert!(v
        .set_property(Property { name: "q".into(), data: PropertyData::Scalar(Column::UChar(vec![5; 3])) })
        .is_err());
    let bytes = ply.to_bytes(PlyEncoding::Ascii).expect("bytes");
    let again = parse(&bytes).expect("parse");
    let v = again.element("vertex").expect("vertex");
    assert_eq!(v.properties.len(), 8);
    assert_eq!(v.scalar("alpha"), Some(&Column::UChar(vec![9; 4])));
    assert_eq!(v.scalar("label"), Some(&Column::UChar(vec![5; 4])));
}

#[test]
fn inconsistent_files_in_code_fail_cleanly() {
    let mut ply = parse(QUAD).expect("parse");
    let face = ply.element_mut("face").expect("face");
    face.count = 3;
    let e = mesh_from_ply(&ply, Path::new("x.ply")).expect_err("inconsistent").to_string();
    assert!(e.contains("rows"), "{e}");
    assert!(ply.to_bytes(PlyEncoding::Ascii).is_err());
    let dir = tempfile::tempdir().expect("tempdir");
    assert!(ply.write(dir.path().join("x.ply"), PlyEncoding::BinaryLittleEndian).is_err());
}

#[test]
fn crlf_headers_aliases_and_small_index_types() {
    let text = b"ply\r\nformat ascii 1.0\r\nelement vertex 3\r\nproperty float32 x\r\nproperty float64 y\r\n\
property int16 z\r\nelement edge 1\r\nproperty int8 a\r\nelement face 1\r\n\
property list int8 uint16 vertex_index\r\nproperty char label\r\nend_header\r\n0 0 0\r\n1 0 0\r\n0 1 2\r\n-1\r\n3 2 1 0 -5\r\n";
    let m = mesh_of(text).expect("parse");
    assert_eq!(m.triangles, vec![[2, 1, 0]]);
    assert_eq!(m.triangle_labels, vec![UNLABELED]);
    assert_eq!(m.positions[2], Vec3::new(0.0, 1.0, 2.0));
}

#[test]
fn writes_atomically_and_round_trips() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("m.ply");
    let mesh = mesh_of(QUAD).expect("parse");
    for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        write_ply(&path, &mesh, enc).expect("write");
        assert_eq!(read_ply(&path).expect("read"), mesh);
    }
    let names: Vec<_> = std::fs::read_dir(dir.path()).expect("dir").map(|e| e.map(|e| e.file_name())).collect();
    assert_eq!(names.len(), 1, "temporary file left behind: {names:?}");
}

/// Both files of `write_ply_recoloured` are the bytes of `write_ply` on the mesh and on a
/// recoloured copy, in every encoding; colours not one per vertex are an error.
#[test]
fn recoloured_pair_equals_two_writes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mesh = mesh_of(QUAD).expect("parse");
    let colors: Vec<[u8; 3]> = (0..mesh.positions.len()).map(|i| [i as u8, 200, 7 * i as u8]).collect();
    let mut recoloured = mesh.clone();
    recoloured.colors = colors.clone();
    for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        let (a, b, c, d) = ["a", "b", "c", "d"].map(|n| dir.path().join(format!("{n}.ply"))).into();
        write_ply_recoloured(&a, &b, &mesh, &colors, enc, None).expect("pair");
        write_ply(&c, &mesh, enc).expect("mesh");
        write_ply(&d, &recoloured, enc).expect("recoloured");
        let read = |p: &std::path::Path| std::fs::read(p).expect("read");
        assert_eq!(read(&a), read(&c), "{enc:?} mesh");
        assert_eq!(read(&b), read(&d), "{enc:?} recoloured");
    }
    let e = write_ply_recoloured(
        dir.path().join("e.ply"),
        dir.path().join("f.ply"),
        &mesh,
        &colors[1..],
        PlyEncoding::Ascii,
        None,
    )
    .expect_err("short colours")
    .to_string();
    assert!(e.contains("colours for"), "{e}");
}

/// The up direction and floor survive a write and a read in both files and every encoding;
/// files without them read as `None`; malformed ones are errors naming the file.
#[test]
fn gravity_is_recorded_in_the_header() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mesh = mesh_of(QUAD).expect("parse");
    let up = glam::Vec3::new(0.0089, -0.9044, -0.4265);
    for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        let (a, b) = (dir.path().join("a.ply"), dir.path().join("b.ply"));
        let gravity = MeshGravity { up: up * 3.0, floor_height: Some(-1.4797) };
        write_ply_recoloured(&a, &b, &mesh, &mesh.colors, enc, Some(gravity)).expect("pair");
        for p in [&a, &b] {
            let (read, g) = read_ply_with_gravity(p).expect("read");
            assert_eq!(read, mesh);
            let g = g.expect("gravity");
            assert!((g.up - up.normalize()).length() < 1e-6, "{}", g.up);
            assert_eq!(g.floor_height, Some(-1.4797));
        }
        write_ply_recoloured(&a, &b, &mesh, &mesh.colors, enc, Some(MeshGravity::up(up))).expect("pair");
        assert_eq!(read_ply_with_gravity(&a).expect("read").1.and_then(|g| g.floor_height), None);
        write_ply(&a, &mesh, enc).expect("mesh");
        assert_eq!(read_ply_with_gravity(&a).expect("read").1, None);
    }
    let bad = dir.path().join("bad.ply");
    for comment in [
        "semrecon up 0 0 0",
        "semrecon up 1 x 0",
        "semrecon up 1 0",
        "semrecon up nan 0 1",
        "semrecon up 0 0 1\ncomment semrecon floor",
        "semrecon up 0 0 1\ncomment semrecon floor inf",
        "semrecon up 0 0 1\ncomment semrecon floor 1 2",
    ] {
        let text = String::from_utf8(QUAD.to_vec()).expect("ascii").replacen(
            "comment hello world",
            &format!("comment {comment}"),
            1,
        );
        std::fs::write(&bad, text).expect("write");
        let e = read_ply_with_gravity(&bad).expect_err(comment).to_string();
        assert!(e.contains("bad.ply") && (e.contains("up direction") || e.contains("floor height")), "{comment}: {e}");
    }
    for g in [MeshGravity::up(glam::Vec3::ZERO), MeshGravity { up: glam::Vec3::Z, floor_height: Some(f32::NAN) }] {
        assert!(write_ply_recoloured(&bad, &bad, &mesh, &mesh.colors, PlyEncoding::Ascii, Some(g)).is_err());
    }
}

/// A random mesh of `n` vertices and about `2n` triangles, with or without normals, vertex
/// and triangle labels.
fn random_mesh(n: usize, normals: bool, vertex_labels: bool, triangle_labels: bool, seed: u64) -> LabeledMesh {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut v = || Vec3::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0), rng.random_range(-1.0..3.0));
    let positions: Vec<Vec3> = (0..n).map(|_| v()).collect();
    let normals = if normals { (0..n).map(|_| v().normalize_or_zero()).collect() } else { Vec::new() };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 1);
    let colors = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
    let vertex_labels =
        if vertex_labels { (0..n).map(|_| rng.random_range(0..=UNLABELED)).collect() } else { Vec::new() };
    let t = if n == 0 { 0 } else { 2 * n + 3 };
    let triangles: Vec<[u32; 3]> = (0..t).map(|_| [0; 3].map(|_: u32| rng.random_range(0..n as u32))).collect();
    let triangle_labels = if triangle_labels { (0..t).map(|_| rng.random_range(0..20)).collect() } else { Vec::new() };
    LabeledMesh { positions, colors, normals, vertex_labels, triangles, triangle_labels }
}

/// The streamed writer (blocks of rows) writes the bytes of the whole conversion
/// ([`mesh_to_ply`] then the column writer) in every encoding, over several blocks and
/// their edges, with and without normals and labels, recoloured or not, with comments.
#[test]
fn streamed_mesh_equals_the_whole_conversion() {
    let n_big = 2 * STREAM_BLOCK_ROWS + 17;
    let cases = [
        (n_big, true, true, false),
        (STREAM_BLOCK_ROWS, false, false, true),
        (STREAM_BLOCK_ROWS / 2 - 1, true, false, true),
        (5, false, true, false),
        (0, false, false, false),
    ];
    for (seed, &(n, normals, vl, tl)) in cases.iter().enumerate() {
        let mut mesh = random_mesh(n, normals, vl, tl, seed as u64);
        if n == 5 {
            mesh.triangles.clear(); // a point cloud: no face element
        }
        let recolour: Vec<[u8; 3]> = (0..n).map(|i| [i as u8, (i / 256) as u8, 9]).collect();
        let comments = vec!["semrecon up 0 0 1".to_string()];
        for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian] {
            if format == PlyFormat::Ascii && n > STREAM_BLOCK_ROWS {
                continue; // the binary formats cover the block edges; text is slow to compare
            }
            for colors in [None, Some(&recolour[..])] {
                let mut whole = mesh.clone();
                if let Some(c) = colors {
                    whole.colors = c.to_vec();
                }
                let mut ply = mesh_to_ply(&whole).expect("valid");
                ply.comments.extend(comments.iter().cloned());
                let mut expected = Vec::new();
                ply.write_unchecked(&mut expected, format).expect("write");
                let mut streamed = Vec::new();
                write_mesh_streamed(&mut streamed, &mesh, colors, &comments, format).expect("stream");
                assert!(expected == streamed, "n {n}, {format:?}, recoloured {}", colors.is_some());
            }
        }
    }
}
