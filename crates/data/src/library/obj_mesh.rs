//! Turning one catalogue model (an OBJ with its MTL and textures inside a `.sh3f` zip) into a
//! [`LabeledMesh`] in the library's local frame: decoded by `tobj`, rotated by the
//! catalogue's `modelRotation`, its axes mapped from Sweet Home 3D's (y up, front +z) to ours
//! (z up, front -y), scaled to the catalogue size, coloured per vertex from the material's
//! `Kd` or its texture sampled at the vertex's UV, and with big triangles bisected so that a
//! texture's colour varies over a large face (a sensor simulator only sees vertex colours).
//! Separate from the catalogue reader because it is the only part that decodes geometry
//! and images, and the only slow one.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;

use glam::{Mat3, Vec2, Vec3};
use image::RgbImage;

use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;

use super::catalogue::{entry_error_path, read_entry, Archive, CatalogueEntry};
use super::lock;

/// Triangles longer than this (longest edge, metres) are bisected so that colour varies
/// over them.
pub const MAX_EDGE: f32 = 0.1;

/// Subdivision stops adding triangles at this many per model (the threshold of
/// [`MAX_EDGE`] grows for models that would exceed it).
pub const MAX_TRIANGLES: usize = 200_000;

/// Colour of a surface whose material is missing (sRGB).
const DEFAULT_COLOR: [f32; 3] = [0.7, 0.7, 0.7];

/// One material as far as colours go: its `Kd` and its decoded diffuse texture, if any.
struct Shade {
    kd: [u8; 3],
    texture: Option<RgbImage>,
}

impl Shade {
    /// The colour at texture coordinate `uv` (OBJ convention: v up), or `Kd` without a
    /// texture or coordinate. Bilinear, wrapping (`fract`) like a repeating texture.
    fn color(&self, uv: Option<Vec2>) -> [u8; 3] {
        let (Some(tex), Some(uv)) = (&self.texture, uv) else { return self.kd };
        let (w, h) = (tex.width() as i64, tex.height() as i64);
        if w == 0 || h == 0 || !uv.is_finite() {
            return self.kd;
        }
        // Image rows go down, v goes up: flip v.
        let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
        let y = (1.0 - uv.y.rem_euclid(1.0)) * h as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let px = |xi: i64, yi: i64| {
            let p = tex.get_pixel(xi.rem_euclid(w) as u32, yi.rem_euclid(h) as u32).0;
            Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        let c = px(x0, y0) * (1.0 - fx) * (1.0 - fy)
            + px(x0 + 1, y0) * fx * (1.0 - fy)
            + px(x0, y0 + 1) * (1.0 - fx) * fy
            + px(x0 + 1, y0 + 1) * fx * fy;
        [c.x.round().clamp(0.0, 255.0) as u8, c.y.round().clamp(0.0, 255.0) as u8, c.z.round().clamp(0.0, 255.0) as u8]
    }
}

fn to_u8(c: [f32; 3]) -> [u8; 3] {
    c.map(|v| if v.is_finite() { (v * 255.0).round().clamp(0.0, 255.0) as u8 } else { 0 })
}

/// Resolves `rel` (as written in an OBJ or MTL) against the folder `base_dir` of the file
/// that names it, inside the archive: `/` separators, `.` and `..` resolved, a leading `/`
/// meaning the archive root.
pub fn resolve_entry(base_dir: &str, rel: &str) -> String {
    let rel = rel.replace('\\', "/");
    let mut parts: Vec<&str> =
        if rel.starts_with('/') { Vec::new() } else { base_dir.split('/').filter(|s| !s.is_empty()).collect() };
    for p in rel.split('/') {
        match p {
            "" | "." => {}
            ".." => {
                parts.pop();
            }
            p => parts.push(p),
        }
    }
    parts.join("/")
}

fn parent_dir(entry: &str) -> &str {
    entry.rfind('/').map_or("", |i| &entry[..i])
}

/// Loads the model `entry` of the archive at `archive_path` as a mesh labelled `class`.
pub fn load_entry_mesh(
    archive_path: &Path,
    archive: &Mutex<Archive>,
    entry: &CatalogueEntry,
    class: u8,
) -> Result<LabeledMesh> {
    let obj_name = entry.model.as_str();
    let obj_dir = parent_dir(obj_name).to_string();
    let err = |m: String| DataError::parse(entry_error_path(archive_path, obj_name), None, m);

    // 1. The OBJ and its MTL files, read under the archive's lock.
    let obj_bytes = read_entry(&mut lock(archive), archive_path, obj_name)?;
    // OBJ is ASCII in principle; group or material names in other encodings must not make
    // the whole model unreadable (tobj reads lines as UTF-8).
    let obj_text = String::from_utf8_lossy(&obj_bytes).into_owned();
    drop(obj_bytes);
    let mtl_names: Vec<String> = obj_text
        .lines()
        .filter_map(|l| l.trim_start().strip_prefix("mtllib").filter(|r| r.starts_with([' ', '\t'])))
        .map(|r| r.trim().to_string())
        .collect();
    let mut mtl_texts: HashMap<String, (String, String)> = HashMap::new();
    {
        let mut a = lock(archive);
        // The OBJ's own name with `.mtl` is the fallback (Scopia's kids_shelves names a file
        // that is not in the archive, while kids_shelves.mtl is).
        let stem = obj_name.rsplit('/').next().unwrap_or(obj_name);
        let fallback = format!("{}.mtl", stem.strip_suffix(".obj").unwrap_or(stem));
        for name in mtl_names {
            for candidate in [name.as_str(), fallback.as_str()] {
                let full = resolve_entry(&obj_dir, candidate);
                // A missing MTL leaves the model grey rather than unusable.
                if let Ok(bytes) = read_entry(&mut a, archive_path, &full) {
                    mtl_texts.insert(name.clone(), (full, String::from_utf8_lossy(&bytes).into_owned()));
                    break;
                }
            }
        }
    }

    // 2. Geometry and materials.
    // No `merging`/`reorder_data` fields: tobj builds without those features.
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ignore_points: true, ignore_lines: true };
    let mtl_dirs: HashMap<String, String> =
        mtl_texts.values().map(|(full, _)| (full.clone(), parent_dir(full).to_string())).collect();
    let loaded_from: std::cell::RefCell<Vec<String>> = std::cell::RefCell::new(Vec::new());
    let (models, materials) = tobj::load_obj_buf(&mut obj_text.as_bytes(), &options, |p| {
        let key = p.to_string_lossy();
        match mtl_texts.get(key.as_ref()) {
            Some((full, text)) => {
                loaded_from.borrow_mut().push(full.clone());
                tobj::load_mtl_buf(&mut text.as_bytes())
            }
            None => Err(tobj::LoadError::OpenFileFailed),
        }
    })
    .map_err(|e| err(format!("cannot parse OBJ: {e}")))?;
    // Material errors (a missing or broken MTL) only cost colours.
    let materials = materials.unwrap_or_default();
    // Textures are named relative to the MTL; the usual case is one MTL beside the OBJ.
    let tex_dir = loaded_from.borrow().first().and_then(|f| mtl_dirs.get(f).cloned()).unwrap_or(obj_dir.clone());

