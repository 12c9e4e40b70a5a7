//! PLY (Stanford polygon file format) reading and writing, at two levels.
//!
//! The low level ([`PlyFile`]) keeps every element and every property of a file as typed
//! columns (one `Vec` per scalar property, offsets + values per list property), so that a
//! command can add or replace one property (a vertex `label`) and rewrite the file with all
//! the others intact. It reads `ascii`, `binary_little_endian` and `binary_big_endian`
//! bodies and writes `ascii` and `binary_little_endian` ones. The high level
//! ([`read_ply`], [`write_ply`], [`mesh_from_ply`], [`mesh_to_ply`]) converts to and from a
//! [`LabeledMesh`].
//!
//! Hand-written rather than taken from a crate because (1) every malformed input must give
//! an exact [`DataError::Parse`] naming the file, the header or body line (ASCII) or the
//! element, row and property (binary), never a panic; (2) column storage keeps
//! multi-million-vertex meshes fast: fixed-size binary rows are decoded column by column
//! with one tight loop each, with no per-value allocation or dynamic dispatch; (3) the
//! format is small enough that a dependency would cost more than it saves.
//!
//! Hostile headers cannot make the reader allocate: a header may claim 10^12 vertices, but
//! no buffer is reserved beyond what the bytes actually present in the file can fill, so
//! such a file fails with "truncated" after reading what is there.

use std::fmt::Display;
use std::io::Write;
use std::ops::Range;
use std::path::Path;

mod gravity;
mod mesh;
mod reader;
pub use gravity::{read_ply_with_gravity, write_ply_with_gravity, MeshGravity};
pub use mesh::{mesh_from_ply, mesh_to_ply, read_ply, write_ply, write_ply_recoloured};

use glam::Vec3;

use crate::class::UNLABELED;
use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;
use reader::{parse_header, read_ascii_element, read_binary_element, AsciiCursor};

/// The scalar types of PLY properties.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ScalarType {
    /// `char` / `int8`.
    Char,
    /// `uchar` / `uint8`.
    UChar,
    /// `short` / `int16`.
    Short,
    /// `ushort` / `uint16`.
    UShort,
    /// `int` / `int32`.
    Int,
    /// `uint` / `uint32`.
    UInt,
    /// `float` / `float32`.
    Float,
    /// `double` / `float64`.
    Double,
}

impl ScalarType {
    /// Parses a PLY type name, including the sized aliases (`uint8`, `float32`, ...).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::Char,
            "uchar" | "uint8" => Self::UChar,
            "short" | "int16" => Self::Short,
            "ushort" | "uint16" => Self::UShort,
            "int" | "int32" => Self::Int,
            "uint" | "uint32" => Self::UInt,
            "float" | "float32" => Self::Float,
            "double" | "float64" => Self::Double,
            _ => return None,
        })
    }

    /// The classic PLY name of the type, as written in headers.
    pub fn name(self) -> &'static str {
        match self {
            Self::Char => "char",
            Self::UChar => "uchar",
            Self::Short => "short",
            Self::UShort => "ushort",
            Self::Int => "int",
            Self::UInt => "uint",
            Self::Float => "float",
            Self::Double => "double",
        }
    }

    /// Size in bytes in binary bodies.
    pub fn size(self) -> usize {
        match self {
            Self::Char | Self::UChar => 1,
            Self::Short | Self::UShort => 2,
            Self::Int | Self::UInt | Self::Float => 4,
            Self::Double => 8,
        }
    }

    /// Whether the type is an integer type (list counts and indices must be).
    pub fn is_integer(self) -> bool {
        !matches!(self, Self::Float | Self::Double)
    }

    /// Range of an integer type (list counts); `None` for float types.
    fn int_range(self) -> Option<(i64, i64)> {
        Some(match self {
            Self::Char => (i8::MIN.into(), i8::MAX.into()),
            Self::UChar => (0, u8::MAX.into()),
            Self::Short => (i16::MIN.into(), i16::MAX.into()),
            Self::UShort => (0, u16::MAX.into()),
            Self::Int => (i32::MIN.into(), i32::MAX.into()),
            Self::UInt => (0, u32::MAX.into()),
            Self::Float | Self::Double => return None,
        })
    }

    /// Decodes a binary integer of this type (`b.len()` = size); `None` for float types.
    #[inline]
    fn decode_int(self, b: &[u8], big: bool) -> Option<i64> {
        Some(match self {
            Self::Char => i8::from_bytes(b, big).into(),
            Self::UChar => u8::from_bytes(b, big).into(),
            Self::Short => i16::from_bytes(b, big).into(),
            Self::UShort => u16::from_bytes(b, big).into(),
            Self::Int => i32::from_bytes(b, big).into(),
            Self::UInt => u32::from_bytes(b, big).into(),
            Self::Float | Self::Double => return None,
        })
    }

    /// Parses a text integer of this type; `None` when it is not one or out of range.
    fn parse_int(self, token: &str) -> Option<i64> {
        let (lo, hi) = self.int_range()?;
        token.parse::<i64>().ok().filter(|v| (lo..=hi).contains(v))
    }
}

