//! The high level of the PLY module: a [`LabeledMesh`] read from and written to PLY (positions,
//! normals, colours, the vertex `label`, triangles from any polygon list).

use super::*;

/// Reads a PLY mesh or point cloud into a [`LabeledMesh`]; see [`mesh_from_ply`] for what
/// is read.
pub fn read_ply(path: impl AsRef<Path>) -> Result<LabeledMesh> {
    let path = path.as_ref();
    let ply = PlyFile::read(path)?;
    mesh_from_ply(&ply, path)
}

/// Writes `mesh` as PLY, atomically; see [`mesh_to_ply`] for the layout.
pub fn write_ply(path: impl AsRef<Path>, mesh: &LabeledMesh, encoding: PlyEncoding) -> Result<()> {
    write_mesh_file(path.as_ref(), mesh, None, encoding, None)
}

/// Writes `mesh` to `path` atomically as [`mesh_to_ply`] then [`PlyFile::write`] would, the
/// colours replaced by `colors` and the header recording `gravity` when given, streamed
/// ([`write_mesh_streamed`]).
pub(super) fn write_mesh_file(
    path: &Path,
    mesh: &LabeledMesh,
    colors: Option<&[[u8; 3]]>,
    encoding: PlyEncoding,
    gravity: Option<&MeshGravity>,
) -> Result<()> {
    let invalid = |m: String| DataError::InvalidArgument(format!("cannot write {}: {m}", path.display()));
    // Checks the mesh and its size as the whole conversion would, converting nothing.
    mesh.validate().map_err(invalid)?;
    if mesh.positions.len() > i32::MAX as usize {
        return Err(invalid(format!("{} vertices cannot be indexed by PLY 'int' indices", mesh.positions.len())));
    }
    if let Some(c) = colors.filter(|c| c.len() != mesh.positions.len()) {
        return Err(invalid(format!("{} colours for {} vertices", c.len(), mesh.positions.len())));
    }
    let comments = match gravity {
        Some(g) => g.comments().map_err(invalid)?,
        None => Vec::new(),
    };
    if let Some(c) = comments.iter().find(|c| c.contains(['\n', '\r'])) {
        return Err(invalid(format!("comment '{c}' contains a line break")));
    }
    let format = encoding.into();
    crate::atomic_file::write_atomic_with(path, |w| write_mesh_streamed(w, mesh, colors, &comments, format))
}

/// Writes `mesh` as PLY to `path`, and again to `recoloured_path` with the vertex colours
/// `colors` (e.g. class colours), both atomically: the same bytes as two [`write_ply`]
/// calls with a recoloured copy of the mesh, without the copy and without converting the
/// mesh whole (blocks of rows at a time: a whole home's mesh is gigabytes).
///
/// `gravity`, when given, is recorded in both headers ([`MeshGravity::comments`]).
///
/// # Errors
/// As [`write_ply`]; `colors` not one per vertex.
pub fn write_ply_recoloured(
    path: impl AsRef<Path>,
    recoloured_path: impl AsRef<Path>,
    mesh: &LabeledMesh,
    colors: &[[u8; 3]],
    encoding: PlyEncoding,
    gravity: Option<MeshGravity>,
) -> Result<()> {
    let (path, recoloured_path) = (path.as_ref(), recoloured_path.as_ref());
    if colors.len() != mesh.positions.len() {
        return Err(DataError::InvalidArgument(format!(
            "cannot write {}: {} colours for {} vertices",
            recoloured_path.display(),
            colors.len(),
            mesh.positions.len()
        )));
    }
    write_mesh_file(path, mesh, None, encoding, gravity.as_ref())?;
    write_mesh_file(recoloured_path, mesh, Some(colors), encoding, gravity.as_ref())
}