    // 3. Textures, read under the lock, decoded outside it.
    // Keyed by the name as the MTL writes it. Some MTLs name textures by the absolute path
    // they had on their author's disk: the file name alone, beside the MTL, is the fallback;
    // a texture absent from the archive leaves the material's Kd (as in Sweet Home 3D).
    let mut tex_bytes: HashMap<String, Option<Vec<u8>>> = HashMap::new();
    {
        let mut a = lock(archive);
        for t in materials.iter().filter_map(texture_name) {
            if tex_bytes.contains_key(&t) {
                continue;
            }
            let base = t.rsplit(['/', '\\']).next().unwrap_or(&t).to_string();
            let bytes = [t.as_str(), base.as_str()]
                .iter()
                .find_map(|c| read_entry(&mut a, archive_path, &resolve_entry(&tex_dir, c)).ok());
            tex_bytes.insert(t, bytes);
        }
    }
    let mut decoded: HashMap<String, Option<RgbImage>> = HashMap::new();
    for (name, bytes) in tex_bytes {
        // Unsupported or broken images fall back to Kd.
        let img = bytes.and_then(|b| image::load_from_memory(&b).ok()).map(|i| i.to_rgb8());
        decoded.insert(name, img);
    }
    let mut shades: Vec<Shade> = materials
        .iter()
        .map(|m| {
            let texture = texture_name(m).and_then(|t| decoded.get(&t).cloned().flatten());
            Shade { kd: to_u8(m.diffuse.unwrap_or(DEFAULT_COLOR)), texture }
        })
        .collect();
    let no_material = shades.len();
    shades.push(Shade { kd: to_u8(DEFAULT_COLOR), texture: None });

