//! Reading a PLY file: the header (format, elements, properties, comments) and the body's
//! elements, ASCII line by line or binary column by column, every malformed input an exact
//! error naming where it is (see the parent module).

use std::path::Path;

use super::*;

/// One empty column per property definition, with room for `cap` rows (callers bound `cap`
/// by what the file's remaining bytes can hold, so a lying header cannot force a huge
/// allocation).
fn empty_columns(defs: &[PropertyDef], cap: usize) -> Vec<PropertyData> {
    defs.iter()
        .map(|d| match d.list_count {
            None => PropertyData::Scalar(Column::with_capacity(d.ty, cap)),
            Some(ct) => {
                let mut l = ListColumn::new(ct, d.ty);
                l.offsets.reserve(cap);
                PropertyData::List(l)
            }
        })
        .collect()
}

/// Parses the header: the file skeleton with empty columns, the property definitions per
/// element, the byte offset of the body and the line number the body starts on.
pub(super) fn parse_header(bytes: &[u8], path: &Path) -> Result<(PlyFile, Vec<Vec<PropertyDef>>, usize, usize)> {
    let err = |line: usize, msg: String| DataError::parse(path, Some(line), msg);
    let mut file = PlyFile::default();
    let mut defs: Vec<Vec<PropertyDef>> = Vec::new();
    let mut format = None;
    let mut pos = 0;
    let mut line_no = 0;
    loop {
        line_no += 1;
        if pos >= bytes.len() {
            return Err(err(line_no, "end of file inside the header (no 'end_header' line)".into()));
        }
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map(|i| pos + i);
        let raw = &bytes[pos..end.unwrap_or(bytes.len())];
        let next = end.map_or(bytes.len(), |e| e + 1);
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let text = std::str::from_utf8(raw).map_err(|_| err(line_no, "header line is not valid UTF-8 text".into()))?;
        pos = next;
        if line_no == 1 {
            if text.trim_end() != "ply" {
                return Err(err(1, "not a PLY file: the first line must be 'ply'".into()));
            }
            continue;
        }
        let mut words = text.split_whitespace();
        let Some(keyword) = words.next() else { continue };
        let rest: Vec<&str> = words.collect();
        match keyword {
            "format" => {
                if format.is_some() {
                    return Err(err(line_no, "second 'format' line".into()));
                }
                let [kind, _version] = rest[..] else {
                    return Err(err(line_no, format!("'format' needs a kind and a version, got '{text}'")));
                };
                format = Some(match kind {
                    "ascii" => PlyFormat::Ascii,
                    "binary_little_endian" => PlyFormat::BinaryLittleEndian,
                    "binary_big_endian" => PlyFormat::BinaryBigEndian,
                    other => return Err(err(line_no, format!("unknown format '{other}'"))),
                });
            }
            "comment" => file.comments.push(comment_text(text, "comment")),
            "obj_info" => file.obj_info.push(comment_text(text, "obj_info")),
            "element" => {
                let [name, count] = rest[..] else {
                    return Err(err(line_no, format!("'element' needs a name and a count, got '{text}'")));
                };
                let count: usize = count
                    .parse()
                    .map_err(|_| err(line_no, format!("element count '{count}' is not a non-negative integer")))?;
                if file.elements.iter().any(|e| e.name == name) {
                    return Err(err(line_no, format!("second element named '{name}'")));
                }
                file.elements.push(Element::new(name, count));
                defs.push(Vec::new());
            }
            "property" => {
                let Some(el_defs) = defs.last_mut() else {
                    return Err(err(line_no, "'property' before any 'element'".into()));
                };
                let ty = |name: &str| {
                    ScalarType::from_name(name).ok_or_else(|| err(line_no, format!("unknown property type '{name}'")))
                };
                let def = match rest[..] {
                    ["list", count, item, name] => {
                        let count_ty = ty(count)?;
                        if !count_ty.is_integer() {
                            return Err(err(line_no, format!("list count type '{count}' is not an integer type")));
                        }
                        PropertyDef { name: name.to_string(), list_count: Some(count_ty), ty: ty(item)? }
                    }
                    [t, name] if t != "list" => PropertyDef { name: name.to_string(), list_count: None, ty: ty(t)? },
                    _ => {
                        return Err(err(
                            line_no,
                            format!(
                                "expected 'property TYPE NAME' or 'property list COUNT_TYPE TYPE NAME', got '{text}'"
                            ),
                        ))
                    }
                };
                if el_defs.iter().any(|d| d.name == def.name) {
                    return Err(err(line_no, format!("second property named '{}'", def.name)));
                }
                el_defs.push(def);
            }
            "end_header" => {
                if !rest.is_empty() {
                    return Err(err(line_no, format!("unexpected text after 'end_header': '{text}'")));
                }
                if end.is_none() && pos < bytes.len() {
                    return Err(err(line_no, "'end_header' is not followed by a line break".into()));
                }
                break;
            }
            other => return Err(err(line_no, format!("unknown header keyword '{other}'"))),
        }
    }
    file.format = format.ok_or_else(|| err(line_no, "header has no 'format' line".into()))?;
    Ok((file, defs, pos, line_no + 1))
}

