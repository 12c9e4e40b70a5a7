//! The sparse convolution engine ([`semrecon_sparse`]) for numpy: `ConvGeometry` is one
//! layer's geometry (the kernel map between an input and an output voxel set, and the chunk
//! plans of the fast kernels), built once per coordinate set and used by every layer on it,
//! forward and backward.
//!
//! Coordinates are int32 `(N, 4)` rows `(batch, x, y, z)` (spconv's order; batch 0 or 1, x, y,
//! z in `[-2^20, 2^20 - 1]`, distinct); features float32 `(N, C)`; weights float32
//! `(K^3, C_in, C_out)` with the offset numbering of [`semrecon_sparse::kernel_map`]
//! (submanifold: offset `(dx, dy, dz)` in `[-r, r]^3` is `((dz + r) K + dy + r) K + dx + r` and
//! output `u` reads input `u + (dx, dy, dz)`; strided: fine `u` feeds coarse `floor(u / 2)`
//! through offset `dx + 2 dy + 4 dz` with `d = u - 2 floor(u / 2)`; transposed: the same pairs
//! from coarse to fine).

use numpy::{PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadwriteArrayDyn};
use pyo3::prelude::*;
use semrecon_sparse::{ChunkConfig, ChunkedConv, Coord, KernelMap, MapKind};

use crate::arrays::{rows, shaped, typed};
use crate::errors::{sparse_err, value_error};

/// The coordinates argument `arg` as Rust coordinates `[x, y, z, batch]`.
fn coords_arg(arg: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<Coord>> {
    let c = typed::<i32>(arg, obj, "int32", &[None, Some(4)], "(N, 4) rows (batch, x, y, z)")?;
    Ok(c.slice().chunks_exact(4).map(|r| [r[1], r[2], r[3], r[0]]).collect())
}

/// Rust coordinates as an int32 `(N, 4)` array of rows `(batch, x, y, z)`.
fn coords_array<'py>(py: Python<'py>, coords: &[Coord]) -> PyResult<Bound<'py, PyArray2<i32>>> {
    rows(py, coords.iter().flat_map(|c| [c[3], c[0], c[1], c[2]]).collect(), 4)
}

/// The `out` argument: a writeable, C-contiguous, aligned float32 `(rows, cols)` array.
fn writable<'py>(out: &Bound<'py, PyAny>, rows: usize, cols: usize) -> PyResult<PyReadwriteArrayDyn<'py, f32>> {
    // The checks of `typed` (dtype, shape, contiguity, alignment), then writeability.
    typed::<f32>("out", out, "float32", &[Some(rows), Some(cols)], &format!("({rows}, {cols})"))?;
    let array = out.cast::<PyArrayDyn<f32>>().map_err(|_| value_error("out", "expected a float32 array"))?;
    array.try_readwrite().map_err(|_| value_error("out", "the array is not writeable (or is borrowed)"))
}

/// `(in_rows, out_rows)` of one kernel offset.
type RowPairs<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>);

/// The geometry of one sparse convolution layer; see the module documentation.
#[pyclass(frozen, module = "semrecon")]
pub struct ConvGeometry {
    conv: ChunkedConv,
    in_coords: Vec<Coord>,
    out_coords: Vec<Coord>,
}

impl ConvGeometry {
    fn kv(&self) -> usize {
        self.conv.forward_plan().kernel_volume()
    }

    /// Checks a feature array `(rows, ?)` and returns it with its channel count.
    fn features<'py>(
        &self,
        arg: &str,
        obj: &Bound<'py, PyAny>,
        rows: usize,
        side: &str,
    ) -> PyResult<(crate::arrays::Checked<'py, f32>, usize)> {
        let a =
            typed::<f32>(arg, obj, "float32", &[Some(rows), None], &format!("({rows}, C), one row per {side} voxel"))?;
        let c = a.shape[1];
        Ok((a, c))
    }

    /// Checks a weight array `(K^3, c_in, c_out)` (either channel count may be `None`).
    fn weight<'py>(
        &self,
        obj: &Bound<'py, PyAny>,
        c_in: Option<usize>,
        c_out: Option<usize>,
    ) -> PyResult<crate::arrays::Checked<'py, f32>> {
        let kv = self.kv();
        let show = |c: Option<usize>, name: &str| c.map_or(name.to_string(), |c| c.to_string());
        typed::<f32>(
            "weight",
            obj,
            "float32",
            &[Some(kv), c_in, c_out],
            &format!("({kv}, {}, {})", show(c_in, "C_in"), show(c_out, "C_out")),
        )
    }
}