    // 4. One vertex list over all OBJ groups; each group has one material.
    let mut pos: Vec<Vec3> = Vec::new();
    let mut uvs: Vec<Option<Vec2>> = Vec::new();
    let mut tris: Vec<([u32; 3], usize)> = Vec::new();
    for model in &models {
        let mesh = &model.mesh;
        let base = pos.len() as u32;
        let n = mesh.positions.len() / 3;
        let has_uv = mesh.texcoords.len() >= 2 * n;
        for i in 0..n {
            pos.push(Vec3::new(mesh.positions[3 * i], mesh.positions[3 * i + 1], mesh.positions[3 * i + 2]));
            uvs.push(has_uv.then(|| Vec2::new(mesh.texcoords[2 * i], mesh.texcoords[2 * i + 1])));
        }
        let shade = mesh.material_id.filter(|&m| m < no_material).unwrap_or(no_material);
        for t in mesh.indices.chunks_exact(3) {
            if t.iter().any(|&i| i as usize >= n) {
                return Err(err(format!("group {:?} has a vertex index out of range", model.name)));
            }
            tris.push(([base + t[0], base + t[1], base + t[2]], shade));
        }
    }
    if tris.is_empty() {
        return Err(err("no triangle".into()));
    }
    if let Some(i) = pos.iter().position(|p| !p.is_finite()) {
        return Err(err(format!("vertex {i} is not finite")));
    }

