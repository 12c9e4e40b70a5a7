//! Camera trajectories and the text formats datasets store them in: TUM
//! (`timestamp tx ty tz qx qy qz qw`), Redwood/Open3D `.log` (an `i j n` line then a 4x4
//! matrix per pose), single 4x4 matrix files (7-Scenes/SUN3D `frame-N.pose.txt`, ScanNet
//! `pose/N.txt`, where `-inf` marks a frame without a pose) and Replica/NICE-SLAM `traj.txt`
//! (16 row-major floats per line).
//!
//! Every parser checks that a pose is a finite rigid transform: files written by other tools
//! carry slightly non-orthonormal rotations (printed with few digits, accumulated in f32),
//! which are projected back onto the nearest rotation, while anything further off than a
//! rounding error is rejected with the file and line, because a reflection or a scale in a
//! "ground-truth" pose silently ruins every metric computed from it. All writers are atomic.

use std::fmt::Write as _;
use std::path::Path;

use glam::{Affine3A, DMat3, DQuat, DVec3, Mat3A, Quat, Vec3A};

use crate::atomic_file::write_atomic;
use crate::error::{DataError, Result};

/// How far the determinant of a parsed rotation may be from 1 before it is rejected.
const DET_TOLERANCE: f64 = 0.05;
/// How far any entry of `R Rᵀ` may be from the identity before it is rejected.
const ORTHO_TOLERANCE: f64 = 0.05;
/// How far the last row of a 4x4 matrix may be from `0 0 0 1`.
const LAST_ROW_TOLERANCE: f64 = 1e-3;

/// A timed sequence of `world_from_camera` poses.
///
/// # Shapes
/// `timestamps` and `poses` have the same length; timestamps are seconds for TUM and the frame
/// number for formats without time (`.log`, `traj.txt`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Time of each pose (seconds, or frame number where the format has no time).
    pub timestamps: Vec<f64>,
    /// `world_from_camera` of each pose.
    pub poses: Vec<Affine3A>,
}

impl Trajectory {
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether the trajectory has no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Appends a pose.
    pub fn push(&mut self, timestamp: f64, world_from_camera: Affine3A) {
        self.timestamps.push(timestamp);
        self.poses.push(world_from_camera);
    }

    /// Reads a TUM trajectory file (`timestamp tx ty tz qx qy qz qw` per line, `#` comments).
    pub fn read_tum(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_tum(&read_text(path)?, path)
    }

    /// Parses TUM trajectory text; `path` only names the source in errors.
    pub fn parse_tum(text: &str, path: &Path) -> Result<Self> {
        let mut out = Self::default();
        for (line_no, fields) in data_lines(text) {
            let values = parse_floats(&fields, path, line_no)?;
            if values.len() != 8 {
                return Err(DataError::parse(
                    path,
                    Some(line_no),
                    format!("expected 8 fields (timestamp tx ty tz qx qy qz qw), found {}", values.len()),
                ));
            }
            let q = DQuat::from_xyzw(values[4], values[5], values[6], values[7]);
            // Divide by the largest component first so that huge components cannot overflow.
            let largest = q.to_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if largest <= 1e-12 {
                return Err(DataError::parse(path, Some(line_no), "quaternion has zero length"));
            }
            let q = (q / largest).normalize();
            let t = DVec3::new(values[1], values[2], values[3]);
            let pose = affine_from_f64(DMat3::from_quat(q), t).map_err(|m| DataError::parse(path, Some(line_no), m))?;
            out.push(values[0], pose);
        }
        Ok(out)
    }

    /// Formats the trajectory as TUM text (with a `#` header line).
    pub fn to_tum_string(&self) -> String {
        let mut s = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for (t, pose) in self.timestamps.iter().zip(&self.poses) {
            let q = Quat::from_mat3a(&pose.matrix3).normalize();
            let p = pose.translation;
            // `{}` prints the shortest text that reads back to the same f32/f64 bits.
            let _ = writeln!(s, "{t} {} {} {} {} {} {} {}", p.x, p.y, p.z, q.x, q.y, q.z, q.w);
        }
        s
    }