/// Converts a parsed PLY file into a [`LabeledMesh`]; `path` names the file in errors.
///
/// - `vertex` element with scalar `x`, `y`, `z` (any numeric type) is required; every
///   coordinate must be finite.
/// - `nx`, `ny`, `nz`: normals when all three are present (finite).
/// - `red`, `green`, `blue` (or `diffuse_red`, ...): integer channels are clamped to
///   0..=255, float channels are taken as 0..1 and scaled; `alpha` is ignored; vertices
///   without colour are grey (128, 128, 128).
/// - vertex `label` of any integer type: values 0..=254 are kept as they are (class ids are
///   0..13; larger values are kept so that other label sets survive, and
///   [`crate::SemanticClass::from_id`] rejects them); negative values and values above
///   254 become [`UNLABELED`].
/// - `face` element with a `vertex_indices` or `vertex_index` list of any integer type:
///   polygons are fan-triangulated (`v0 v_i v_(i+1)`); a polygon with fewer than 3
///   vertices or an index outside the vertices is an error. Face `label` (integer, same
///   mapping as vertex labels) labels every triangle of its polygon.
/// - Without a `face` element the result is a point cloud (no triangles). Other elements
///   are ignored.
/// - Fails (never panics) on a [`PlyFile`] assembled in code whose columns disagree with
///   the element counts.
pub fn mesh_from_ply(ply: &PlyFile, path: &Path) -> Result<LabeledMesh> {
    // A parsed file is consistent; one assembled in code may not be.
    ply.check().map_err(|m| DataError::parse(path, None, m))?;
    let vertex =
        ply.element("vertex").ok_or_else(|| DataError::parse(path, None, "PLY file has no 'vertex' element"))?;
    let row_err = |el: &Element, row: usize, msg: String| {
        let line = el.line_of_row(row);
        let at = if line.is_some() { String::new() } else { format!(" (element '{}' row {row})", el.name) };
        DataError::parse(path, line, format!("{msg}{at}"))
    };
    let coord = |name: &str| -> Result<Vec<f32>> {
        let col = vertex
            .scalar(name)
            .ok_or_else(|| DataError::parse(path, None, format!("element 'vertex' has no scalar property '{name}'")))?;
        Ok(col.to_f32_vec())
    };
    let (xs, ys, zs) = (coord("x")?, coord("y")?, coord("z")?);
    let positions: Vec<Vec3> = xs.iter().zip(&ys).zip(&zs).map(|((&x, &y), &z)| Vec3::new(x, y, z)).collect();
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(row_err(vertex, i, format!("vertex {i} has a non-finite position {}", positions[i])));
    }

    let normal_names = ["nx", "ny", "nz"];
    let present = normal_names.iter().filter(|n| vertex.scalar(n).is_some()).count();
    let normals = match present {
        0 => Vec::new(),
        3 => {
            let (nx, ny, nz) = (coord("nx")?, coord("ny")?, coord("nz")?);
            let normals: Vec<Vec3> = nx.iter().zip(&ny).zip(&nz).map(|((&x, &y), &z)| Vec3::new(x, y, z)).collect();
            if let Some(i) = normals.iter().position(|n| !n.is_finite()) {
                return Err(row_err(vertex, i, format!("vertex {i} has a non-finite normal {}", normals[i])));
            }
            normals
        }
        _ => return Err(DataError::parse(path, None, "element 'vertex' has some but not all of nx, ny, nz")),
    };

    let channel = |names: [&str; 2]| names.iter().find_map(|n| vertex.scalar(n)).map(color_channel);
    let colors =
        match (channel(["red", "diffuse_red"]), channel(["green", "diffuse_green"]), channel(["blue", "diffuse_blue"]))
        {
            (Some(r), Some(g), Some(b)) => r.iter().zip(&g).zip(&b).map(|((&r, &g), &b)| [r, g, b]).collect(),
            (None, None, None) => vec![[128, 128, 128]; positions.len()],
            _ => return Err(DataError::parse(path, None, "element 'vertex' has some but not all of red, green, blue")),
        };

    let vertex_labels = match vertex.property("label") {
        None => Vec::new(),
        Some(p) => label_column(&p.data).ok_or_else(|| {
            DataError::parse(path, None, "vertex property 'label' must be a scalar of an integer type")
        })?,
    };

    let mut triangles = Vec::new();
    let mut triangle_labels = Vec::new();
    if let Some(face) = ply.element("face") {
        let list = ["vertex_indices", "vertex_index"].iter().find_map(|n| face.property(n)).ok_or_else(|| {
            DataError::parse(path, None, "element 'face' has no 'vertex_indices' or 'vertex_index' property")
        })?;
        let PropertyData::List(list) = &list.data else {
            return Err(DataError::parse(path, None, format!("face property '{}' is not a list", list.name)));
        };
        if !list.values.scalar_type().is_integer() {
            return Err(DataError::parse(path, None, "face vertex indices are not of an integer type"));
        }
        let face_labels = match face.property("label") {
            None => None,
            Some(p) => Some(label_column(&p.data).ok_or_else(|| {
                DataError::parse(path, None, "face property 'label' must be a scalar of an integer type")
            })?),
        };
        let n = positions.len() as i64;
        // Pure triangle meshes (the usual case) convert in one pass per column; anything
        // else, or any bad index, goes through the general loop, which names the face.
        let all_triangles = list.offsets.iter().enumerate().all(|(i, &o)| o == 3 * i);
        let direct = if all_triangles { triangles_direct(&list.values, n) } else { None };
        if let Some(direct) = direct {
            triangles = direct;
            triangle_labels = face_labels.unwrap_or_default();
        } else {
            triangles.reserve(face.count);
            for row in 0..face.count {
                let range = list.row_range(row).unwrap_or(0..0);
                let len = range.len();
                if len < 3 {
                    return Err(row_err(
                        face,
                        row,
                        format!("face {row} has {len} vertices; a polygon needs at least 3"),
                    ));
                }
                let index = |k: usize| -> Result<u32> {
                    let v = list.values.get_i64(k).unwrap_or(-1);
                    if (0..n).contains(&v) {
                        Ok(v as u32)
                    } else {
                        Err(row_err(
                            face,
                            row,
                            format!("face {row} has vertex index {v}, out of range for {n} vertices"),
                        ))
                    }
                };
                let v0 = index(range.start)?;
                let mut prev = index(range.start + 1)?;
                for k in range.start + 2..range.end {
                    let v = index(k)?;
                    triangles.push([v0, prev, v]);
                    if let Some(l) = &face_labels {
                        triangle_labels.push(l[row]);
                    }
                    prev = v;
                }
            }
        }
    }
    let mesh = LabeledMesh { positions, colors, normals, vertex_labels, triangles, triangle_labels };
    debug_assert!(mesh.validate().is_ok());
    Ok(mesh)
}

