//! Reading a Sweet Home 3D furniture catalogue (`*.sh3f`, a zip archive): its
//! `PluginFurnitureCatalog.properties` in Java properties syntax, turned into one
//! [`CatalogueEntry`] per model in the file's `#N` order. Kept apart from the class table and
//! the mesh loader because it is the only place that knows the catalogue's key names and
//! units (centimetres), and because the properties syntax (escapes, continuation lines,
//! Latin-1 bytes) deserves unit tests that need no installed package.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};

use crate::error::{DataError, Result};

/// The properties file at the root of every `.sh3f` archive (the untranslated one; the
/// `_fr`, `_de`, ... variants only translate names).
pub const PROPERTIES_ENTRY: &str = "PluginFurnitureCatalog.properties";

/// An opened `.sh3f` archive.
pub type Archive = zip::ZipArchive<BufReader<File>>;

/// One model of a catalogue, as its properties describe it (no class, no geometry).
#[derive(Debug, Clone, PartialEq)]
pub struct CatalogueEntry {
    /// Catalogue file stem (`BlendSwap-CC-0`).
    pub catalogue: String,
    /// 1-based `#N` index in the properties file.
    pub index: usize,
    /// Unique id (`Blend Swap CC-0#bed1`).
    pub id: String,
    /// Display name.
    pub name: String,
    /// Catalogue category (`Bedroom`, ...).
    pub category: String,
    /// Comma-separated search tags (may be empty).
    pub tags: String,
    /// Path of the OBJ inside the archive, without a leading `/`.
    pub model: String,
    /// Size in metres: x = width, y = depth, z = height.
    pub size: Vec3,
    /// Height of the model's bottom above the floor, metres.
    pub elevation: f32,
    /// Whether the model is a door or a window.
    pub door_or_window: bool,
    /// Author.
    pub creator: String,
    /// Rotation applied to the OBJ coordinates before sizing (`modelRotation`, row-major).
    pub model_rotation: Option<Mat3>,
}

/// A catalogue's properties: its header and its models.
#[derive(Debug, Clone)]
pub struct Catalogue {
    /// File stem (`Scopia`).
    pub stem: String,
    /// The archive's path.
    pub path: PathBuf,
    /// The header's `license=` line (empty when absent).
    pub license: String,
    /// The header's `name=` line.
    pub name: String,
    /// The models in `#N` order.
    pub entries: Vec<CatalogueEntry>,
}

/// Opens the zip archive `path`.
pub fn open_archive(path: &Path) -> Result<Archive> {
    let file = File::open(path).map_err(|e| DataError::io(path, e))?;
    zip::ZipArchive::new(BufReader::new(file))
        .map_err(|e| DataError::parse(path, None, format!("not a readable zip archive: {e}")))
}

/// The bytes of `entry` inside `archive` (which was opened from `path`, named in errors as
/// `path!/entry`, the jar-URL way).
pub fn read_entry(archive: &mut Archive, path: &Path, entry: &str) -> Result<Vec<u8>> {
    let name = entry_error_path(path, entry);
    let mut file =
        archive.by_name(entry).map_err(|e| DataError::parse(&name, None, format!("cannot open entry: {e}")))?;
    // The size comes from the archive: a hint only, capped so a lying header cannot make us
    // reserve gigabytes.
    let mut bytes = Vec::with_capacity((file.size() as usize).min(64 << 20));
    file.read_to_end(&mut bytes).map_err(|e| DataError::parse(&name, None, format!("cannot read entry: {e}")))?;
    Ok(bytes)
}

/// `archive.sh3f!/entry`: how errors name a file inside an archive.
pub fn entry_error_path(path: &Path, entry: &str) -> PathBuf {
    PathBuf::from(format!("{}!/{}", path.display(), entry))
}

/// Reads the catalogue header and models of the archive `path`.
pub fn read_catalogue(path: &Path, archive: &mut Archive) -> Result<Catalogue> {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let bytes = read_entry(archive, path, PROPERTIES_ENTRY)?;
    // Java properties files are ISO 8859-1 (Scopia's has raw Latin-1 bytes besides \uXXXX
    // escapes): map each byte to the code point of the same value, which is exactly Latin-1.
    let text: String = bytes.iter().map(|&b| b as char).collect();
    let props = parse_properties(&text);
    let map: HashMap<&str, &str> = props.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let err_path = entry_error_path(path, PROPERTIES_ENTRY);
    let mut entries = Vec::new();
    for index in 1.. {
        let get = |key: &str| map.get(format!("{key}#{index}").as_str()).copied();
        let Some(id) = get("id") else { break };
        let req = |key: &str| {
            get(key).ok_or_else(|| DataError::parse(&err_path, None, format!("model {id}: no {key}#{index}")))
        };
        let num = |key: &str, default: Option<f32>| -> Result<f32> {
            match (get(key), default) {
                (Some(v), _) => v.trim().parse::<f32>().map_err(|_| {
                    DataError::parse(&err_path, None, format!("model {id}: {key}#{index} = {v:?} is not a number"))
                }),
                (None, Some(d)) => Ok(d),
                (None, None) => Err(DataError::parse(&err_path, None, format!("model {id}: no {key}#{index}"))),
            }
        };
        let model_rotation = match get("modelRotation") {
            None => None,
            Some(v) => {
                let m: Vec<f32> = v.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                if m.len() != 9 {
                    return Err(DataError::parse(
                        &err_path,
                        None,
                        format!("model {id}: modelRotation#{index} = {v:?} is not 9 numbers"),
                    ));
                }
                // Row-major in the file; glam's constructor takes columns.
                Some(Mat3::from_cols_array(&[m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8]]))
            }
        };
        // Centimetres in the file, metres here.
        let size = Vec3::new(num("width", None)?, num("depth", None)?, num("height", None)?) / 100.0;
        entries.push(CatalogueEntry {
            catalogue: stem.clone(),
            index,
            id: id.to_string(),
            name: req("name")?.to_string(),
            category: get("category").unwrap_or("").to_string(),
            tags: get("tags").unwrap_or("").to_string(),
            model: req("model")?.trim_start_matches('/').to_string(),
            size,
            elevation: num("elevation", Some(0.0))? / 100.0,
            door_or_window: get("doorOrWindow").is_some_and(|v| v.trim() == "true"),
            creator: get("creator").unwrap_or("").to_string(),
            model_rotation,
        });
    }
    if entries.is_empty() {
        return Err(DataError::parse(&err_path, None, "no model (no id#1 key)"));
    }
    Ok(Catalogue {
        stem,
        path: path.to_path_buf(),
        license: map.get("license").copied().unwrap_or("").to_string(),
        name: map.get("name").copied().unwrap_or("").to_string(),
        entries,
    })
}