/// The encoding of a PLY body as declared by the `format` header line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
    /// `format binary_big_endian 1.0`.
    BinaryBigEndian,
}

impl PlyFormat {
    fn name(self) -> &'static str {
        match self {
            Self::Ascii => "ascii",
            Self::BinaryLittleEndian => "binary_little_endian",
            Self::BinaryBigEndian => "binary_big_endian",
        }
    }
}

/// The encodings this module writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Text; floats printed so that they parse back to the same bits.
    Ascii,
    /// Binary little endian: compact and fast.
    BinaryLittleEndian,
}

impl From<PlyEncoding> for PlyFormat {
    fn from(e: PlyEncoding) -> Self {
        match e {
            PlyEncoding::Ascii => Self::Ascii,
            PlyEncoding::BinaryLittleEndian => Self::BinaryLittleEndian,
        }
    }
}

/// Decoding, encoding and text formatting of one PLY scalar type.
trait PlyScalar: Copy + std::str::FromStr + Display {
    const SIZE: usize;
    /// `b.len() == SIZE`.
    fn from_bytes(b: &[u8], big_endian: bool) -> Self;
    fn put(self, out: &mut Vec<u8>, big_endian: bool);
}

macro_rules! impl_scalar {
    ($($t:ty),*) => {$(
        impl PlyScalar for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            #[inline]
            fn from_bytes(b: &[u8], big_endian: bool) -> Self {
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(b);
                if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
            }
            #[inline]
            fn put(self, out: &mut Vec<u8>, big_endian: bool) {
                if big_endian {
                    out.extend_from_slice(&self.to_be_bytes())
                } else {
                    out.extend_from_slice(&self.to_le_bytes())
                }
            }
        }
    )*};
}
impl_scalar!(i8, u8, i16, u16, i32, u32, f32, f64);

/// The values of one scalar property (or the flattened items of a list property), one
/// `Vec` per PLY type.
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)]
pub enum Column {
    Char(Vec<i8>),
    UChar(Vec<u8>),
    Short(Vec<i16>),
    UShort(Vec<u16>),
    Int(Vec<i32>),
    UInt(Vec<u32>),
    Float(Vec<f32>),
    Double(Vec<f64>),
}

/// Runs `$body` with `$v` bound to the inner `Vec` of a column, whatever its type.
macro_rules! with_column {
    ($col:expr, $v:ident => $body:expr) => {
        match $col {
            Column::Char($v) => $body,
            Column::UChar($v) => $body,
            Column::Short($v) => $body,
            Column::UShort($v) => $body,
            Column::Int($v) => $body,
            Column::UInt($v) => $body,
            Column::Float($v) => $body,
            Column::Double($v) => $body,
        }
    };
}