/// Triangles from a flat index column of 3 items per face; `None` for float columns or
/// any index outside `0..n` (the caller then reports the exact face).
pub(super) fn triangles_direct(values: &Column, n: i64) -> Option<Vec<[u32; 3]>> {
    fn go<T: Copy + Into<i64>>(v: &[T], n: i64) -> Option<Vec<[u32; 3]>> {
        let ok = |x: T| {
            let x: i64 = x.into();
            (0..n).contains(&x).then_some(x as u32)
        };
        v.chunks_exact(3).map(|t| Some([ok(t[0])?, ok(t[1])?, ok(t[2])?])).collect()
    }
    match values {
        Column::Char(v) => go(v, n),
        Column::UChar(v) => go(v, n),
        Column::Short(v) => go(v, n),
        Column::UShort(v) => go(v, n),
        Column::Int(v) => go(v, n),
        Column::UInt(v) => go(v, n),
        Column::Float(_) | Column::Double(_) => None,
    }
}

/// Colour channel as u8: integers clamped to 0..=255, floats read as 0..1.
pub(super) fn color_channel(col: &Column) -> Vec<u8> {
    match col {
        Column::UChar(v) => v.clone(),
        Column::Float(_) | Column::Double(_) => {
            (0..col.len()).map(|i| (col.get_f64(i).unwrap_or(0.0) * 255.0).round().clamp(0.0, 255.0) as u8).collect()
        }
        _ => (0..col.len()).map(|i| col.get_i64(i).unwrap_or(0).clamp(0, 255) as u8).collect(),
    }
}

/// Integer labels as u8: 0..=254 kept, anything else [`UNLABELED`]; `None` for non-integer
/// or list data.
pub(super) fn label_column(data: &PropertyData) -> Option<Vec<u8>> {
    let PropertyData::Scalar(col) = data else { return None };
    if !col.scalar_type().is_integer() {
        return None;
    }
    Some(
        (0..col.len())
            .map(|i| match col.get_i64(i) {
                Some(v @ 0..=254) => v as u8,
                _ => UNLABELED,
            })
            .collect(),
    )
}

/// The PLY layout [`write_ply`] writes: vertex `x y z` float, `nx ny nz` float when the
/// mesh has normals, `red green blue` uchar, `label` uchar when it has vertex labels; face
/// (only when there are triangles) `vertex_indices` as `list uchar int`, and `label` uchar
/// when it has triangle labels. Fails when the mesh breaks its invariants or has more
/// vertices than an `int` index can address.
pub fn mesh_to_ply(mesh: &LabeledMesh) -> std::result::Result<PlyFile, String> {
    mesh.validate()?;
    let n = mesh.positions.len();
    if n > i32::MAX as usize {
        return Err(format!("{n} vertices cannot be indexed by PLY 'int' indices"));
    }
    Ok(mesh_block_to_ply(mesh, None, 0..n, 0..mesh.triangles.len()))
}