/// Text of a `comment` / `obj_info` line after the keyword and one separator.
fn comment_text(line: &str, keyword: &str) -> String {
    let rest = line.trim_start().strip_prefix(keyword).unwrap_or("");
    rest.strip_prefix([' ', '\t']).unwrap_or(rest).to_string()
}

/// Reads one element from a binary body starting at `pos`; returns the position after it.
pub(super) fn read_binary_element(
    el: &mut Element,
    defs: &[PropertyDef],
    body: &[u8],
    pos: usize,
    big: bool,
) -> std::result::Result<usize, String> {
    let remaining = body.len() - pos;
    if defs.is_empty() {
        return Ok(pos);
    }
    if defs.iter().all(|d| d.list_count.is_none()) {
        // Fixed-size rows: check the size once, then decode column by column.
        let stride: usize = defs.iter().map(|d| d.ty.size()).sum();
        let need = el.count.checked_mul(stride).filter(|&n| n <= remaining).ok_or_else(|| {
            format!(
                "binary body truncated: element '{}' needs {} rows of {stride} bytes but only {remaining} bytes remain \
                 (at byte {pos} of the body)",
                el.name, el.count
            )
        })?;
        let rows = &body[pos..pos + need];
        let mut offset = 0;
        for d in defs {
            let col = Column::decode_strided(d.ty, rows, el.count, stride, offset, big);
            offset += d.ty.size();
            el.properties.push(Property { name: d.name.clone(), data: PropertyData::Scalar(col) });
        }
        return Ok(pos + need);
    }
    // Rows with lists: decode sequentially. Each row takes at least `min_row` bytes, which
    // bounds what may be reserved by what the file can hold.
    let min_row: usize = defs.iter().map(|d| d.list_count.unwrap_or(d.ty).size()).sum();
    let cap = el.count.min(remaining / min_row.max(1));
    let mut data = empty_columns(defs, cap);
    let mut p = pos;
    for row in 0..el.count {
        for (d, data) in defs.iter().zip(data.iter_mut()) {
            let truncated = |at: usize| {
                format!(
                    "binary body truncated in element '{}' row {row} property '{}' (at byte {at} of the body)",
                    el.name, d.name
                )
            };
            match data {
                PropertyData::Scalar(c) => {
                    let b = body.get(p..p + d.ty.size()).ok_or_else(|| truncated(p))?;
                    c.push_bytes(b, big);
                    p += d.ty.size();
                }
                PropertyData::List(l) => {
                    let ct = l.count_type;
                    let b = body.get(p..p + ct.size()).ok_or_else(|| truncated(p))?;
                    let n = ct.decode_int(b, big).unwrap_or(-1);
                    let n = usize::try_from(n).map_err(|_| {
                        format!("element '{}' row {row} property '{}': negative list length {n}", el.name, d.name)
                    })?;
                    p += ct.size();
                    let bytes = n
                        .checked_mul(d.ty.size())
                        .and_then(|len| body.get(p..p.checked_add(len)?))
                        .ok_or_else(|| truncated(p))?;
                    l.values.extend_from_bytes(bytes, big);
                    p += bytes.len();
                    l.offsets.push(l.values.len());
                }
            }
        }
    }
    for (d, data) in defs.iter().zip(data) {
        el.properties.push(Property { name: d.name.clone(), data });
    }
    Ok(p)
}