    // 5. Rotation, axes, size. Only vertices used by triangles count for the bounds (Sweet
    // Home 3D sizes the visible shape).
    let rot = entry.model_rotation.unwrap_or(Mat3::IDENTITY);
    let mut used = vec![false; pos.len()];
    for (t, _) in &tris {
        for &i in t {
            used[i as usize] = true;
        }
    }
    for p in pos.iter_mut() {
        *p = rot * *p;
    }
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for (p, _) in pos.iter().zip(&used).filter(|(_, &u)| u) {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let ext = hi - lo;
    // OBJ x -> our x (width), OBJ y -> our z (height), OBJ +z -> our -y (depth, front -y).
    let scale = |e: f32, s: f32| if e > 1e-9 { s / e } else { 0.0 };
    let (sx, sy, sz) = (scale(ext.x, entry.size.x), scale(ext.z, entry.size.y), scale(ext.y, entry.size.z));
    for p in pos.iter_mut() {
        let q = *p - lo;
        *p = Vec3::new(q.x * sx, entry.size.y - q.z * sy, q.y * sz);
    }
    if rot.determinant() < 0.0 {
        // A mirroring rotation turns faces inside out; keep them counter-clockwise.
        for (t, _) in tris.iter_mut() {
            t.swap(1, 2);
        }
    }

    // 6. Colours, with big triangles bisected.
    let mut mesh = subdivide(pos, uvs, tris, &shades);
    // 7. Normals and labels.
    mesh.normals = vertex_normals(&mesh.positions, &mesh.triangles);
    mesh.vertex_labels = vec![class; mesh.positions.len()];
    mesh.triangle_labels = vec![class; mesh.triangles.len()];
    mesh.validate().map_err(|m| err(format!("invalid mesh: {m}")))?;
    Ok(mesh)
}

/// The file name of a material's diffuse texture (`map_Kd`), without options such as
/// `-s 1 1 1` (the name is then the last word).
fn texture_name(m: &tobj::Material) -> Option<String> {
    let t = m.diffuse_texture.as_deref()?.trim();
    if t.is_empty() {
        return None;
    }
    if t.starts_with('-') {
        return t.split_whitespace().last().map(str::to_string);
    }
    Some(t.to_string())
}

/// Longest-edge bisection until no edge is longer than the threshold (starting at
/// [`MAX_EDGE`], grown until the estimated count fits [`MAX_TRIANGLES`]); new vertices sit at
/// edge midpoints (shared between the two triangles of an edge) with the colour sampled at
/// their interpolated UV. Returns positions, colours and triangles.
fn subdivide(
    mut pos: Vec<Vec3>,
    mut uvs: Vec<Option<Vec2>>,
    tris: Vec<([u32; 3], usize)>,
    shades: &[Shade],
) -> LabeledMesh {
    let estimate = |t: f32| -> f64 {
        tris.iter()
            .map(|(v, _)| {
                let [a, b, c] = v.map(|i| pos[i as usize]);
                let longest = (b - a).length().max((c - b).length()).max((a - c).length());
                if longest <= t {
                    1.0
                } else {
                    let area = 0.5 * (b - a).cross(c - a).length();
                    ((longest / t).ceil() as f64).max((4.0 * area / (t * t)).ceil() as f64).max(2.0)
                }
            })
            .sum()
    };
    let mut threshold = MAX_EDGE;
    while estimate(threshold) > MAX_TRIANGLES as f64 && threshold < 100.0 {
        threshold *= 1.2;
    }
    let t2 = threshold * threshold;
    // Vertex colours: a vertex belongs to one OBJ group, hence one material.
    let mut vshade = vec![usize::MAX; pos.len()];
    for (v, s) in &tris {
        for &i in v {
            vshade[i as usize] = *s;
        }
    }
    let mut colors: Vec<[u8; 3]> =
        (0..pos.len()).map(|i| shades.get(vshade[i]).map_or(to_u8(DEFAULT_COLOR), |s| s.color(uvs[i]))).collect();

    let cap = MAX_TRIANGLES.max(tris.len());
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
    let mut out: Vec<[u32; 3]> = Vec::with_capacity(tris.len());
    let mut stack: Vec<([u32; 3], usize)> = tris.into_iter().rev().collect();
    while let Some((v, s)) = stack.pop() {
        let e = [0, 1, 2].map(|k| (pos[v[(k + 1) % 3] as usize] - pos[v[k] as usize]).length_squared());
        let k = if e[0] >= e[1] && e[0] >= e[2] {
            0
        } else if e[1] >= e[2] {
            1
        } else {
            2
        };
        if e[k] <= t2 || out.len() + stack.len() + 2 > cap {
            out.push(v);
            continue;
        }
        let (a, b, c) = (v[k], v[(k + 1) % 3], v[(k + 2) % 3]);
        let key = (a.min(b), a.max(b));
        let m = match midpoints.get(&key) {
            Some(&m) => m,
            None => {
                let m = pos.len() as u32;
                pos.push((pos[a as usize] + pos[b as usize]) * 0.5);
                let uv = match (uvs[a as usize], uvs[b as usize]) {
                    (Some(x), Some(y)) => Some((x + y) * 0.5),
                    _ => None,
                };
                uvs.push(uv);
                colors.push(shades.get(s).map_or(to_u8(DEFAULT_COLOR), |sh| sh.color(uv)));
                midpoints.insert(key, m);
                m
            }
        };
        // Same winding as (a, b, c).
        stack.push(([m, b, c], s));
        stack.push(([a, m, c], s));
    }
    LabeledMesh { positions: pos, colors, triangles: out, ..Default::default() }
}

/// Area-weighted vertex normals (unit; +z for a vertex of no or only degenerate triangles).
pub fn vertex_normals(pos: &[Vec3], tris: &[[u32; 3]]) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; pos.len()];
    for t in tris {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        // The cross product's length is twice the area: the weighting comes for free.
        let f = (b - a).cross(c - a);
        for &i in t {
            n[i as usize] += f;
        }
    }
    n.into_iter().map(|v| v.try_normalize().unwrap_or(Vec3::Z)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entry_paths_resolve() {
        assert_eq!(resolve_entry("a/b", "c.mtl"), "a/b/c.mtl");
        assert_eq!(resolve_entry("a/b", "./tex/../c.jpg"), "a/b/c.jpg");
        assert_eq!(resolve_entry("a/b", "../c.jpg"), "a/c.jpg");
        assert_eq!(resolve_entry("a/b", "/x/y.png"), "x/y.png");
        assert_eq!(resolve_entry("", "y.png"), "y.png");
    }

    #[test]
    fn bisection_bounds_edges_and_keeps_winding() {
        let pos = vec![Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
        let shades = [Shade { kd: [10, 20, 30], texture: None }];
        let m = subdivide(pos, vec![None; 3], vec![([0, 1, 2], 0)], &shades);
        assert!(m.triangles.len() > 100);
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            assert!((b - a).cross(c - a).z > 0.0, "winding flipped");
            for (p, q) in [(a, b), (b, c), (c, a)] {
                assert!((p - q).length() <= MAX_EDGE + 1e-6);
            }
        }
        let area: f32 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        assert!((area - 0.5).abs() < 1e-4);
        assert!(m.colors.iter().all(|&c| c == [10, 20, 30]));
    }

    #[test]
    fn texture_sampling_wraps_and_flips_v() {
        let mut img = RgbImage::new(2, 2);
        img.put_pixel(0, 0, image::Rgb([255, 0, 0])); // top left: v near 1
        img.put_pixel(0, 1, image::Rgb([0, 0, 255])); // bottom left: v near 0
        img.put_pixel(1, 0, image::Rgb([0, 255, 0]));
        img.put_pixel(1, 1, image::Rgb([0, 255, 0]));
        let s = Shade { kd: [0, 0, 0], texture: Some(img) };
        assert_eq!(s.color(Some(Vec2::new(0.25, 0.75))), [255, 0, 0]);
        assert_eq!(s.color(Some(Vec2::new(0.25, 0.25))), [0, 0, 255]);
        assert_eq!(s.color(Some(Vec2::new(1.25, -0.75))), [0, 0, 255]);
        assert_eq!(s.color(None), [0, 0, 0]);
    }
}
