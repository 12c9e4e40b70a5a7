//! Stanford S3DIS rooms: the training and test data of the semantic network.
//!
//! Layout: `ROOT/Area_N/ROOM/Annotations/CLASS_K.txt`, one file per annotated object, each
//! line `x y z r g b` (metres, colour 0..=255) separated by spaces. The class comes from the
//! file name (`chair_3.txt` -> chair; `stairs` -> clutter, see
//! [`SemanticClass::from_name`]). The room-level `ROOM/ROOM.txt` (all points, unlabelled)
//! is not read. The real dataset has at least one corrupt line (Area_5/office_19,
//! `ceiling_1.txt`), so every error names the file and the 1-based line.

use std::path::{Path, PathBuf};

use glam::Vec3;
use rayon::prelude::*;

use crate::class::SemanticClass;
use crate::error::{DataError, Result};
use crate::point_cloud::LabeledPointCloud;

/// Reads one room folder (the one holding `Annotations/`) into a labelled point cloud.
/// Points are in the order of the annotation files sorted by name, then file order.
pub fn read_s3dis_room(room: impl AsRef<Path>) -> Result<LabeledPointCloud> {
    let room = room.as_ref();
    let files = annotation_files(room)?;
    // Files are parsed in parallel; collecting keeps their sorted order, so the result is
    // the same for any thread count.
    let parts: Vec<(SemanticClass, Vec<Vec3>, Vec<[u8; 3]>)> = files
        .par_iter()
        .map(|file| {
            let class = class_of_annotation_file(file)?;
            let (positions, colors) = read_annotation_file(file)?;
            Ok((class, positions, colors))
        })
        .collect::<Result<_>>()?;
    let n = parts.iter().map(|p| p.1.len()).sum();
    let mut cloud = LabeledPointCloud {
        positions: Vec::with_capacity(n),
        colors: Vec::with_capacity(n),
        labels: Vec::with_capacity(n),
    };
    for (class, positions, colors) in parts {
        cloud.labels.extend(std::iter::repeat_n(class.id(), positions.len()));
        cloud.positions.extend(positions);
        cloud.colors.extend(colors);
    }
    Ok(cloud)
}

/// The room folders under `root`, sorted by path. `root` may be an S3DIS root (holding
/// `Area_*` folders, possibly one level further down such as
/// `Stanford3dDataset_v1.2_Aligned_Version/`), an `Area_N` folder or a room folder; a room
/// folder is any folder with an `Annotations/` subfolder.
pub fn find_s3dis_rooms(root: impl AsRef<Path>) -> Result<Vec<PathBuf>> {
    let root = root.as_ref();
    if !root.is_dir() {
        return Err(DataError::dataset(root, "not a folder (expected an S3DIS root, Area or room folder)"));
    }
    let mut rooms = Vec::new();
    collect_rooms(root, 3, &mut rooms)?;
    if rooms.is_empty() {
        return Err(DataError::dataset(root, "no S3DIS room (folder with an Annotations/ subfolder) found"));
    }
    rooms.sort();
    Ok(rooms)
}

fn collect_rooms(dir: &Path, depth: usize, rooms: &mut Vec<PathBuf>) -> Result<()> {
    if dir.join("Annotations").is_dir() {
        rooms.push(dir.to_path_buf());
        return Ok(());
    }
    if depth == 0 {
        return Ok(());
    }
    for entry in std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))? {
        let path = entry.map_err(|e| DataError::io(dir, e))?.path();
        let hidden = path.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with('.'));
        if path.is_dir() && !hidden {
            collect_rooms(&path, depth - 1, rooms)?;
        }
    }
    Ok(())
}

/// The `*.txt` files of `room/Annotations`, sorted.
fn annotation_files(room: &Path) -> Result<Vec<PathBuf>> {
    let dir = room.join("Annotations");
    let mut files = Vec::new();
    for entry in std::fs::read_dir(&dir).map_err(|e| DataError::io(&dir, e))? {
        let path = entry.map_err(|e| DataError::io(&dir, e))?.path();
        let hidden = path.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with('.'));
        if !hidden && path.extension().is_some_and(|e| e == "txt") && path.is_file() {
            files.push(path);
        }
    }
    if files.is_empty() {
        return Err(DataError::dataset(&dir, "no annotation file (CLASS_K.txt)"));
    }
    files.sort();
    Ok(files)
}