/// Whitespace-separated tokens of an ASCII body with line tracking.
pub(super) struct AsciiCursor<'a> {
    pub(super) data: &'a [u8],
    pub(super) pos: usize,
    pub(super) line: usize,
}

impl<'a> AsciiCursor<'a> {
    /// The next token and the line it is on.
    pub(super) fn next_token(&mut self) -> Option<(&'a [u8], usize)> {
        while let Some(&b) = self.data.get(self.pos) {
            if b == b'\n' {
                self.line += 1;
            } else if !b.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while self.data.get(self.pos).is_some_and(|b| !b.is_ascii_whitespace()) {
            self.pos += 1;
        }
        (self.pos > start).then(|| (&self.data[start..self.pos], self.line))
    }
}

/// Reads one element from an ASCII body; errors carry the line.
pub(super) fn read_ascii_element(
    el: &mut Element,
    defs: &[PropertyDef],
    cur: &mut AsciiCursor,
) -> std::result::Result<(), (usize, String)> {
    if defs.is_empty() {
        return Ok(());
    }
    // Every value takes at least two bytes (digit + separator), bounding reservations.
    let cap = el.count.min((cur.data.len() - cur.pos) / (2 * defs.len()) + 1);
    let mut data = empty_columns(defs, cap);
    let mut first_line = None;
    let mut one_per_line = true;
    for row in 0..el.count {
        let mut row_line = None;
        for (d, data) in defs.iter().zip(data.iter_mut()) {
            let mut next = |what: &str| -> std::result::Result<(&str, usize), (usize, String)> {
                let (tok, line) = cur.next_token().ok_or_else(|| {
                    (cur.line, format!("end of file in element '{}' row {row}: missing {what}", el.name))
                })?;
                let tok = std::str::from_utf8(tok).map_err(|_| (line, "value is not valid UTF-8 text".to_string()))?;
                match row_line {
                    None => row_line = Some(line),
                    Some(l) if l != line => one_per_line = false,
                    Some(_) => {}
                }
                Ok((tok, line))
            };
            let ctx =
                |line: usize, m: String| (line, format!("element '{}' row {row} property '{}': {m}", el.name, d.name));
            match data {
                PropertyData::Scalar(c) => {
                    let (tok, line) = next(&format!("property '{}'", d.name))?;
                    c.push_text(tok).map_err(|m| ctx(line, m))?;
                }
                PropertyData::List(l) => {
                    let (tok, line) = next(&format!("the length of list '{}'", d.name))?;
                    let ct = l.count_type;
                    let n = ct
                        .parse_int(tok)
                        .ok_or_else(|| ctx(line, format!("list length '{tok}' is not a valid {} value", ct.name())))?;
                    let n = usize::try_from(n).map_err(|_| ctx(line, format!("negative list length {n}")))?;
                    for _ in 0..n {
                        let (tok, line) = next(&format!("an item of list '{}'", d.name))?;
                        l.values.push_text(tok).map_err(|m| ctx(line, m))?;
                    }
                    l.offsets.push(l.values.len());
                }
            }
        }
        if let Some(line) = row_line {
            match first_line {
                None => first_line = Some(line),
                Some(f) if f + row != line => one_per_line = false,
                Some(_) => {}
            }
        }
    }
    el.first_line = if one_per_line { first_line } else { None };
    for (d, data) in defs.iter().zip(data) {
        el.properties.push(Property { name: d.name.clone(), data });
    }
    Ok(())
}