/// The rows `vertices` and `triangles` of `mesh` (validated, indexable by `int`) in the
/// layout of [`mesh_to_ply`], the colours replaced by `colors` when given (one per vertex):
/// the columns of a block of a file being written, with the element counts of the block.
/// Whether there is a face element depends on the whole mesh, so that every block has the
/// same elements.
fn mesh_block_to_ply(
    mesh: &LabeledMesh,
    colors: Option<&[[u8; 3]]>,
    vertices: Range<usize>,
    triangles: Range<usize>,
) -> PlyFile {
    let mut vertex = Element::new("vertex", vertices.len());
    let scalar = |name: &str, c: Column| Property { name: name.to_string(), data: PropertyData::Scalar(c) };
    let axis = |v: &[Vec3], k: usize| Column::Float(v[vertices.clone()].iter().map(|p| p[k]).collect());
    vertex.properties.push(scalar("x", axis(&mesh.positions, 0)));
    vertex.properties.push(scalar("y", axis(&mesh.positions, 1)));
    vertex.properties.push(scalar("z", axis(&mesh.positions, 2)));
    if !mesh.normals.is_empty() {
        vertex.properties.push(scalar("nx", axis(&mesh.normals, 0)));
        vertex.properties.push(scalar("ny", axis(&mesh.normals, 1)));
        vertex.properties.push(scalar("nz", axis(&mesh.normals, 2)));
    }
    let colors = &colors.unwrap_or(&mesh.colors)[vertices.clone()];
    for (k, name) in ["red", "green", "blue"].into_iter().enumerate() {
        vertex.properties.push(scalar(name, Column::UChar(colors.iter().map(|c| c[k]).collect())));
    }
    if !mesh.vertex_labels.is_empty() {
        vertex.properties.push(scalar("label", Column::UChar(mesh.vertex_labels[vertices].to_vec())));
    }
    let mut ply = PlyFile { comments: vec!["semrecon".into()], elements: vec![vertex], ..Default::default() };
    if !mesh.triangles.is_empty() || !mesh.triangle_labels.is_empty() {
        let mut face = Element::new("face", triangles.len());
        let list = ListColumn {
            count_type: ScalarType::UChar,
            offsets: (0..=triangles.len()).map(|i| 3 * i).collect(),
            values: Column::Int(mesh.triangles[triangles.clone()].iter().flat_map(|t| t.map(|i| i as i32)).collect()),
        };
        face.properties.push(Property { name: "vertex_indices".into(), data: PropertyData::List(list) });
        if !mesh.triangle_labels.is_empty() {
            face.properties.push(scalar("label", Column::UChar(mesh.triangle_labels[triangles].to_vec())));
        }
        ply.elements.push(face);
    }
    ply
}

/// Rows per block of [`write_mesh_streamed`]: a few MB of columns at a time.
pub(super) const STREAM_BLOCK_ROWS: usize = 1 << 16;

/// Writes `mesh` as [`mesh_to_ply`] then [`PlyFile::write`] would (the same bytes, with
/// `comments` after the first one and `colors` for the vertex colours when given) without
/// converting the whole mesh: blocks of rows at a time, so that writing a whole home's mesh
/// costs megabytes, not another copy of it.
pub(super) fn write_mesh_streamed(
    w: &mut dyn Write,
    mesh: &LabeledMesh,
    colors: Option<&[[u8; 3]]>,
    comments: &[String],
    format: PlyFormat,
) -> std::io::Result<()> {
    let mut header = mesh_block_to_ply(mesh, colors, 0..0, 0..0);
    header.comments.extend(comments.iter().cloned());
    header.elements[0].count = mesh.positions.len();
    if let Some(face) = header.elements.get_mut(1) {
        face.count = mesh.triangles.len();
    }
    header.write_header(w, format)?;
    let mut buf: Vec<u8> = Vec::with_capacity(super::ROW_FLUSH_BYTES + 4096);
    let blocks = |n: usize| (0..n).step_by(STREAM_BLOCK_ROWS).map(move |a| a..(a + STREAM_BLOCK_ROWS).min(n));
    for v in blocks(mesh.positions.len()) {
        mesh_block_to_ply(mesh, colors, v, 0..0).elements[0].write_rows(w, &mut buf, format)?;
    }
    if header.elements.len() > 1 {
        for t in blocks(mesh.triangles.len()) {
            mesh_block_to_ply(mesh, colors, 0..0, t).elements[1].write_rows(w, &mut buf, format)?;
        }
    }
    w.write_all(&buf)?;
    w.flush()
}
