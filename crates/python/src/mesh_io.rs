//! PLY files ([`semrecon_data::ply`]): `write_ply(path, mesh)` writes a mesh dict (the layout
//! `Pipeline.mesh()` returns: `vertices`, and optionally `faces`, `colors`, `labels`,
//! `normals`) with a vertex `label` property; `read_ply(path)` reads any PLY mesh or point
//! cloud back into that layout. Meshes written by `semrecon run` record where gravity points
//! in their frame: `read_ply` returns it as `up` (3 floats) and `floor_height` (float or
//! `None`), and `write_ply` records a dict's `up` / `floor_height` when present.

use glam::Vec3;
use pyo3::exceptions::{PyKeyError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use semrecon_data::{LabeledMesh, MeshGravity, PlyEncoding};

use crate::arrays::{require_finite, typed};
use crate::errors::{data_err, value_error};

/// Face indices as `u32`: int32, int64 or uint32 `(F, 3)`, each in `0..n_vertices`.
fn faces_arg(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<[u32; 3]>> {
    let shape = [None, Some(3)];
    let flat: Vec<i64> = if let Ok(a) = typed::<i32>("mesh['faces']", obj, "int32", &shape, "(F, 3)") {
        a.slice().iter().map(|&v| i64::from(v)).collect()
    } else if let Ok(a) = typed::<i64>("mesh['faces']", obj, "int64", &shape, "(F, 3)") {
        a.slice().to_vec()
    } else {
        // The error of the last try names the shape or the dtype wanted.
        typed::<u32>("mesh['faces']", obj, "uint32", &shape, "(F, 3) of int32, int64 or uint32")?
            .slice()
            .iter()
            .map(|&v| i64::from(v))
            .collect()
    };
    if let Some(i) = flat.iter().position(|&v| v < 0 || v as u64 >= n as u64) {
        return Err(value_error(
            "mesh['faces']",
            format!("face {} has vertex index {}, outside 0..{n}", i / 3, flat[i]),
        ));
    }
    Ok(flat.chunks_exact(3).map(|f| [f[0] as u32, f[1] as u32, f[2] as u32]).collect())
}

/// The mesh dict as a [`LabeledMesh`].
fn mesh_arg(mesh: &Bound<'_, PyDict>) -> PyResult<LabeledMesh> {
    let vertices = mesh.get_item("vertices")?.ok_or_else(|| PyKeyError::new_err("mesh: no 'vertices' entry"))?;
    let v = typed::<f32>("mesh['vertices']", &vertices, "float32", &[None, Some(3)], "(V, 3)")?;
    require_finite("mesh['vertices']", v.slice())?;
    let n = v.shape[0];
    let positions: Vec<Vec3> = v.slice().chunks_exact(3).map(Vec3::from_slice).collect();
    let get = |key: &str| -> PyResult<Option<Bound<'_, PyAny>>> { Ok(mesh.get_item(key)?.filter(|o| !o.is_none())) };
    let triangles = match get("faces")? {
        Some(f) => faces_arg(&f, n)?,
        None => Vec::new(),
    };
    let colors = match get("colors")? {
        Some(c) => typed::<u8>("mesh['colors']", &c, "uint8", &[Some(n), Some(3)], &format!("({n}, 3)"))?
            .slice()
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        None => vec![[128; 3]; n],
    };
    let vertex_labels = match get("labels")? {
        Some(l) => typed::<u8>("mesh['labels']", &l, "uint8", &[Some(n)], &format!("({n},)"))?.slice().to_vec(),
        None => Vec::new(),
    };
    let normals = match get("normals")? {
        Some(nm) => {
            let a = typed::<f32>("mesh['normals']", &nm, "float32", &[None, Some(3)], &format!("({n}, 3) or (0, 3)"))?;
            if a.shape[0] != 0 && a.shape[0] != n {
                return Err(value_error(
                    "mesh['normals']",
                    format!("expected shape ({n}, 3) or (0, 3), got {:?}", a.shape),
                ));
            }
            require_finite("mesh['normals']", a.slice())?;
            a.slice().chunks_exact(3).map(Vec3::from_slice).collect()
        }
        None => Vec::new(),
    };
    Ok(LabeledMesh { positions, colors, normals, vertex_labels, triangles, triangle_labels: Vec::new() })
}

/// `mesh['up']` (3 finite numbers, not all zero) and `mesh['floor_height']` (a finite number),
/// when present and not `None`.
fn gravity_arg(dict: &Bound<'_, PyDict>) -> PyResult<Option<MeshGravity>> {
    let Some(up) = dict.get_item("up")?.filter(|u| !u.is_none()) else { return Ok(None) };
    let v: Vec<f32> = up.extract().map_err(|_| value_error("mesh['up']", "expected 3 numbers"))?;
    let up = match v[..] {
        [x, y, z] => Vec3::new(x, y, z),
        _ => return Err(value_error("mesh['up']", format!("expected 3 numbers, got {}", v.len()))),
    };
    if !(up.is_finite() && up.length() > 1e-6) {
        return Err(value_error("mesh['up']", format!("{up} is not a direction")));
    }
    let floor_height = match dict.get_item("floor_height")?.filter(|f| !f.is_none()) {
        None => None,
        Some(f) => {
            let h: f32 = f.extract().map_err(|_| value_error("mesh['floor_height']", "expected a number"))?;
            if !h.is_finite() {
                return Err(value_error("mesh['floor_height']", format!("{h} is not finite")));
            }
            Some(h)
        }
    };
    Ok(Some(MeshGravity { up, floor_height }))
}

/// `write_ply(path, mesh, *, binary=True)`: writes a mesh dict as PLY (binary little endian,
/// or ASCII), atomically; the dict's `up` and `floor_height`, when present, are recorded in
/// the header.
#[pyfunction]
#[pyo3(signature = (path, mesh, *, binary = true))]
fn write_ply(py: Python<'_>, path: std::path::PathBuf, mesh: &Bound<'_, PyAny>, binary: bool) -> PyResult<()> {
    let dict = mesh.cast::<PyDict>().map_err(|_| {
        PyTypeError::new_err("mesh: expected a dict with 'vertices' (and 'faces', 'colors', 'labels', 'normals')")
    })?;
    let m = mesh_arg(dict)?;
    let gravity = gravity_arg(dict)?;
    let encoding = if binary { PlyEncoding::BinaryLittleEndian } else { PlyEncoding::Ascii };
    py.detach(|| match gravity {
        Some(g) => semrecon_data::write_ply_with_gravity(&path, &m, encoding, &g),
        None => semrecon_data::write_ply(&path, &m, encoding),
    })
    .map_err(data_err)
}

/// `read_ply(path)`: a PLY mesh or point cloud as a mesh dict, with `up` and `floor_height`
/// when the file records them.
#[pyfunction]
fn read_ply<'py>(py: Python<'py>, path: std::path::PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let (mesh, gravity) = py.detach(|| semrecon_data::read_ply_with_gravity(&path)).map_err(data_err)?;
    let d = crate::pipeline::mesh_dict(py, mesh)?;
    if let Some(g) = gravity {
        d.set_item("up", (g.up.x, g.up.y, g.up.z))?;
        d.set_item("floor_height", g.floor_height)?;
    }
    Ok(d)
}

/// Adds the functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(write_ply, m)?)?;
    m.add_function(wrap_pyfunction!(read_ply, m)?)?;
    Ok(())
}