    /// Reads a trajectory in any of the formats above: `.log` files as Redwood logs, other
    /// files by the field count of their first data line (8: TUM, 16: Replica `traj.txt`).
    pub fn read_any(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("log")) {
            return Self::read_log(path);
        }
        let text = read_text(path)?;
        match data_lines(&text).first() {
            Some((_, fields)) if fields.len() == 8 => Self::parse_tum(&text, path),
            Some((_, fields)) if fields.len() == 16 => Self::parse_replica(&text, path),
            Some((line, fields)) => Err(DataError::parse(
                path,
                Some(*line),
                format!(
                    "{} fields: expected 8 (TUM: timestamp tx ty tz qx qy qz qw) or 16 (a row-major 4x4 per line), or a .log file",
                    fields.len()
                ),
            )),
            None => Err(DataError::parse(path, None, "no poses in the file")),
        }
    }

    /// Writes the trajectory in TUM format, atomically.
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), self.to_tum_string().as_bytes())
    }

    /// Reads a Redwood/Open3D `.log` trajectory; timestamps hold each entry's frame id
    /// (the first number of its `i j n` line).
    pub fn read_log(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_log(&read_text(path)?, path)
    }

    /// Parses `.log` text; `path` only names the source in errors.
    pub fn parse_log(text: &str, path: &Path) -> Result<Self> {
        let mut out = Self::default();
        let mut lines = data_lines(text).into_iter();
        while let Some((header_line, header)) = lines.next() {
            let ids = parse_floats(&header, path, header_line)?;
            if ids.len() != 3 {
                return Err(DataError::parse(
                    path,
                    Some(header_line),
                    format!("expected an `i j n` header of 3 fields, found {}", ids.len()),
                ));
            }
            let mut rows = [[0.0; 4]; 4];
            for (r, row) in rows.iter_mut().enumerate() {
                let Some((line_no, fields)) = lines.next() else {
                    return Err(DataError::parse(
                        path,
                        Some(header_line),
                        format!("pose truncated: {r} of 4 matrix rows after this header"),
                    ));
                };
                let values = parse_floats(&fields, path, line_no)?;
                if values.len() != 4 {
                    return Err(DataError::parse(
                        path,
                        Some(line_no),
                        format!("expected 4 values in a matrix row, found {}", values.len()),
                    ));
                }
                row.copy_from_slice(&values);
            }
            let pose = rigid_from_rows(&rows).map_err(|m| DataError::parse(path, Some(header_line + 1), m))?;
            out.push(ids[0], pose);
        }
        Ok(out)
    }

    /// Formats the trajectory as `.log` text (entry `k` gets the header `k k k+1`).
    pub fn to_log_string(&self) -> String {
        let mut s = String::new();
        for (k, pose) in self.poses.iter().enumerate() {
            let _ = writeln!(s, "{k} {k} {}", k + 1);
            for row in rows_of(pose) {
                let _ = writeln!(s, "{} {} {} {}", row[0], row[1], row[2], row[3]);
            }
        }
        s
    }

    /// Writes the trajectory in `.log` format, atomically.
    pub fn write_log(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), self.to_log_string().as_bytes())
    }

    /// Reads a Replica/NICE-SLAM `traj.txt` (16 row-major floats of a 4x4 camera-to-world per
    /// line); timestamps hold the line's pose number (0-based).
    pub fn read_replica(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_replica(&read_text(path)?, path)
    }

    /// Parses `traj.txt` text; `path` only names the source in errors.
    pub fn parse_replica(text: &str, path: &Path) -> Result<Self> {
        let mut out = Self::default();
        for (line_no, fields) in data_lines(text) {
            let values = parse_floats(&fields, path, line_no)?;
            if values.len() != 16 {
                return Err(DataError::parse(
                    path,
                    Some(line_no),
                    format!("expected 16 values (a row-major 4x4 matrix), found {}", values.len()),
                ));
            }
            let mut rows = [[0.0; 4]; 4];
            for (r, row) in rows.iter_mut().enumerate() {
                row.copy_from_slice(&values[4 * r..4 * r + 4]);
            }
            let pose = rigid_from_rows(&rows).map_err(|m| DataError::parse(path, Some(line_no), m))?;
            out.push(out.len() as f64, pose);
        }
        Ok(out)
    }

    /// Formats the trajectory as Replica `traj.txt` text.
    pub fn to_replica_string(&self) -> String {
        let mut s = String::new();
        for pose in &self.poses {
            let values: Vec<String> = rows_of(pose).iter().flatten().map(|v| v.to_string()).collect();
            let _ = writeln!(s, "{}", values.join(" "));
        }
        s
    }

    /// Writes the trajectory in Replica `traj.txt` format, atomically.
    pub fn write_replica(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), self.to_replica_string().as_bytes())
    }

    /// Index of the pose nearest in time to `t`, if it is at most `max_difference` away.
    pub fn nearest(&self, t: f64, max_difference: f64) -> Option<usize> {
        nearest_index(&self.timestamps, t, max_difference)
    }

    /// The pose at time `t`: interpolated (linear translation, slerp rotation) between the
    /// poses just before and after `t` when they are at most `max_gap` apart, else the nearest
    /// pose when it is at most `max_difference` away, else `None`.
    pub fn pose_at(&self, t: f64, max_gap: f64, max_difference: f64) -> Option<Affine3A> {
        let order = sorted_order(&self.timestamps);
        let pos = order.partition_point(|&i| self.timestamps[i] <= t);
        if pos > 0 && pos < order.len() {
            let (a, b) = (order[pos - 1], order[pos]);
            let (ta, tb) = (self.timestamps[a], self.timestamps[b]);
            if tb - ta <= max_gap && tb > ta {
                let s = ((t - ta) / (tb - ta)) as f32;
                let (pa, pb) = (&self.poses[a], &self.poses[b]);
                let qa = Quat::from_mat3a(&pa.matrix3).normalize();
                let qb = Quat::from_mat3a(&pb.matrix3).normalize();
                let q = qa.slerp(qb, s).normalize();
                let p = pa.translation.lerp(pb.translation, s);
                return Some(Affine3A::from_rotation_translation(q, p.into()));
            }
        }
        self.nearest(t, max_difference).map(|i| self.poses[i])
    }
}