impl Column {
    /// An empty column of type `ty` with room for `capacity` values.
    pub fn with_capacity(ty: ScalarType, capacity: usize) -> Self {
        match ty {
            ScalarType::Char => Self::Char(Vec::with_capacity(capacity)),
            ScalarType::UChar => Self::UChar(Vec::with_capacity(capacity)),
            ScalarType::Short => Self::Short(Vec::with_capacity(capacity)),
            ScalarType::UShort => Self::UShort(Vec::with_capacity(capacity)),
            ScalarType::Int => Self::Int(Vec::with_capacity(capacity)),
            ScalarType::UInt => Self::UInt(Vec::with_capacity(capacity)),
            ScalarType::Float => Self::Float(Vec::with_capacity(capacity)),
            ScalarType::Double => Self::Double(Vec::with_capacity(capacity)),
        }
    }

    /// The PLY type of the values.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            Self::Char(_) => ScalarType::Char,
            Self::UChar(_) => ScalarType::UChar,
            Self::Short(_) => ScalarType::Short,
            Self::UShort(_) => ScalarType::UShort,
            Self::Int(_) => ScalarType::Int,
            Self::UInt(_) => ScalarType::UInt,
            Self::Float(_) => ScalarType::Float,
            Self::Double(_) => ScalarType::Double,
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        with_column!(self, v => v.len())
    }

    /// Whether the column holds no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` as `f64` (exact for every PLY type); `None` past the end.
    #[allow(clippy::useless_conversion)] // the macro also expands the f64 arm
    pub fn get_f64(&self, i: usize) -> Option<f64> {
        with_column!(self, v => v.get(i).map(|&x| f64::from(x)))
    }

    /// Value `i` of an integer column as `i64`; `None` past the end or for float columns.
    pub fn get_i64(&self, i: usize) -> Option<i64> {
        match self {
            Self::Char(v) => v.get(i).map(|&x| x as i64),
            Self::UChar(v) => v.get(i).map(|&x| x as i64),
            Self::Short(v) => v.get(i).map(|&x| x as i64),
            Self::UShort(v) => v.get(i).map(|&x| x as i64),
            Self::Int(v) => v.get(i).map(|&x| x as i64),
            Self::UInt(v) => v.get(i).map(|&x| x as i64),
            Self::Float(_) | Self::Double(_) => None,
        }
    }

    /// All values converted to `f32` (rounded for `double`, exact for the others up to
    /// 2^24).
    #[allow(clippy::unnecessary_cast)] // the macro also expands the f32 arm
    pub fn to_f32_vec(&self) -> Vec<f32> {
        match self {
            Self::Float(v) => v.clone(),
            Self::Double(v) => v.iter().map(|&x| x as f32).collect(),
            _ => with_column!(self, v => v.iter().map(|&x| x as f32).collect()),
        }
    }

    /// Appends one value decoded from `b` (`b.len()` = the type's size).
    #[inline]
    fn push_bytes(&mut self, b: &[u8], big_endian: bool) {
        with_column!(self, v => v.push(PlyScalar::from_bytes(b, big_endian)))
    }

    /// Appends the values packed in `b` (a multiple of the type's size), with one type
    /// dispatch for all of them.
    #[inline]
    fn extend_from_bytes(&mut self, b: &[u8], big_endian: bool) {
        fn go<T: PlyScalar>(v: &mut Vec<T>, b: &[u8], big: bool) {
            v.extend(b.chunks_exact(T::SIZE).map(|c| T::from_bytes(c, big)));
        }
        with_column!(self, v => go(v, b, big_endian))
    }

    /// Appends one value parsed from ASCII text; the error says why it does not parse.
    fn push_text(&mut self, token: &str) -> std::result::Result<(), String> {
        fn parse<T: std::str::FromStr>(v: &mut Vec<T>, token: &str, ty: ScalarType) -> std::result::Result<(), String> {
            let x = token.parse::<T>().map_err(|_| format!("'{token}' is not a valid {} value", ty.name()))?;
            v.push(x);
            Ok(())
        }
        let ty = self.scalar_type();
        with_column!(self, v => parse(v, token, ty))
    }

    /// Value `i` in binary.
    #[inline]
    fn put_binary(&self, i: usize, out: &mut Vec<u8>, big_endian: bool) {
        with_column!(self, v => v[i].put(out, big_endian))
    }

    /// Value `i` as text; `Display` of Rust floats prints the shortest string that parses
    /// back to the same bits, which makes ASCII round trips exact.
    #[inline]
    fn put_text(&self, i: usize, out: &mut Vec<u8>) {
        // Writing into a Vec cannot fail.
        let _ = with_column!(self, v => write!(out, "{}", v[i]));
    }

    /// Decodes the values of one property from fixed-size rows: `count` rows of `stride`
    /// bytes, the value at byte `offset` of each row. `body.len() >= count * stride`.
    fn decode_strided(ty: ScalarType, body: &[u8], count: usize, stride: usize, offset: usize, big: bool) -> Self {
        fn go<T: PlyScalar>(body: &[u8], count: usize, stride: usize, offset: usize, big: bool) -> Vec<T> {
            body.chunks_exact(stride)
                .take(count)
                .map(|row| T::from_bytes(&row[offset..offset + T::SIZE], big))
                .collect()
        }
        match ty {
            ScalarType::Char => Self::Char(go(body, count, stride, offset, big)),
            ScalarType::UChar => Self::UChar(go(body, count, stride, offset, big)),
            ScalarType::Short => Self::Short(go(body, count, stride, offset, big)),
            ScalarType::UShort => Self::UShort(go(body, count, stride, offset, big)),
            ScalarType::Int => Self::Int(go(body, count, stride, offset, big)),
            ScalarType::UInt => Self::UInt(go(body, count, stride, offset, big)),
            ScalarType::Float => Self::Float(go(body, count, stride, offset, big)),
            ScalarType::Double => Self::Double(go(body, count, stride, offset, big)),
        }
    }
}

