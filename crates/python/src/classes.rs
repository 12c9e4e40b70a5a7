//! The 13 semantic classes (S3DIS order) and their colours, as module constants:
//! `CLASSES` (tuple of names, index = class id), `CLASS_COLORS` (uint8 array `[13, 3]`),
//! `UNLABELED` (255).

use pyo3::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_data::SemanticClass;

use crate::arrays::rows;

/// Adds the class constants to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    let names: Vec<&str> = SemanticClass::ALL.iter().map(|c| c.name()).collect();
    m.add("CLASSES", pyo3::types::PyTuple::new(py, names)?)?;
    let colors: Vec<u8> = SemanticClass::ALL.iter().flat_map(|c| c.color()).collect();
    let colors = rows(py, colors, 3)?;
    colors.call_method1("setflags", (false,))?;
    m.add("CLASS_COLORS", colors)?;
    m.add("UNLABELED", UNLABELED)?;
    Ok(())
}