/// For every time in `reference`, the index of the nearest time in `candidates` if it is at
/// most `max_difference` away (candidates need not be sorted; non-finite times never match).
///
/// # Shapes
/// The result has `reference.len()` entries.
pub fn associate(reference: &[f64], candidates: &[f64], max_difference: f64) -> Vec<Option<usize>> {
    let order = sorted_order(candidates);
    reference.iter().map(|&t| nearest_in_order(candidates, &order, t, max_difference)).collect()
}

/// Reads a single-pose matrix file: 3 or 4 rows of 4 numbers, a `world_from_camera`
/// (7-Scenes / SUN3D `frame-N.pose.txt`, ScanNet `pose/N.txt`). A matrix containing an
/// infinity (ScanNet writes `-inf` for frames its tracker lost) gives `Ok(None)`; NaN is an
/// error.
pub fn read_pose_matrix(path: impl AsRef<Path>) -> Result<Option<Affine3A>> {
    let path = path.as_ref();
    parse_pose_matrix(&read_text(path)?, path)
}

/// Parses a single-pose matrix file's text; `path` only names the source in errors.
pub fn parse_pose_matrix(text: &str, path: &Path) -> Result<Option<Affine3A>> {
    let lines = data_lines(text);
    if lines.len() != 3 && lines.len() != 4 {
        return Err(DataError::parse(
            path,
            None,
            format!("expected a 3x4 or 4x4 matrix, found {} non-empty lines", lines.len()),
        ));
    }
    let mut rows = [[0.0, 0.0, 0.0, 0.0], [0.0; 4], [0.0; 4], [0.0, 0.0, 0.0, 1.0]];
    let mut invalid = false;
    for ((line_no, fields), row) in lines.iter().zip(rows.iter_mut()) {
        let values = parse_numbers(fields, path, *line_no)?;
        if values.len() != 4 {
            return Err(DataError::parse(
                path,
                Some(*line_no),
                format!("expected 4 values in a matrix row, found {}", values.len()),
            ));
        }
        if values.iter().any(|v| v.is_infinite()) {
            invalid = true;
        } else if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return Err(DataError::parse(path, Some(*line_no), format!("non-finite value {v}")));
        }
        row.copy_from_slice(&values);
    }
    if invalid {
        return Ok(None);
    }
    rigid_from_rows(&rows).map(Some).map_err(|m| DataError::parse(path, Some(lines[0].0), m))
}