/// A list property: row `i` holds `values[offsets[i]..offsets[i + 1]]`.
///
/// # Shapes
/// `offsets`: rows + 1 entries, starting at 0, non-decreasing, ending at `values.len()`.
#[derive(Debug, Clone, PartialEq)]
pub struct ListColumn {
    /// Type of the per-row item count in the file (`uchar` for most face lists).
    pub count_type: ScalarType,
    /// Row boundaries into `values`.
    pub offsets: Vec<usize>,
    /// All items of all rows, concatenated.
    pub values: Column,
}

impl ListColumn {
    /// An empty list column (no rows yet).
    pub fn new(count_type: ScalarType, item_type: ScalarType) -> Self {
        Self { count_type, offsets: vec![0], values: Column::with_capacity(item_type, 0) }
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Range of row `i`'s items in `values`; `None` past the end.
    pub fn row_range(&self, i: usize) -> Option<Range<usize>> {
        Some(*self.offsets.get(i)?..*self.offsets.get(i + 1)?)
    }
}

/// The values of one property of an element.
#[derive(Debug, Clone, PartialEq)]
pub enum PropertyData {
    /// One value per row.
    Scalar(Column),
    /// A variable-length list per row.
    List(ListColumn),
}

impl PropertyData {
    /// Number of rows held.
    pub fn rows(&self) -> usize {
        match self {
            Self::Scalar(c) => c.len(),
            Self::List(l) => l.rows(),
        }
    }
}

/// A named property with its values.
#[derive(Debug, Clone, PartialEq)]
pub struct Property {
    /// Name as in the header (`x`, `red`, `vertex_indices`, `label`).
    pub name: String,
    /// The values, one row per element instance.
    pub data: PropertyData,
}

/// An element (`vertex`, `face`, ...) with all its properties.
#[derive(Debug, Clone)]
pub struct Element {
    /// Name as in the header.
    pub name: String,
    /// Number of instances (rows).
    pub count: usize,
    /// Properties in header order (the order of the values in each row).
    pub properties: Vec<Property>,
    /// For elements read from an ASCII body with exactly one row per line: the line of row 0.
    first_line: Option<usize>,
}

/// Equality of content: where the element was read from does not matter.
impl PartialEq for Element {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && self.count == other.count && self.properties == other.properties
    }
}