#[pymethods]
impl ConvGeometry {
    /// The submanifold layer of `coords` (output set = input set) with an odd `kernel_size`.
    #[staticmethod]
    #[pyo3(signature = (coords, kernel_size = 3))]
    fn submanifold(py: Python<'_>, coords: &Bound<'_, PyAny>, kernel_size: usize) -> PyResult<Self> {
        let coords = coords_arg("coords", coords)?;
        let conv = py
            .detach(|| ChunkedConv::submanifold(&coords, kernel_size, &ChunkConfig::default()))
            .map_err(sparse_err)?;
        Ok(Self { conv, in_coords: coords.clone(), out_coords: coords })
    }

    /// The strided layer (kernel 2, stride 2) from `coords` to the coarse set
    /// `{floor(u / 2)}` (`out_coords`, in order of first appearance).
    #[staticmethod]
    fn downsample(py: Python<'_>, coords: &Bound<'_, PyAny>) -> PyResult<Self> {
        let fine = coords_arg("coords", coords)?;
        let (conv, coarse) = py
            .detach(|| {
                let (coarse, map) = KernelMap::downsample(&fine)?;
                ChunkedConv::new(map, &fine, &coarse, &ChunkConfig::default()).map(|c| (c, coarse))
            })
            .map_err(sparse_err)?;
        Ok(Self { conv, in_coords: fine, out_coords: coarse })
    }

    /// The transposed layer (kernel 2, stride 2) from `coarse` back to `fine`; every fine
    /// voxel's parent `floor(u / 2)` must be in `coarse`.
    #[staticmethod]
    fn upsample(py: Python<'_>, coarse: &Bound<'_, PyAny>, fine: &Bound<'_, PyAny>) -> PyResult<Self> {
        let coarse = coords_arg("coarse", coarse)?;
        let fine = coords_arg("fine", fine)?;
        let conv = py
            .detach(|| {
                let map = KernelMap::upsample(&coarse, &fine)?;
                ChunkedConv::new(map, &coarse, &fine, &ChunkConfig::default())
            })
            .map_err(sparse_err)?;
        Ok(Self { conv, in_coords: coarse, out_coords: fine })
    }

    /// The transposed layer of a strided one (down <-> up over the same two sets), sharing
    /// its plans; a submanifold layer is its own transpose.
    fn transposed(&self) -> Self {
        let conv = self.conv.transposed().unwrap_or_else(|| self.conv.clone());
        Self { conv, in_coords: self.out_coords.clone(), out_coords: self.in_coords.clone() }
    }