/// Writes a pose as a 4x4 row-major matrix file (the 7-Scenes `pose.txt` layout), atomically.
pub fn write_pose_matrix(path: impl AsRef<Path>, world_from_camera: &Affine3A) -> Result<()> {
    let mut s = String::new();
    for row in rows_of(world_from_camera) {
        let _ = writeln!(s, "{} {} {} {}", row[0], row[1], row[2], row[3]);
    }
    write_atomic(path.as_ref(), s.as_bytes())
}

/// Parses a whitespace-separated numeric matrix file (`#` comments, blank lines skipped),
/// requiring `rows` rows of `cols` finite numbers (intrinsics files).
pub(crate) fn parse_matrix(text: &str, path: &Path, rows: usize, cols: usize) -> Result<Vec<Vec<f64>>> {
    let lines = data_lines(text);
    if lines.len() != rows {
        return Err(DataError::parse(
            path,
            None,
            format!("expected a {rows}x{cols} matrix, found {} non-empty lines", lines.len()),
        ));
    }
    lines
        .iter()
        .map(|(line_no, fields)| {
            let values = parse_floats(fields, path, *line_no)?;
            if values.len() != cols {
                return Err(DataError::parse(
                    path,
                    Some(*line_no),
                    format!("expected {cols} values in a matrix row, found {}", values.len()),
                ));
            }
            Ok(values)
        })
        .collect()
}

/// Reads a whole text file, naming it in the error.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))
}

/// Non-empty, non-comment lines split into fields, with 1-based line numbers.
fn data_lines(text: &str) -> Vec<(usize, Vec<&str>)> {
    text.lines()
        .enumerate()
        .filter_map(|(i, line)| {
            let content = line.split('#').next().unwrap_or("").trim();
            (!content.is_empty()).then(|| (i + 1, content.split_whitespace().collect()))
        })
        .collect()
}

/// Parses fields as numbers, allowing infinities and NaN through (callers decide).
fn parse_numbers(fields: &[&str], path: &Path, line: usize) -> Result<Vec<f64>> {
    fields
        .iter()
        .map(|f| f.parse::<f64>().map_err(|_| DataError::parse(path, Some(line), format!("`{f}` is not a number"))))
        .collect()
}

/// Parses fields as finite numbers.
fn parse_floats(fields: &[&str], path: &Path, line: usize) -> Result<Vec<f64>> {
    let values = parse_numbers(fields, path, line)?;
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return Err(DataError::parse(path, Some(line), format!("non-finite value {v}")));
    }
    Ok(values)
}

/// Checks that a 4x4 row-major matrix is a rigid transform and returns it with its rotation
/// projected onto the nearest orthonormal matrix.
fn rigid_from_rows(rows: &[[f64; 4]; 4]) -> Result<Affine3A, String> {
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return Err("matrix has a non-finite value".into());
    }
    let last = rows[3];
    if last[0].abs() > LAST_ROW_TOLERANCE
        || last[1].abs() > LAST_ROW_TOLERANCE
        || last[2].abs() > LAST_ROW_TOLERANCE
        || (last[3] - 1.0).abs() > LAST_ROW_TOLERANCE
    {
        return Err(format!(
            "not a rigid transform: last row is {} {} {} {}, expected 0 0 0 1",
            last[0], last[1], last[2], last[3]
        ));
    }
    let r = DMat3::from_cols(
        DVec3::new(rows[0][0], rows[1][0], rows[2][0]),
        DVec3::new(rows[0][1], rows[1][1], rows[2][1]),
        DVec3::new(rows[0][2], rows[1][2], rows[2][2]),
    );
    let det = r.determinant();
    if (det - 1.0).abs() > DET_TOLERANCE {
        return Err(format!("not a rigid transform: rotation determinant is {det}, expected 1"));
    }
    let gram = r * r.transpose() - DMat3::IDENTITY;
    let off = gram.to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if off > ORTHO_TOLERANCE {
        return Err(format!("not a rigid transform: rotation rows are not orthonormal (error {off:.3})"));
    }
    let t = DVec3::new(rows[0][3], rows[1][3], rows[2][3]);
    affine_from_f64(orthonormalize(r), t)
}