impl Element {
    /// An element with `count` rows and no property yet.
    pub fn new(name: impl Into<String>, count: usize) -> Self {
        Self { name: name.into(), count, properties: Vec::new(), first_line: None }
    }

    /// The property called `name`.
    pub fn property(&self, name: &str) -> Option<&Property> {
        self.properties.iter().find(|p| p.name == name)
    }

    /// The scalar column of the property called `name` (`None` if absent or a list).
    pub fn scalar(&self, name: &str) -> Option<&Column> {
        match &self.property(name)?.data {
            PropertyData::Scalar(c) => Some(c),
            PropertyData::List(_) => None,
        }
    }

    /// Replaces the property of the same name (keeping its position) or appends it.
    /// Fails when its row count differs from the element's.
    pub fn set_property(&mut self, property: Property) -> std::result::Result<(), String> {
        if property.data.rows() != self.count {
            return Err(format!(
                "property '{}' has {} rows, element '{}' has {}",
                property.name,
                property.data.rows(),
                self.name,
                self.count
            ));
        }
        match self.properties.iter_mut().find(|p| p.name == property.name) {
            Some(p) => *p = property,
            None => self.properties.push(property),
        }
        Ok(())
    }

    /// Removes and returns the property called `name`.
    pub fn remove_property(&mut self, name: &str) -> Option<Property> {
        let i = self.properties.iter().position(|p| p.name == name)?;
        Some(self.properties.remove(i))
    }

    /// The 1-based line of row `row` when the element came from an ASCII body with one row
    /// per line (so that later errors about a row can point at the file line).
    pub fn line_of_row(&self, row: usize) -> Option<usize> {
        self.first_line.map(|l| l + row)
    }