/// Parses Java properties text (`java.util.Properties::load` rules): `#`/`!` comment lines,
/// `key=value`, `key:value` or `key value`, a line ending in an odd number of `\` continues
/// on the next (whose leading blanks are dropped), escapes `\t \n \r \f \uXXXX` and `\x` for
/// any other `x`. Returns the pairs in file order (a later duplicate key wins in a map).
pub fn parse_properties(text: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut logical = String::new();
    let mut continuing = false;
    for raw in text.split('\n') {
        let raw = raw.strip_suffix('\r').unwrap_or(raw);
        let line = raw.trim_start_matches([' ', '\t', '\x0c']);
        if !continuing && (line.is_empty() || line.starts_with('#') || line.starts_with('!')) {
            continue;
        }
        let trailing = line.len() - line.trim_end_matches('\\').len();
        if trailing % 2 == 1 {
            logical.push_str(&line[..line.len() - 1]);
            continuing = true;
            continue;
        }
        logical.push_str(line);
        continuing = false;
        out.push(split_pair(&logical));
        logical.clear();
    }
    if continuing && !logical.is_empty() {
        out.push(split_pair(&logical));
    }
    out
}

/// Splits one logical line into its unescaped key and value.
fn split_pair(line: &str) -> (String, String) {
    let chars: Vec<char> = line.chars().collect();
    let mut i = 0;
    // The key ends at the first unescaped `=`, `:` or blank.
    while i < chars.len() {
        match chars[i] {
            '\\' => i += 2,
            '=' | ':' | ' ' | '\t' | '\x0c' => break,
            _ => i += 1,
        }
    }
    let key_end = i.min(chars.len());
    // Then blanks, at most one separator, blanks.
    let mut j = key_end;
    while j < chars.len() && matches!(chars[j], ' ' | '\t' | '\x0c') {
        j += 1;
    }
    if j < chars.len() && matches!(chars[j], '=' | ':') {
        j += 1;
        while j < chars.len() && matches!(chars[j], ' ' | '\t' | '\x0c') {
            j += 1;
        }
    }
    (unescape(&chars[..key_end]), unescape(&chars[j.min(chars.len())..]))
}

/// Resolves backslash escapes; a malformed `\u` keeps its characters as they are.
fn unescape(chars: &[char]) -> String {
    let mut s = String::with_capacity(chars.len());
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c != '\\' || i + 1 >= chars.len() {
            s.push(c);
            i += 1;
            continue;
        }
        let e = chars[i + 1];
        i += 2;
        match e {
            't' => s.push('\t'),
            'n' => s.push('\n'),
            'r' => s.push('\r'),
            'f' => s.push('\x0c'),
            'u' => {
                let hex: String = chars[i..chars.len().min(i + 4)].iter().collect();
                match (hex.len() == 4).then(|| u32::from_str_radix(&hex, 16).ok()).flatten().and_then(char::from_u32) {
                    Some(ch) => {
                        s.push(ch);
                        i += 4;
                    }
                    None => s.push('u'),
                }
            }
            other => s.push(other),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(text: &str) -> HashMap<String, String> {
        parse_properties(text).into_iter().collect()
    }

    #[test]
    fn comments_separators_and_blanks() {
        let m = map("# a comment\n! another\n\n  key1=value one\nkey2 : v2\nkey3 v3\nkey4=\n");
        assert_eq!(m.len(), 4, "{m:?}");
        assert_eq!(m["key1"], "value one");
        assert_eq!(m["key2"], "v2");
        assert_eq!(m["key3"], "v3");
        assert_eq!(m["key4"], "");
    }

    #[test]
    fn escapes() {
        let m = map("name#1=Caf\\u00e9 \\t tab\nk\\=ey=a\\:b\\\\c\nlatin=\u{e9}t\u{e9}\ncrlf=x\r\n");
        assert_eq!(m["name#1"], "Café \t tab");
        assert_eq!(m["k=ey"], "a:b\\c");
        assert_eq!(m["latin"], "été");
        assert_eq!(m["crlf"], "x");
    }

    #[test]
    fn continuation_lines() {
        let m = map("tags#1=Blend Swap, \\\n    Seat, \\\n\tChair\nafter=1\neven=ends with backslash\\\\\nnext=2\n");
        assert_eq!(m["tags#1"], "Blend Swap, Seat, Chair");
        assert_eq!(m["after"], "1");
        assert_eq!(m["even"], "ends with backslash\\");
        assert_eq!(m["next"], "2");
    }

    #[test]
    fn comment_marker_inside_a_continuation_is_text() {
        let m = map("a=one \\\n# not a comment\n");
        assert_eq!(m["a"], "one # not a comment");
    }
}