/// Nearest rotation to an almost-orthonormal `r` (polar decomposition by the Newton
/// iteration `R <- (R + R^-T) / 2`, which converges quadratically from close starts).
fn orthonormalize(mut r: DMat3) -> DMat3 {
    for _ in 0..20 {
        let next = (r + r.inverse().transpose()) * 0.5;
        let change = (next - r).to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
        r = next;
        if change < 1e-15 {
            break;
        }
    }
    r
}

/// The pose in single precision; fails when a value does not fit.
fn affine_from_f64(r: DMat3, t: DVec3) -> Result<Affine3A, String> {
    let pose = Affine3A {
        matrix3: Mat3A::from_cols(
            Vec3A::new(r.x_axis.x as f32, r.x_axis.y as f32, r.x_axis.z as f32),
            Vec3A::new(r.y_axis.x as f32, r.y_axis.y as f32, r.y_axis.z as f32),
            Vec3A::new(r.z_axis.x as f32, r.z_axis.y as f32, r.z_axis.z as f32),
        ),
        translation: Vec3A::new(t.x as f32, t.y as f32, t.z as f32),
    };
    if pose.is_finite() {
        Ok(pose)
    } else {
        Err(format!("translation {} {} {} is out of single-precision range", t.x, t.y, t.z))
    }
}