    fn check(&self) -> std::result::Result<(), String> {
        check_name(&self.name, "element")?;
        for (i, p) in self.properties.iter().enumerate() {
            check_name(&p.name, "property")?;
            if self.properties[..i].iter().any(|q| q.name == p.name) {
                return Err(format!("element '{}' has two properties named '{}'", self.name, p.name));
            }
            if p.data.rows() != self.count {
                return Err(format!(
                    "property '{}' of element '{}' has {} rows for {} elements",
                    p.name,
                    self.name,
                    p.data.rows(),
                    self.count
                ));
            }
            if let PropertyData::List(l) = &p.data {
                if !l.count_type.is_integer() {
                    return Err(format!("list property '{}' has a non-integer count type", p.name));
                }
                if l.offsets.first() != Some(&0)
                    || l.offsets.last() != Some(&l.values.len())
                    || l.offsets.windows(2).any(|w| w[0] > w[1])
                {
                    return Err(format!("list property '{}' has inconsistent offsets", p.name));
                }
                let max = max_count(l.count_type);
                if let Some(w) = l.offsets.windows(2).find(|w| (w[1] - w[0]) as u64 > max) {
                    return Err(format!(
                        "list property '{}' has a row of {} items, more than its count type {} holds",
                        p.name,
                        w[1] - w[0],
                        l.count_type.name()
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Largest list length a count of type `ty` can express.
fn max_count(ty: ScalarType) -> u64 {
    ty.int_range().map_or(0, |(_, hi)| hi as u64)
}

fn check_name(name: &str, what: &str) -> std::result::Result<(), String> {
    if name.is_empty() || name.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return Err(format!("{what} name '{name}' is empty or contains whitespace"));
    }
    Ok(())
}

/// A whole PLY file: header metadata and every element with every property.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyFile {
    /// Body encoding of the file read (informational: writing takes its own encoding).
    pub format: PlyFormat,
    /// `comment` lines, without the keyword.
    pub comments: Vec<String>,
    /// `obj_info` lines, without the keyword.
    pub obj_info: Vec<String>,
    /// Elements in file order.
    pub elements: Vec<Element>,
}

impl Default for PlyFile {
    fn default() -> Self {
        Self { format: PlyFormat::BinaryLittleEndian, comments: Vec::new(), obj_info: Vec::new(), elements: Vec::new() }
    }
}

/// A header property before its values are read.
struct PropertyDef {
    name: String,
    /// `Some(count type)` for lists.
    list_count: Option<ScalarType>,
    ty: ScalarType,
}

impl PlyFile {
    /// Reads and parses the PLY file at `path`.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
        Self::parse(&bytes, path)
    }

    /// Parses PLY bytes; `path` only names the source in errors.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        let err = |line: Option<usize>, msg: String| DataError::parse(path, line, msg);
        let (mut file, defs, body_start, body_line) = parse_header(bytes, path)?;
        let body = &bytes[body_start..];
        match file.format {
            PlyFormat::Ascii => {
                let mut cur = AsciiCursor { data: body, pos: 0, line: body_line };
                for (el, defs) in file.elements.iter_mut().zip(&defs) {
                    read_ascii_element(el, defs, &mut cur).map_err(|(l, m)| err(Some(l), m))?;
                }
                if let Some((_, line)) = cur.next_token() {
                    return Err(err(Some(line), "unexpected data after the last element".into()));
                }
            }
            PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
                let big = file.format == PlyFormat::BinaryBigEndian;
                let mut pos = 0;
                for (el, defs) in file.elements.iter_mut().zip(&defs) {
                    pos = read_binary_element(el, defs, body, pos, big).map_err(|m| err(None, m))?;
                }
                // Trailing bytes are tolerated: some writers pad binary files.
            }
        }
        Ok(file)
    }

    /// The element called `name`.
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.name == name)
    }

    /// The element called `name`, mutable.
    pub fn element_mut(&mut self, name: &str) -> Option<&mut Element> {
        self.elements.iter_mut().find(|e| e.name == name)
    }

    /// Writes the file atomically (temporary file in the same folder, then rename).
    pub fn write(&self, path: impl AsRef<Path>, encoding: PlyEncoding) -> Result<()> {
        let path = path.as_ref();
        self.check().map_err(|m| DataError::InvalidArgument(format!("cannot write {}: {m}", path.display())))?;
        crate::atomic_file::write_atomic_with(path, |w| self.write_unchecked(w, encoding.into()))
    }

    /// Encodes the file into bytes.
    pub fn to_bytes(&self, encoding: PlyEncoding) -> std::result::Result<Vec<u8>, String> {
        self.check()?;
        let mut out = Vec::new();
        self.write_unchecked(&mut out, encoding.into()).map_err(|e| e.to_string())?;
        Ok(out)
    }

    /// Checks that the file can be written: names, comments, row counts, list offsets.
    pub fn check(&self) -> std::result::Result<(), String> {
        for (i, e) in self.elements.iter().enumerate() {
            e.check()?;
            if self.elements[..i].iter().any(|f| f.name == e.name) {
                return Err(format!("two elements named '{}'", e.name));
            }
        }
        if let Some(c) = self.comments.iter().chain(&self.obj_info).find(|c| c.contains(['\n', '\r'])) {
            return Err(format!("comment '{c}' contains a line break"));
        }
        Ok(())
    }

    fn write_unchecked(&self, w: &mut dyn Write, format: PlyFormat) -> std::io::Result<()> {
        self.write_header(w, format)?;
        let mut buf: Vec<u8> = Vec::with_capacity(ROW_FLUSH_BYTES + 4096);
        for e in &self.elements {
            e.write_rows(w, &mut buf, format)?;
        }
        w.write_all(&buf)?;
        w.flush()
    }