/// The class of an annotation file from its name `CLASS_K.txt` (or `CLASS.txt`).
pub fn class_of_annotation_file(path: &Path) -> Result<SemanticClass> {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let name = match stem.rsplit_once('_') {
        Some((name, k)) if !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit()) => name,
        _ => stem,
    };
    SemanticClass::from_name(name).ok_or_else(|| {
        DataError::dataset(
            path,
            format!("unknown S3DIS class '{name}' in the file name (expected CLASS_K.txt with one of the 13 classes or stairs)"),
        )
    })
}

/// Reads the points of one annotation file.
fn read_annotation_file(path: &Path) -> Result<(Vec<Vec3>, Vec<[u8; 3]>)> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    // About 50 bytes per line in S3DIS: reserve close to what is needed.
    let guess = bytes.len() / 40;
    let mut positions = Vec::with_capacity(guess);
    let mut colors = Vec::with_capacity(guess);
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let err = |m: String| DataError::parse(path, Some(i + 1), m);
        let line = std::str::from_utf8(raw).map_err(|_| err("line is not valid UTF-8 text".into()))?;
        if line.trim().is_empty() {
            continue;
        }
        let (p, c) = parse_s3dis_line(line).map_err(err)?;
        positions.push(p);
        colors.push(c);
    }
    Ok((positions, colors))
}

/// Parses `x y z r g b`: finite coordinates, colours in 0..=255 (integers, or numbers that
/// round to one).
fn parse_s3dis_line(line: &str) -> std::result::Result<(Vec3, [u8; 3]), String> {
    let mut values = [0f32; 6];
    let mut n = 0;
    for token in line.split_ascii_whitespace() {
        if n == 6 {
            return Err(format!("more than 6 values (expected 'x y z r g b') in {line:?}"));
        }
        values[n] = token.parse::<f32>().map_err(|_| format!("{token:?} is not a number"))?;
        n += 1;
    }
    if n < 6 {
        return Err(format!("{n} values, expected 6 ('x y z r g b') in {line:?}"));
    }
    let p = Vec3::new(values[0], values[1], values[2]);
    if !p.is_finite() {
        return Err(format!("non-finite position in {line:?}"));
    }
    let mut c = [0u8; 3];
    for (k, &v) in values[3..].iter().enumerate() {
        if !(0.0..=255.0).contains(&v.round()) {
            return Err(format!("colour value {v} is outside 0..=255"));
        }
        c[k] = v.round() as u8;
    }
    Ok((p, c))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parses_lines() {
        assert_eq!(parse_s3dis_line("1.5 -2 3e-1 255 0 12").expect("ok"), (Vec3::new(1.5, -2.0, 0.3), [255, 0, 12]));
        assert_eq!(parse_s3dis_line(" 0 0 0 1.0 2 3\r").expect("ok").1, [1, 2, 3]);
        for bad in ["1 2 3 4 5", "1 2 3 4 5 6 7", "1 2 nan 0 0 0", "1 2 3 256 0 0", "103.0\u{10}00 1 2 3 4 5"] {
            assert!(parse_s3dis_line(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn class_from_file_name() {
        let c = |n: &str| class_of_annotation_file(Path::new(n)).ok();
        assert_eq!(c("a/chair_12.txt"), Some(SemanticClass::Chair));
        assert_eq!(c("stairs_1.txt"), Some(SemanticClass::Clutter));
        assert_eq!(c("ceiling.txt"), Some(SemanticClass::Ceiling));
        let e = class_of_annotation_file(Path::new("x/lamp_1.txt")).expect_err("unknown").to_string();
        assert!(e.contains("x/lamp_1.txt") && e.contains("lamp"), "{e}");
    }

    #[test]
    fn corrupt_line_is_reported_with_file_and_line() {
        let dir = tempfile::tempdir().expect("tempdir");
        let ann = dir.path().join("office_19/Annotations");
        std::fs::create_dir_all(&ann).expect("mkdir");
        std::fs::write(ann.join("ceiling_1.txt"), "1 2 3 4 5 6\n1 2 3 4 5 6\n103.0\u{10}00 71.847 3.350 1 2 3\n")
            .expect("write");
        let e = read_s3dis_room(dir.path().join("office_19")).expect_err("corrupt").to_string();
        assert!(e.contains("ceiling_1.txt:3"), "{e}");
    }

    proptest! {
        #[test]
        fn line_parser_never_panics(line in "\\PC{0,80}") {
            let _ = parse_s3dis_line(&line);
        }

        #[test]
        fn line_parser_never_panics_on_numberish_text(line in "[0-9eE+.\\- \t]{0,60}") {
            if let Ok((p, _)) = parse_s3dis_line(&line) {
                prop_assert!(p.is_finite());
            }
        }
    }
}