/// The three top rows of a pose's 4x4 matrix plus `0 0 0 1`.
fn rows_of(pose: &Affine3A) -> [[f32; 4]; 4] {
    let m = pose.matrix3;
    let t = pose.translation;
    [
        [m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x],
        [m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y],
        [m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Indices of the finite `times`, sorted by time.
fn sorted_order(times: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..times.len()).filter(|&i| times[i].is_finite()).collect();
    order.sort_by(|&a, &b| times[a].total_cmp(&times[b]));
    order
}

fn nearest_index(times: &[f64], t: f64, max_difference: f64) -> Option<usize> {
    nearest_in_order(times, &sorted_order(times), t, max_difference)
}

fn nearest_in_order(times: &[f64], order: &[usize], t: f64, max_difference: f64) -> Option<usize> {
    if !t.is_finite() {
        return None;
    }
    let pos = order.partition_point(|&i| times[i] < t);
    let before = pos.checked_sub(1).map(|p| order[p]);
    let after = order.get(pos).copied();
    let best = match (before, after) {
        (Some(a), Some(b)) => {
            if (t - times[a]).abs() <= (times[b] - t).abs() {
                Some(a)
            } else {
                Some(b)
            }
        }
        (a, b) => a.or(b),
    };
    best.filter(|&i| (times[i] - t).abs() <= max_difference)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("test.txt")
    }

    #[test]
    fn tum_parses_comments_and_normalises_quaternions() {
        let text = "# header\n\n1.5 1 2 3 0 0 0 2\n 2.0 0 0 0 0 0 1 1 # half turn-ish\n";
        let t = Trajectory::parse_tum(text, p()).expect("valid");
        assert_eq!(t.timestamps, vec![1.5, 2.0]);
        assert!((t.poses[0].translation - Vec3A::new(1.0, 2.0, 3.0)).length() < 1e-6);
        assert!((t.poses[0].matrix3.x_axis - Vec3A::X).length() < 1e-6);
        assert!((t.poses[1].transform_vector3(glam::Vec3::X) - glam::Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn tum_errors_name_the_line() {
        let e = Trajectory::parse_tum("1 2 3\n", p()).expect_err("short");
        assert!(e.to_string().contains("test.txt:1") && e.to_string().contains("8 fields"), "{e}");
        let e = Trajectory::parse_tum("\n1 0 0 0 0 0 0 0\n", p()).expect_err("zero q");
        assert!(e.to_string().contains(":2") && e.to_string().contains("zero"), "{e}");
        let e = Trajectory::parse_tum("1 nan 0 0 0 0 0 1\n", p()).expect_err("nan");
        assert!(e.to_string().contains("non-finite"), "{e}");
        let e = Trajectory::parse_tum("1 1e300 0 0 0 0 0 1\n", p()).expect_err("huge");
        assert!(e.to_string().contains("out of single-precision range"), "{e}");
        let t = Trajectory::parse_tum("1 0 0 0 1e300 0 0 1e300\n", p()).expect("huge quaternion");
        assert!(t.poses[0].is_finite());
        let e = Trajectory::parse_tum("1 x 0 0 0 0 0 1\n", p()).expect_err("word");
        assert!(e.to_string().contains("`x` is not a number"), "{e}");
    }

    #[test]
    fn log_round_trip_and_errors() {
        let mut t = Trajectory::default();
        t.push(0.0, Affine3A::from_rotation_translation(Quat::from_rotation_y(0.3), glam::Vec3::new(1.0, 2.0, 3.0)));
        t.push(1.0, Affine3A::IDENTITY);
        let back = Trajectory::parse_log(&t.to_log_string(), p()).expect("round trip");
        assert_eq!(back.timestamps, t.timestamps);
        for (a, b) in back.poses.iter().zip(&t.poses) {
            assert!(a.abs_diff_eq(*b, 1e-6));
        }
        let e = Trajectory::parse_log("0 0 1\n1 0 0 0\n0 1 0 0\n", p()).expect_err("truncated");
        assert!(e.to_string().contains("truncated"), "{e}");
        let e = Trajectory::parse_log("0 0 1\n2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", p()).expect_err("scaled");
        assert!(e.to_string().contains("determinant"), "{e}");
    }

    #[test]
    fn matrix_files_accept_3_or_4_rows_and_inf() {
        let four = "1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n";
        let three = "1 0 0 1\n0 1 0 2\n0 0 1 3\n";
        let a = parse_pose_matrix(four, p()).expect("valid").expect("pose");
        let b = parse_pose_matrix(three, p()).expect("valid").expect("pose");
        assert_eq!(a, b);
        let inf = "-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n";
        assert!(parse_pose_matrix(inf, p()).expect("valid").is_none());
        let e = parse_pose_matrix("1 0 0 1\n0 1 0 2\n0 0 1 nan\n", p()).expect_err("nan");
        assert!(e.to_string().contains("test.txt:3"), "{e}");
        let e = parse_pose_matrix("1 0 0\n0 1 0\n0 0 1\n", p()).expect_err("3 cols");
        assert!(e.to_string().contains("4 values"), "{e}");
        let e = parse_pose_matrix("-1 0 0 0\n0 1 0 0\n0 0 1 0\n", p()).expect_err("mirror");
        assert!(e.to_string().contains("rigid"), "{e}");
        let e = parse_pose_matrix("1 0.3 0 0\n0 1 0 0\n0 0 1 0\n", p()).expect_err("shear");
        assert!(e.to_string().contains("orthonormal"), "{e}");
    }

    #[test]
    fn slightly_off_rotations_are_orthonormalised() {
        let m =
            parse_pose_matrix("1.001 0.002 0 0\n-0.002 0.999 0 0\n0 0 1.0005 0\n", p()).expect("valid").expect("pose");
        let r = m.matrix3;
        let gram = r * r.transpose() - Mat3A::IDENTITY;
        assert!(gram.to_cols_array().iter().all(|v| v.abs() < 1e-6), "{gram:?}");
        assert!((r.determinant() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn association_picks_nearest_within_limit() {
        let cand = [0.30, 0.0, 0.1, 0.2];
        let got = associate(&[0.09, 0.16, 0.5, -0.01, f64::NAN], &cand, 0.02);
        assert_eq!(got, vec![Some(2), None, None, Some(1), None]);
        let got = associate(&[0.14], &cand, 0.1);
        assert_eq!(got, vec![Some(2)]);
    }

    #[test]
    fn pose_at_interpolates_between_neighbours() {
        let mut t = Trajectory::default();
        t.push(0.0, Affine3A::from_translation(glam::Vec3::ZERO));
        t.push(1.0, Affine3A::from_rotation_translation(Quat::from_rotation_z(1.0), glam::Vec3::X));
        let mid = t.pose_at(0.25, 2.0, 0.0).expect("bracketed");
        assert!((mid.translation.x - 0.25).abs() < 1e-6);
        let expected = glam::Vec3::new(0.25f32.cos(), 0.25f32.sin(), 0.0);
        assert!((mid.transform_vector3(glam::Vec3::X) - expected).length() < 1e-5);
        assert!(t.pose_at(0.25, 0.5, 0.02).is_none());
        assert!(t.pose_at(0.99, 0.5, 0.02).is_some());
        assert!(t.pose_at(3.0, 5.0, 0.5).is_none());
    }
}