    /// Writes the header: format, comments, and every element with its `count` and its
    /// properties' types (the rows themselves are not read).
    pub(crate) fn write_header(&self, w: &mut dyn Write, format: PlyFormat) -> std::io::Result<()> {
        let mut head = String::from("ply\n");
        head += &format!("format {} 1.0\n", format.name());
        for c in &self.comments {
            head += &format!("comment {c}\n");
        }
        for c in &self.obj_info {
            head += &format!("obj_info {c}\n");
        }
        for e in &self.elements {
            head += &format!("element {} {}\n", e.name, e.count);
            for p in &e.properties {
                match &p.data {
                    PropertyData::Scalar(c) => head += &format!("property {} {}\n", c.scalar_type().name(), p.name),
                    PropertyData::List(l) => {
                        head += &format!(
                            "property list {} {} {}\n",
                            l.count_type.name(),
                            l.values.scalar_type().name(),
                            p.name
                        )
                    }
                }
            }
        }
        head += "end_header\n";
        w.write_all(head.as_bytes())
    }
}

/// Rows are assembled in a buffer written out every ~1 MiB: one write call per block
/// rather than per value.
pub(crate) const ROW_FLUSH_BYTES: usize = 1 << 20;

impl Element {
    /// Appends the element's rows (`count` of them, checked against the columns
    /// beforehand) to `buf` in the body encoding, writing `buf` out to `w` whenever it
    /// holds [`ROW_FLUSH_BYTES`]; what is left in `buf` is for the caller to write.
    pub(crate) fn write_rows(&self, w: &mut dyn Write, buf: &mut Vec<u8>, format: PlyFormat) -> std::io::Result<()> {
        let big = format == PlyFormat::BinaryBigEndian;
        for row in 0..self.count {
            for (k, p) in self.properties.iter().enumerate() {
                if format == PlyFormat::Ascii && k > 0 {
                    buf.push(b' ');
                }
                match &p.data {
                    PropertyData::Scalar(c) => {
                        if format == PlyFormat::Ascii {
                            c.put_text(row, buf);
                        } else {
                            c.put_binary(row, buf, big);
                        }
                    }
                    PropertyData::List(l) => {
                        let (a, b) = (l.offsets[row], l.offsets[row + 1]);
                        put_count(l.count_type, b - a, buf, format);
                        for i in a..b {
                            if format == PlyFormat::Ascii {
                                buf.push(b' ');
                                l.values.put_text(i, buf);
                            } else {
                                l.values.put_binary(i, buf, big);
                            }
                        }
                    }
                }
            }
            if format == PlyFormat::Ascii {
                buf.push(b'\n');
            }
            if buf.len() >= ROW_FLUSH_BYTES {
                w.write_all(buf)?;
                buf.clear();
            }
        }
        Ok(())
    }
}

/// Writes a list count `n` (checked to fit `ty` beforehand) in the body encoding.
fn put_count(ty: ScalarType, n: usize, out: &mut Vec<u8>, format: PlyFormat) {
    if format == PlyFormat::Ascii {
        let _ = write!(out, "{n}");
        return;
    }
    let big = format == PlyFormat::BinaryBigEndian;
    match ty {
        ScalarType::Char => (n as i8).put(out, big),
        ScalarType::UChar => (n as u8).put(out, big),
        ScalarType::Short => (n as i16).put(out, big),
        ScalarType::UShort => (n as u16).put(out, big),
        ScalarType::Int => (n as i32).put(out, big),
        ScalarType::UInt => (n as u32).put(out, big),
        ScalarType::Float => (n as f32).put(out, big),
        ScalarType::Double => (n as f64).put(out, big),
    }
}

#[cfg(test)]
mod tests;
