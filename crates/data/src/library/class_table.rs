//! The reviewed class table `crates/data/furniture_classes.tsv`: for every model of the five
//! catalogues, its S3DIS class, a fine category (for ScanNet-style class sets later), whether
//! it belongs inside a room at all (`use`), and its train / held-out split. The table is
//! compiled into the crate, so the library works from any working directory, and a model
//! the table does not cover is never used silently (the mapping test lists it).

use std::sync::OnceLock;

use crate::class::SemanticClass;
use crate::error::{DataError, Result};

use super::Split;

/// The table's text, as committed.
pub const CLASS_TABLE_TSV: &str = include_str!("../../furniture_classes.tsv");

/// The header line the table must start with.
pub const CLASS_TABLE_HEADER: &str = "catalogue\tid\tname\tfine\tclass\tuse\tsplit";

/// One row of the class table.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassRow {
    /// Catalogue file stem.
    pub catalogue: String,
    /// Model id.
    pub id: String,
    /// Display name (for the reviewer; not used).
    pub name: String,
    /// Fine category (`bed`, `office_chair`, ...).
    pub fine: String,
    /// S3DIS class.
    pub class: SemanticClass,
    /// Whether the model may be placed in a room.
    pub used: bool,
    /// Train or held out.
    pub split: Split,
}

/// Parses a class table (`CLASS_TABLE_HEADER` then one tab-separated row per model).
pub fn parse_class_table(text: &str) -> Result<Vec<ClassRow>> {
    let path = "crates/data/furniture_classes.tsv";
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim_end() == CLASS_TABLE_HEADER => {}
        _ => return Err(DataError::parse(path, Some(1), format!("the header must be {CLASS_TABLE_HEADER:?}"))),
    }
    let mut rows = Vec::new();
    for (i, line) in lines {
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        let err = |m: String| DataError::parse(path, Some(i + 1), m);
        let f: Vec<&str> = line.split('\t').collect();
        if f.len() != 7 {
            return Err(err(format!("{} columns, 7 expected", f.len())));
        }
        let class = SemanticClass::from_name(f[4]).ok_or_else(|| err(format!("unknown class {:?}", f[4])))?;
        let used = match f[5] {
            "yes" => true,
            "no" => false,
            o => return Err(err(format!("use must be yes or no, not {o:?}"))),
        };
        let split = match f[6] {
            "train" => Split::Train,
            "held_out" => Split::HeldOut,
            o => return Err(err(format!("split must be train or held_out, not {o:?}"))),
        };
        rows.push(ClassRow {
            catalogue: f[0].to_string(),
            id: f[1].to_string(),
            name: f[2].to_string(),
            fine: f[3].to_string(),
            class,
            used,
            split,
        });
    }
    Ok(rows)
}

/// The committed table, parsed once.
pub fn class_table() -> Result<&'static [ClassRow]> {
    static TABLE: OnceLock<std::result::Result<Vec<ClassRow>, String>> = OnceLock::new();
    match TABLE.get_or_init(|| parse_class_table(CLASS_TABLE_TSV).map_err(|e| e.to_string())) {
        Ok(rows) => Ok(rows),
        Err(m) => Err(DataError::parse("crates/data/furniture_classes.tsv", None, m.clone())),
    }
}