    /// `"submanifold"`, `"down"` or `"up"`.
    #[getter]
    fn kind(&self) -> &'static str {
        match self.conv.map().kind() {
            MapKind::Submanifold { .. } => "submanifold",
            MapKind::Down => "down",
            MapKind::Up => "up",
        }
    }
    /// Kernel offsets (`K^3`).
    #[getter]
    fn kernel_volume(&self) -> usize {
        self.kv()
    }
    /// Rows of the input set.
    #[getter]
    fn n_in(&self) -> usize {
        self.conv.n_in()
    }
    /// Rows of the output set.
    #[getter]
    fn n_out(&self) -> usize {
        self.conv.n_out()
    }
    /// (input, output) pairs over all offsets.
    #[getter]
    fn num_pairs(&self) -> usize {
        self.conv.num_pairs()
    }
    /// Input voxels, int32 `(n_in, 4)` rows `(batch, x, y, z)`.
    #[getter]
    fn in_coords<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i32>>> {
        coords_array(py, &self.in_coords)
    }
    /// Output voxels, int32 `(n_out, 4)` rows `(batch, x, y, z)`.
    #[getter]
    fn out_coords<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i32>>> {
        coords_array(py, &self.out_coords)
    }

    /// The pairs of offset `k`: `(in_rows, out_rows)`, int64 `(P,)` each.
    fn pairs<'py>(&self, py: Python<'py>, k: usize) -> PyResult<RowPairs<'py>> {
        if k >= self.kv() {
            return Err(value_error("k", format!("offset {k} of a kernel with {} offsets", self.kv())));
        }
        let (ins, outs) = self.conv.map().pairs(k);
        let cast = |v: &[u32]| PyArray1::from_vec(py, v.iter().map(|&r| i64::from(r)).collect());
        Ok((cast(ins), cast(outs)))
    }

    /// Forward: `features` float32 `(n_in, C_in)`, `weight` float32 `(K^3, C_in, C_out)` ->
    /// float32 `(n_out, C_out)`, written into `out` when given (a C-contiguous, writeable
    /// float32 array of that shape, kept between calls as a training loop would).
    #[pyo3(signature = (features, weight, *, out = None))]
    fn forward<'py>(
        &self,
        py: Python<'py>,
        features: &Bound<'py, PyAny>,
        weight: &Bound<'py, PyAny>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (x, c_in) = self.features("features", features, self.conv.n_in(), "input")?;
        let w = self.weight(weight, Some(c_in), None)?;
        let c_out = w.shape[2];
        let (xs, ws) = (x.slice(), w.slice());
        let Some(out) = out else {
            let y = py.detach(|| self.conv.forward(xs, c_in, ws, c_out)).map_err(sparse_err)?;
            return Ok(shaped(py, y, &[self.conv.n_out(), c_out])?.into_any());
        };
        let mut y = writable(out, self.conv.n_out(), c_out)?;
        let ys = y.as_slice_mut().map_err(|_| value_error("out", "not a contiguous array"))?;
        py.detach(|| self.conv.forward_into(xs, c_in, ws, c_out, ys)).map_err(sparse_err)?;
        drop(y);
        Ok(out.clone())
    }

    /// Gradient of the input: `grad_out` float32 `(n_out, C_out)`, `weight` float32
    /// `(K^3, C_in, C_out)` -> float32 `(n_in, C_in)`.
    fn backward_input<'py>(
        &self,
        py: Python<'py>,
        grad_out: &Bound<'py, PyAny>,
        weight: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (dy, c_out) = self.features("grad_out", grad_out, self.conv.n_out(), "output")?;
        let w = self.weight(weight, None, Some(c_out))?;
        let c_in = w.shape[1];
        let (dys, ws) = (dy.slice(), w.slice());
        let dx = py.detach(|| self.conv.backward_input(dys, c_out, ws, c_in)).map_err(sparse_err)?;
        shaped(py, dx, &[self.conv.n_in(), c_in])
    }

    /// Gradient of the weight: `features` float32 `(n_in, C_in)`, `grad_out` float32
    /// `(n_out, C_out)` -> float32 `(K^3, C_in, C_out)`.
    fn backward_weight<'py>(
        &self,
        py: Python<'py>,
        features: &Bound<'py, PyAny>,
        grad_out: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (x, c_in) = self.features("features", features, self.conv.n_in(), "input")?;
        let (dy, c_out) = self.features("grad_out", grad_out, self.conv.n_out(), "output")?;
        let (xs, dys) = (x.slice(), dy.slice());
        let dw = py.detach(|| self.conv.backward_weight(xs, c_in, dys, c_out)).map_err(sparse_err)?;
        shaped(py, dw, &[self.kv(), c_in, c_out])
    }

    fn __repr__(&self) -> String {
        format!(
            "ConvGeometry(kind={:?}, n_in={}, n_out={}, kernel_volume={}, pairs={})",
            self.kind(),
            self.conv.n_in(),
            self.conv.n_out(),
            self.kv(),
            self.conv.num_pairs()
        )
    }
}

/// Adds the class to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<ConvGeometry>()?;
    Ok(())
}
