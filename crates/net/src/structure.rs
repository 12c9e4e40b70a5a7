//! Structure at inference: room geometry that the network's per-voxel scores do not use on
//! their own, applied after the network call to the labels of one room.
//!
//! The network labels each 5 cm voxel from what its receptive field sees. Two things about
//! indoor rooms hold whatever the network saw in training, and can correct it on real data:
//!
//! 1. **Objects are made of smooth, similarly coloured patches.** A graph segmentation
//!    (Felzenszwalb and Huttenlocher 2004) over the 26-neighbourhood of the occupied voxels,
//!    with edge weights from the angle between the voxels' normals and their colour
//!    difference, cuts the room into segments that rarely cross an object boundary; each
//!    segment then takes the class with the largest summed network probability among the
//!    classes its members voted for ([`vote`]), so a chair is not half chair, half sofa.
//! 2. **Gravity makes floors and ceilings the big horizontal planes.** With z up, the
//!    heights of the voxels whose normals are near vertical pile up at the floor and the
//!    ceiling ([`find_planes`]): the lowest plane that covers a good share of the room's
//!    footprint, with (nearly) nothing below it, is the floor; the highest one at least
//!    2 m above it (nothing above it) the ceiling. Voxels on them take floor / ceiling; a
//!    voxel labelled floor well above the floor (a table top, a seat) or ceiling well below
//!    the ceiling takes its best other class. A partial scan may hold neither (the S3DIS
//!    fragment of this repository holds only walls, a door, a beam, a board, a chair and
//!    clutter): planes smaller than a share of the footprint are not acted on.
//!
//! Plus test-time augmentation ([`tta_probabilities`]): the network on the room rotated by
//! multiples of 90 degrees about z and mirrored, exactly on the voxel grid (no resampling),
//! the class probabilities averaged.
//!
//! What each step buys on real and generated data, and what it costs against the network
//! call, is measured in docs/model.md ("Structure at inference"): the segment vote raised the
//! real S3DIS fragment's accuracy from 47.1 to 55.7 % at about a tenth of the network's time
//! and is the default of `semrecon segment` and `eval seg`; the planes are right but change
//! almost nothing the network had wrong, and test-time augmentation costs a network call per
//! symmetry, so both are opt-in. Everything here is
//! deterministic: the same labels for any number of rayon threads (parallel steps map each
//! voxel on its own; sorting breaks ties by index; the union-find and the sums run in
//! order).

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

use glam::Vec3;
use rayon::prelude::*;
use semrecon_data::SemanticClass;
use semrecon_sparse::key::{pack_key, unpack_key, AXIS_BITS};
use semrecon_sparse::Coord;

use crate::error::{NetError, Result};
use crate::inference::Segmenter;

/// Which structure steps run after the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StructureMode {
    /// The network's labels as they are.
    #[default]
    None,
    /// Labels voted over geometric segments.
    Segments,
    /// Floor and ceiling from gravity-aligned planes.
    Planes,
    /// Planes, then segments (the votes see the plane-corrected probabilities).
    All,
}

impl StructureMode {
    /// Every mode, in the order of the command-line help.
    pub const ALL: [Self; 4] = [Self::None, Self::Segments, Self::Planes, Self::All];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Segments => "segments",
            Self::Planes => "planes",
            Self::All => "all",
        }
    }

    /// Whether the segment vote runs.
    pub fn segments(self) -> bool {
        matches!(self, Self::Segments | Self::All)
    }

    /// Whether the floor and ceiling planes are used.
    pub fn planes(self) -> bool {
        matches!(self, Self::Planes | Self::All)
    }
}

impl fmt::Display for StructureMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for StructureMode {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| format!("`{s}`: expected one of none, segments, planes, all"))
    }
}

/// Parameters of the graph segmentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentParams {
    /// Felzenszwalb-Huttenlocher's `k`: a segment of `s` voxels absorbs an edge up to
    /// `k / s` heavier than its heaviest internal edge (larger: larger segments).
    pub k: f32,
    /// Weight of the colour difference (Euclidean, RGB in `[0, 1]`) against the normal term
    /// `1 - |n_i . n_j|`.
    pub color_weight: f32,
    /// Segments smaller than this many voxels merge into a neighbour (lightest edge first).
    pub min_size: usize,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self { k: 0.4, color_weight: 2.0, min_size: 10 }
    }
}

/// Parameters of the floor and ceiling planes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneParams {
    /// A voxel is horizontal when `|n_z|` of its normal is at least this.
    pub normal_z_min: f32,
    /// A plane is big when its horizontal voxels cover at least this many square metres...
    pub min_area_m2: f32,
    /// ...and at least this share of the room's footprint (occupied x-y columns).
    pub min_footprint_share: f32,
    /// At most this share of all voxels may lie below the floor (above the ceiling).
    pub max_share_beyond: f32,
    /// Half thickness of a plane in voxels: a plane at level `l` counts the horizontal
    /// voxels of levels `l - band ..= l + band` when its size is judged...
    pub band: i32,
    /// ...and holds those of the levels with at least this share of level `l`'s count.
    pub member_share: f32,
    /// A voxel labelled floor more than this above the floor (ceiling below the ceiling),
    /// in metres, takes its best other class.
    pub off_plane_m: f32,
    /// The ceiling is at least this high above the floor (metres); with only one of the two
    /// planes found, nothing closer than this to it takes the other's class.
    pub min_room_height_m: f32,
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            normal_z_min: 0.9,
            min_area_m2: 1.0,
            min_footprint_share: 0.2,
            max_share_beyond: 0.05,
            band: 1,
            member_share: 0.3,
            off_plane_m: 0.3,
            min_room_height_m: 2.0,
        }
    }
}

/// What [`refine`] does and with which parameters.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StructureConfig {
    /// Which steps run.
    pub mode: StructureMode,
    /// The graph segmentation.
    pub segments: SegmentParams,
    /// The planes.
    pub planes: PlaneParams,
}

impl StructureConfig {
    /// `mode` with the default parameters.
    pub fn new(mode: StructureMode) -> Self {
        Self { mode, ..Self::default() }
    }
}

/// Wall time of the steps of one [`refine`] call.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StructureTiming {
    /// Neighbour lists and normals.
    pub normals: Duration,
    /// Plane search and the probability corrections.
    pub planes: Duration,
    /// Edge weights, sorting, union-find and the vote.
    pub segments: Duration,
}

impl StructureTiming {
    /// All steps together.
    pub fn total(&self) -> Duration {
        self.normals + self.planes + self.segments
    }
}

/// The result of [`refine`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Refinement {
    /// Class of every voxel.
    pub labels: Vec<u8>,
    /// Number of segments (0 when the vote did not run).
    pub segments: usize,
    /// Height of the floor plane (metres, voxel centres), when one was found and used.
    pub floor_z: Option<f32>,
    /// Height of the ceiling plane, when one was found and used.
    pub ceiling_z: Option<f32>,
    /// Voxels whose class differs from the network's own.
    pub changed: usize,
    /// Time per step.
    pub timing: StructureTiming,
}

/// Softmax of every row of `k` scores, in place (numerically stable).
///
/// # Shapes
/// `scores`: `[n, k]` row-major.
pub fn softmax_rows(scores: &mut [f32], k: usize) {
    if k == 0 {
        return;
    }
    scores.par_chunks_mut(k * 256).for_each(|block| {
        for row in block.chunks_exact_mut(k) {
            let m = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let mut sum = 0.0;
            for v in row.iter_mut() {
                *v = (*v - m).exp();
                sum += *v;
            }
            for v in row.iter_mut() {
                *v /= sum;
            }
        }
    });
}

/// The index of the largest value of every row (the first on ties).
///
/// # Shapes
/// `scores`: `[n, k]`; result `[n]`.
pub fn argmax_rows(scores: &[f32], k: usize) -> Vec<u8> {
    crate::inference::argmax_rows(scores, k)
}

/// Refined class of every voxel: [`refine`] without the report.
///
/// # Shapes
/// `coords`: `[n]` distinct voxels of one batch (any order); `features`: `[n, 3]` colour
/// features as the network takes them (`c / 127.5 - 1`, see
/// [`crate::color_features`]); `probs`: `[n, classes]` class probabilities (softmax of the
/// network's logits, or their average over test-time augmentations); result `[n]` class ids.
///
/// # Errors
/// [`NetError::InvalidInput`] when the lengths do not match or `voxel_size` is not positive.
pub fn refine_labels(
    coords: &[Coord],
    features: &[f32],
    probs: &[f32],
    classes: usize,
    voxel_size: f32,
    config: &StructureConfig,
) -> Result<Vec<u8>> {
    Ok(refine(coords, features, probs, classes, voxel_size, config)?.labels)
}

/// Refined class of every voxel, with what was found and how long each step took.
///
/// With [`StructureMode::None`] the labels are the argmax of `probs`. With planes, the floor
/// and ceiling are searched among the horizontal voxels ([`find_planes`]); voxels on them
/// become floor / ceiling and classes impossible at a voxel's height lose their probability
/// ([`plane_corrections`]). With segments, [`felzenszwalb`] over [`voxel_edges`] and
/// [`vote`] on the (corrected) probabilities; plane voxels stay floor / ceiling after the
/// vote, and a vote that gives a voxel a class impossible at its height falls back to the
/// voxel's own best class.
///
/// # Shapes
/// As [`refine_labels`].
///
/// # Errors
/// As [`refine_labels`].
pub fn refine(
    coords: &[Coord],
    features: &[f32],
    probs: &[f32],
    classes: usize,
    voxel_size: f32,
    config: &StructureConfig,
) -> Result<Refinement> {
    let n = coords.len();
    if features.len() != n * 3 {
        return Err(NetError::InvalidInput(format!("{} feature values for {n} voxels of 3 channels", features.len())));
    }
    if classes == 0 || probs.len() != n * classes {
        return Err(NetError::InvalidInput(format!("{} scores for {n} voxels of {classes} classes", probs.len())));
    }
    if !(voxel_size.is_finite() && voxel_size > 0.0) {
        return Err(NetError::InvalidInput(format!("voxel size {voxel_size} must be positive")));
    }
    let network = argmax_rows(probs, classes);
    let mode = config.mode;
    if mode == StructureMode::None || n == 0 {
        return Ok(Refinement { labels: network, ..Refinement::default() });
    }
    let mut timing = StructureTiming::default();

    let t = Instant::now();
    let neighbours = voxel_neighbours(coords);
    let normals = voxel_normals(coords, &neighbours);
    timing.normals = t.elapsed();

    let t = Instant::now();
    let floor_id = SemanticClass::Floor.id() as usize;
    let ceiling_id = SemanticClass::Ceiling.id() as usize;
    let mut probs_used: Option<Vec<f32>> = None;
    let mut corrections = None;
    let (mut floor_z, mut ceiling_z) = (None, None);
    if mode.planes() && classes > floor_id.max(ceiling_id) {
        let planes = find_planes(coords, &normals, voxel_size, &config.planes);
        floor_z = planes.floor.map(|p| (p.level as f32 + 0.5) * voxel_size);
        ceiling_z = planes.ceiling.map(|p| (p.level as f32 + 0.5) * voxel_size);
        let c = plane_corrections(coords, &normals, &planes, voxel_size, &config.planes);
        let mut p = probs.to_vec();
        apply_corrections(&mut p, classes, &c);
        probs_used = Some(p);
        corrections = Some(c);
    }
    timing.planes = t.elapsed();

    let t = Instant::now();
    let p: &[f32] = probs_used.as_deref().unwrap_or(probs);
    let mut segments = 0;
    let mut labels = if mode.segments() {
        let edges = voxel_edges(&neighbours, &normals, features, config.segments.color_weight);
        let segment = felzenszwalb(n, &edges, config.segments.k, config.segments.min_size);
        segments = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
        vote(&segment, p, classes)
    } else {
        argmax_rows(p, classes)
    };
    if let Some(c) = &corrections {
        // The planes have the last word: members keep their plane's class, and no voxel
        // keeps a class its height rules out (its own best allowed class instead).
        let own = argmax_rows(p, classes);
        for (i, l) in labels.iter_mut().enumerate() {
            match c.kind[i] {
                PlaneMember::Floor => *l = floor_id as u8,
                PlaneMember::Ceiling => *l = ceiling_id as u8,
                PlaneMember::No => {
                    let forbidden =
                        (*l as usize == floor_id && c.no_floor[i]) || (*l as usize == ceiling_id && c.no_ceiling[i]);
                    if forbidden {
                        *l = own[i];
                    }
                }
            }
        }
    }
    timing.segments = t.elapsed();
    let changed = labels.iter().zip(&network).filter(|(a, b)| a != b).count();
    Ok(Refinement { labels, segments, floor_z, ceiling_z, changed, timing })
}

/// The 26 neighbour offsets `(dx, dy, dz)`, ordered by `(dz, dy, dx)`: the first 13 precede
/// the centre, the last 13 follow it (each undirected neighbour pair appears once among the
/// "following" offsets of its first voxel).
pub const NEIGHBOUR_OFFSETS: [[i32; 3]; 26] = {
    let mut out = [[0; 3]; 26];
    let mut i = 0;
    let mut dz = -1;
    while dz <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dx = -1;
            while dx <= 1 {
                if !(dx == 0 && dy == 0 && dz == 0) {
                    out[i] = [dx, dy, dz];
                    i += 1;
                }
                dx += 1;
            }
            dy += 1;
        }
        dz += 1;
    }
    out
};

/// Marks a missing neighbour in [`voxel_neighbours`].
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// For every voxel, the row of each of its 26 neighbours ([`NEIGHBOUR_OFFSETS`] order), or
/// [`NO_NEIGHBOUR`].
///
/// # Shapes
/// `coords`: `[n]` distinct; result `[n]`.
pub fn voxel_neighbours(coords: &[Coord]) -> Vec<[u32; 26]> {
    // Rows of voxels along x, sorted by (batch, z, y, x) (the packed key's order): the
    // neighbours of a row lie in the 9 rows around it, and two pointers walk each pair of
    // rows once. Linear in the voxels, and the memory is read in order (26 hash look-ups a
    // voxel cost 15 times more).
    let mut sorted: Vec<(u64, u32)> =
        coords.iter().enumerate().filter_map(|(i, &c)| pack_key(c, i).ok().map(|k| (k, i as u32))).collect();
    sorted.par_sort_unstable();
    let row_of = |k: u64| k >> AXIS_BITS;
    let mut rows: Vec<(u64, usize, usize)> = Vec::new();
    let mut start = 0;
    for i in 1..=sorted.len() {
        if i == sorted.len() || row_of(sorted[i].0) != row_of(sorted[start].0) {
            rows.push((row_of(sorted[start].0), start, i));
            start = i;
        }
    }
    let x_of = |k: u64| (k & ((1 << AXIS_BITS) - 1)) as i64;
    let per_row: Vec<Vec<(u32, [u32; 26])>> = rows
        .par_iter()
        .map(|&(_, a, b)| {
            let mut out: Vec<(u32, [u32; 26])> = sorted[a..b].iter().map(|&(_, i)| (i, [NO_NEIGHBOUR; 26])).collect();
            let c = unpack_key(sorted[a].0);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    let q = [c[0], c[1] + dy, c[2] + dz, c[3]];
                    let Ok(qk) = pack_key(q, 0) else { continue };
                    let Ok(r) = rows.binary_search_by_key(&row_of(qk), |e| e.0) else { continue };
                    let (qa, qb) = (rows[r].1, rows[r].2);
                    let mut p = qa;
                    for (slot, &(k, _)) in out.iter_mut().zip(&sorted[a..b]) {
                        let x = x_of(k);
                        while p < qb && x_of(sorted[p].0) < x - 1 {
                            p += 1;
                        }
                        let mut s = p;
                        while s < qb && x_of(sorted[s].0) <= x + 1 {
                            let dx = x_of(sorted[s].0) - x;
                            if !(dx == 0 && dy == 0 && dz == 0) {
                                slot.1[offset_slot(dx as i32, dy, dz)] = sorted[s].1;
                            }
                            s += 1;
                        }
                    }
                }
            }
            out
        })
        .collect();
    let mut result = vec![[NO_NEIGHBOUR; 26]; coords.len()];
    for (i, nb) in per_row.into_iter().flatten() {
        result[i as usize] = nb;
    }
    result
}

/// The index of offset `(dx, dy, dz)` (each in -1..=1, not all 0) in [`NEIGHBOUR_OFFSETS`].
#[inline]
fn offset_slot(dx: i32, dy: i32, dz: i32) -> usize {
    let linear = ((dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)) as usize;
    if linear > 13 {
        linear - 1
    } else {
        linear
    }
}

/// Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations: eigenvalues
/// ascending and the matching unit eigenvectors.
pub fn symmetric_eigen3(a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut m = a;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = m[0][1].abs() + m[0][2].abs() + m[1][2].abs();
        let scale = m[0][0].abs() + m[1][1].abs() + m[2][2].abs();
        if off <= 1e-15 * scale.max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if m[p][q] == 0.0 {
                continue;
            }
            let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // m <- J^T m J with J the rotation in the (p, q) plane.
            for row in &mut m {
                let (mrp, mrq) = (row[p], row[q]);
                row[p] = c * mrp - s * mrq;
                row[q] = s * mrp + c * mrq;
            }
            let (mp, mq) = (m[p], m[q]);
            m[p] = std::array::from_fn(|r| c * mp[r] - s * mq[r]);
            m[q] = std::array::from_fn(|r| s * mp[r] + c * mq[r]);
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| m[i][i].total_cmp(&m[j][j]));
    let values = order.map(|i| m[i][i]);
    let vectors = order.map(|i| [v[0][i], v[1][i], v[2][i]]);
    (values, vectors)
}

/// Unit normal of every voxel: the direction of least spread of the centres of the voxel
/// and its occupied neighbours (principal component analysis), signed with `z >= 0`; zero
/// where fewer than three voxels are around or they lie on a line.
///
/// The normal depends only on which of the 26 neighbours are occupied, and a room's surfaces
/// show few of the 2^26 patterns: each distinct pattern is solved once.
///
/// # Shapes
/// `coords`, `neighbours`: `[n]`; result `[n]` in voxel units (unit length or zero).
pub fn voxel_normals(coords: &[Coord], neighbours: &[[u32; 26]]) -> Vec<Vec3> {
    debug_assert_eq!(coords.len(), neighbours.len());
    let masks: Vec<u32> = neighbours
        .par_iter()
        .map(|nb| nb.iter().enumerate().fold(0u32, |m, (b, &j)| if j == NO_NEIGHBOUR { m } else { m | 1 << b }))
        .collect();
    let mut patterns = masks.clone();
    patterns.par_sort_unstable();
    patterns.dedup();
    let normals: Vec<Vec3> = patterns.par_iter().map(|&m| normal_of_pattern(m)).collect();
    masks.par_iter().map(|m| patterns.binary_search(m).map_or(Vec3::ZERO, |i| normals[i])).collect()
}

/// The PCA normal of a voxel whose occupied neighbours are the set bits of `mask`
/// ([`NEIGHBOUR_OFFSETS`] order).
fn normal_of_pattern(mask: u32) -> Vec3 {
    let mut pts: Vec<[f64; 3]> = Vec::with_capacity(27);
    pts.push([0.0; 3]);
    for (b, o) in NEIGHBOUR_OFFSETS.iter().enumerate() {
        if mask & (1 << b) != 0 {
            pts.push(o.map(f64::from));
        }
    }
    normal_of_points(&pts)
}

/// The PCA normal of a small point set (see [`voxel_normals`]).
fn normal_of_points(pts: &[[f64; 3]]) -> Vec3 {
    if pts.len() < 3 {
        return Vec3::ZERO;
    }
    let inv = 1.0 / pts.len() as f64;
    let mut mean = [0.0; 3];
    for p in pts {
        for a in 0..3 {
            mean[a] += p[a] * inv;
        }
    }
    let mut cov = [[0.0; 3]; 3];
    for p in pts {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += d[a] * d[b] * inv;
            }
        }
    }
    let (values, vectors) = symmetric_eigen3(cov);
    // A line (two tiny eigenvalues) has no normal.
    if values[1] <= 1e-9 * values[2].max(1e-300) {
        return Vec3::ZERO;
    }
    let v = vectors[0];
    let s = if v[2] < 0.0 { -1.0 } else { 1.0 };
    Vec3::new((v[0] * s) as f32, (v[1] * s) as f32, (v[2] * s) as f32).normalize_or_zero()
}

/// The undirected edges of the voxel adjacency with their weights
/// `(1 - |n_i . n_j|) + color_weight * |c_i - c_j|` (colours in `[0, 1]`; a missing normal
/// counts as perpendicular), each pair once as `(i, j)` with `j` a following neighbour of `i`,
/// in order of `i` then offset.
///
/// # Shapes
/// `neighbours`, `normals`: `[n]`; `features`: `[n, 3]` network colour features in `[-1, 1]`.
pub fn voxel_edges(neighbours: &[[u32; 26]], normals: &[Vec3], features: &[f32], color_weight: f32) -> Vec<Edge> {
    neighbours
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, nb)| {
            nb[13..].iter().filter(|&&j| j != NO_NEIGHBOUR).map(move |&j| {
                let ju = j as usize;
                let dot = normals[i].dot(normals[ju]).abs().min(1.0);
                let dc =
                    (0..3).map(|ch| (features[i * 3 + ch] - features[ju * 3 + ch]) * 0.5).map(|d| d * d).sum::<f32>();
                Edge { a: i as u32, b: j, w: (1.0 - dot) + color_weight * dc.sqrt() }
            })
        })
        .collect()
}

/// An undirected weighted edge of a graph over `0..n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// One end.
    pub a: u32,
    /// The other end.
    pub b: u32,
    /// Dissimilarity (lower: more alike).
    pub w: f32,
}

/// Weight buckets of [`edge_order`].
const WEIGHT_BUCKETS: usize = 1 << 16;

/// The order in which [`felzenszwalb`] visits `edges`: by weight quantised to 1/65536 of the
/// largest weight, ties in input order (a counting sort: linear, stable, the same for any
/// thread count). Negative and NaN weights count as 0.
pub fn edge_order(edges: &[Edge]) -> Vec<u32> {
    let clean = |w: f32| if w.is_nan() { 0.0 } else { w.max(0.0) };
    let top = edges.iter().map(|e| clean(e.w)).filter(|w| w.is_finite()).fold(0.0f32, f32::max);
    let scale = if top > 0.0 { (WEIGHT_BUCKETS - 1) as f32 / top } else { 0.0 };
    let bucket: Vec<u16> = edges
        .par_iter()
        .map(|e| {
            let w = clean(e.w);
            if w.is_finite() {
                (w * scale).min((WEIGHT_BUCKETS - 1) as f32) as u16
            } else {
                (WEIGHT_BUCKETS - 1) as u16
            }
        })
        .collect();
    let mut start = vec![0u32; WEIGHT_BUCKETS + 1];
    for &b in &bucket {
        start[b as usize + 1] += 1;
    }
    for i in 0..WEIGHT_BUCKETS {
        start[i + 1] += start[i];
    }
    let mut order = vec![0u32; edges.len()];
    for (i, &b) in bucket.iter().enumerate() {
        order[start[b as usize] as usize] = i as u32;
        start[b as usize] += 1;
    }
    order
}

/// Union-find with union by size (ties: the smaller index becomes the root).
struct Forest {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl Forest {
    fn new(n: usize) -> Self {
        Self { parent: (0..n as u32).collect(), size: vec![1; n] }
    }

    fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let p = self.parent[x as usize];
            self.parent[x as usize] = self.parent[p as usize];
            x = p;
        }
        x
    }

    /// Joins two roots; returns the new root.
    fn union(&mut self, a: u32, b: u32) -> u32 {
        let (sa, sb) = (self.size[a as usize], self.size[b as usize]);
        let (root, child) = if sa > sb || (sa == sb && a < b) { (a, b) } else { (b, a) };
        self.parent[child as usize] = root;
        self.size[root as usize] = sa + sb;
        root
    }
}

/// Felzenszwalb-Huttenlocher graph segmentation: edges in increasing weight (ties in input
/// order, [`edge_order`]) join two components when the edge is no heavier than either component's largest
/// internal edge plus `k / size`; then components smaller than `min_size` are joined along
/// the remaining edges in the same order. Returns the component of every node, numbered
/// `0..m` in order of each component's first node.
///
/// # Shapes
/// `edges` over nodes `0..n`; result `[n]`.
pub fn felzenszwalb(n: usize, edges: &[Edge], k: f32, min_size: usize) -> Vec<u32> {
    let order = edge_order(edges);
    let valid = |e: &Edge| (e.a as usize) < n && (e.b as usize) < n;
    let mut forest = Forest::new(n);
    let mut threshold = vec![k; n];
    for &i in &order {
        let e = edges[i as usize];
        if !valid(&e) {
            continue;
        }
        let (ra, rb) = (forest.find(e.a), forest.find(e.b));
        if ra != rb && e.w <= threshold[ra as usize] && e.w <= threshold[rb as usize] {
            let r = forest.union(ra, rb);
            threshold[r as usize] = e.w + k / forest.size[r as usize] as f32;
        }
    }
    if min_size > 1 {
        for &i in &order {
            let e = edges[i as usize];
            if !valid(&e) {
                continue;
            }
            let (ra, rb) = (forest.find(e.a), forest.find(e.b));
            if ra != rb && (forest.size[ra as usize] < min_size as u32 || forest.size[rb as usize] < min_size as u32) {
                forest.union(ra, rb);
            }
        }
    }
    let mut id = vec![u32::MAX; n];
    let mut next = 0;
    let mut out = vec![0u32; n];
    for (i, o) in out.iter_mut().enumerate() {
        let r = forest.find(i as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = next;
            next += 1;
        }
        *o = id[r];
    }
    out
}

/// The class of every node from its segment: the segment's members each vote for their
/// argmax class, and the segment takes, among the classes voted for, the one with the
/// largest summed probability (ties: the smaller id). A class no member voted for is never
/// chosen.
///
/// # Shapes
/// `segment`: `[n]` ids `0..m`; `probs`: `[n, k]`; result `[n]`.
pub fn vote(segment: &[u32], probs: &[f32], k: usize) -> Vec<u8> {
    let own = argmax_rows(probs, k);
    let m = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
    let mut sums = vec![0f64; m * k];
    let mut voted = vec![false; m * k];
    for (i, &s) in segment.iter().enumerate() {
        let s = s as usize;
        for (acc, &p) in sums[s * k..(s + 1) * k].iter_mut().zip(&probs[i * k..(i + 1) * k]) {
            *acc += f64::from(p);
        }
        voted[s * k + own[i] as usize] = true;
    }
    let class: Vec<u8> = (0..m)
        .map(|s| {
            let mut best: Option<usize> = None;
            for c in 0..k {
                if voted[s * k + c] && best.is_none_or(|b| sums[s * k + c] > sums[s * k + b]) {
                    best = Some(c);
                }
            }
            best.unwrap_or(0) as u8
        })
        .collect();
    segment.iter().map(|&s| class[s as usize]).collect()
}

/// A horizontal plane: its fullest level and the levels around it that belong to it (voxel
/// levels along z).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plane {
    /// The level with the most horizontal voxels.
    pub level: i32,
    /// Lowest level of the plane.
    pub lo: i32,
    /// Highest level of the plane.
    pub hi: i32,
}

/// The floor and ceiling planes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Planes {
    /// The floor.
    pub floor: Option<Plane>,
    /// The ceiling.
    pub ceiling: Option<Plane>,
}

/// The floor and ceiling of a room with z up: among the levels (z coordinates) of the
/// horizontal voxels (`|n_z| >= normal_z_min`), a plane at level `l` counts the horizontal
/// voxels of levels `l - band ..= l + band`; it is big when they cover `min_area_m2` and
/// `min_footprint_share` of the footprint (the occupied x-y columns). The floor is the
/// lowest big plane if at most `max_share_beyond` of all voxels lie below it; the ceiling is
/// the highest big plane if it is at least `min_room_height_m` above the floor (with no
/// floor: above the lowest voxel) and at most `max_share_beyond` of the voxels lie above it.
/// A plane's level is the fullest of its band, and it spans the neighbouring levels (within
/// the band) that hold at least `member_share` as many horizontal voxels (a noisy or
/// half-voxel-offset floor spreads over two levels; a sofa's underside 5 cm above the floor
/// does not make the floor thicker).
///
/// # Shapes
/// `coords`, `normals`: `[n]`.
pub fn find_planes(coords: &[Coord], normals: &[Vec3], voxel_size: f32, params: &PlaneParams) -> Planes {
    let n = coords.len();
    if n == 0 {
        return Planes::default();
    }
    // Voxel counts per level, all and horizontal, indexed from the lowest level.
    let z0 = coords.iter().map(|c| c[2]).min().unwrap_or(0);
    let z1 = coords.iter().map(|c| c[2]).max().unwrap_or(0);
    let levels = (i64::from(z1) - i64::from(z0) + 1) as usize;
    let mut all_count = vec![0usize; levels];
    let mut horizontal_count = vec![0usize; levels];
    let mut columns: Vec<(i32, i32, i32)> = Vec::with_capacity(n);
    for (c, nrm) in coords.iter().zip(normals) {
        let l = (c[2] - z0) as usize;
        all_count[l] += 1;
        if nrm.z.abs() >= params.normal_z_min {
            horizontal_count[l] += 1;
        }
        columns.push((c[0], c[1], c[3]));
    }
    let all: BTreeMap<i32, usize> =
        all_count.iter().enumerate().filter(|(_, &c)| c > 0).map(|(l, &c)| (z0 + l as i32, c)).collect();
    let horizontal: BTreeMap<i32, usize> =
        horizontal_count.iter().enumerate().filter(|(_, &c)| c > 0).map(|(l, &c)| (z0 + l as i32, c)).collect();
    columns.par_sort_unstable();
    columns.dedup();
    let cell = f64::from(voxel_size) * f64::from(voxel_size);
    let need = (f64::from(params.min_area_m2)).max(f64::from(params.min_footprint_share) * columns.len() as f64 * cell);
    let band = params.band.max(0);
    let h = |l: i32| horizontal.get(&l).copied().unwrap_or(0);
    let band_count = |l: i32| (l - band..=l + band).map(h).sum::<usize>();
    let big = |l: i32| band_count(l) as f64 * cell >= need;
    let max_beyond = f64::from(params.max_share_beyond) * n as f64;
    let lowest = *all.keys().next().unwrap_or(&0);
    let room = (params.min_room_height_m / voxel_size).round() as i32;
    let plane_at = |peak: i32| {
        let member = |l: i32| h(l) as f64 >= f64::from(params.member_share) * h(peak) as f64;
        let mut lo = peak;
        while lo > peak - band && member(lo - 1) {
            lo -= 1;
        }
        let mut hi = peak;
        while hi < peak + band && member(hi + 1) {
            hi += 1;
        }
        Plane { level: peak, lo, hi }
    };

    let mut planes = Planes::default();
    if let Some(l) = horizontal.keys().copied().find(|&l| big(l)) {
        // The fullest level of the band (the lowest on ties).
        let peak = (l - band..=l + band).fold(l - band, |best, x| if h(x) > h(best) { x } else { best });
        let plane = plane_at(peak);
        let below = all.range(..plane.lo).map(|(_, &c)| c).sum::<usize>();
        if below as f64 <= max_beyond {
            planes.floor = Some(plane);
        }
    }
    if let Some(l) = horizontal.keys().rev().copied().find(|&l| big(l)) {
        let peak = (l - band..=l + band).rev().fold(l + band, |best, x| if h(x) > h(best) { x } else { best });
        let plane = plane_at(peak);
        let base = planes.floor.map_or(lowest, |f| f.level);
        let above = all.range(plane.hi + 1..).map(|(_, &c)| c).sum::<usize>();
        if peak - base >= room && above as f64 <= max_beyond {
            planes.ceiling = Some(plane);
        }
    }
    planes
}

/// Where a voxel lies with respect to the planes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneMember {
    /// On neither plane.
    No,
    /// A horizontal voxel within the floor's band.
    Floor,
    /// A horizontal voxel within the ceiling's band.
    Ceiling,
}

/// What the planes say about every voxel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlaneCorrections {
    /// Membership of each voxel.
    pub kind: Vec<PlaneMember>,
    /// The voxel cannot be floor: more than `off_plane_m` above the floor, or (without a
    /// floor) closer than `min_room_height_m` below the ceiling.
    pub no_floor: Vec<bool>,
    /// The voxel cannot be ceiling: more than `off_plane_m` below the ceiling, or (without a
    /// ceiling) closer than `min_room_height_m` above the floor.
    pub no_ceiling: Vec<bool>,
}

/// Plane membership and the classes ruled out by height, per voxel (see
/// [`PlaneCorrections`]).
///
/// # Shapes
/// `coords`, `normals`: `[n]`; result vectors `[n]`.
pub fn plane_corrections(
    coords: &[Coord],
    normals: &[Vec3],
    planes: &Planes,
    voxel_size: f32,
    params: &PlaneParams,
) -> PlaneCorrections {
    let off = (params.off_plane_m / voxel_size).round() as i32;
    let room = (params.min_room_height_m / voxel_size).round() as i32;
    let mut out = PlaneCorrections::default();
    for (c, nrm) in coords.iter().zip(normals) {
        let z = c[2];
        let horizontal = nrm.z.abs() >= params.normal_z_min;
        let on = |p: &Option<Plane>| p.is_some_and(|p| (p.lo..=p.hi).contains(&z));
        let kind = if horizontal && on(&planes.floor) {
            PlaneMember::Floor
        } else if horizontal && on(&planes.ceiling) {
            PlaneMember::Ceiling
        } else {
            PlaneMember::No
        };
        let no_floor = match (planes.floor, planes.ceiling) {
            (Some(f), _) => z > f.hi + off,
            (None, Some(cl)) => z > cl.level - room,
            (None, None) => false,
        };
        let no_ceiling = match (planes.ceiling, planes.floor) {
            (Some(cl), _) => z < cl.lo - off,
            (None, Some(f)) => z < f.level + room,
            (None, None) => false,
        };
        out.kind.push(kind);
        out.no_floor.push(no_floor);
        out.no_ceiling.push(no_ceiling);
    }
    out
}

/// Applies [`PlaneCorrections`] to probabilities: plane members become one-hot floor /
/// ceiling, classes ruled out at a voxel get probability 0 (the rest is left unnormalised).
fn apply_corrections(probs: &mut [f32], k: usize, c: &PlaneCorrections) {
    let floor = SemanticClass::Floor.id() as usize;
    let ceiling = SemanticClass::Ceiling.id() as usize;
    for (i, row) in probs.chunks_exact_mut(k).enumerate() {
        match c.kind[i] {
            PlaneMember::Floor | PlaneMember::Ceiling => {
                let keep = if c.kind[i] == PlaneMember::Floor { floor } else { ceiling };
                row.iter_mut().enumerate().for_each(|(j, v)| *v = if j == keep { 1.0 } else { 0.0 });
            }
            PlaneMember::No => {
                if c.no_floor[i] {
                    row[floor] = 0.0;
                }
                if c.no_ceiling[i] {
                    row[ceiling] = 0.0;
                }
            }
        }
    }
}

/// The `t`-th of the eight symmetries of the square grid about the z axis applied to a
/// voxel: `0` identity, `1` half turn, `2`, `3` mirrors in x and y, `4`, `5` quarter
/// turns, `6`, `7` the diagonal mirrors (`t` modulo 8). Negation is `-x - 1`, which maps
/// the grid, and every coarser level's cells, onto itself.
pub fn grid_symmetry(c: Coord, t: usize) -> Coord {
    let [x, y, z, b] = c;
    let (nx, ny) = (!x, !y);
    let (x2, y2) = match t % 8 {
        0 => (x, y),
        1 => (nx, ny),
        2 => (nx, y),
        3 => (x, ny),
        4 => (ny, x),
        5 => (y, nx),
        6 => (y, x),
        _ => (ny, nx),
    };
    [x2, y2, z, b]
}

/// Class probabilities of every voxel averaged over `n` (1..=8) symmetries of the grid
/// ([`grid_symmetry`]); `n <= 1` is the network's softmax alone. `identity_logits`, the
/// network's scores of the unmoved voxels when the caller has them already, saves that pass.
///
/// # Shapes
/// `coords`: `[v]`; `features`: `[v, in_channels]`; `identity_logits`: `[v, classes]`;
/// result `[v, classes]` in the order of `coords`.
///
/// # Errors
/// Those of [`Segmenter::segment`]; [`NetError::InvalidInput`] for identity logits of
/// another length.
pub fn tta_probabilities(
    net: &mut Segmenter,
    coords: &[Coord],
    features: &[f32],
    n: usize,
    identity_logits: Option<Vec<f32>>,
) -> Result<Vec<f32>> {
    let k = net.config().classes;
    let n = n.clamp(1, 8);
    let mut first = identity_logits;
    if first.as_ref().is_some_and(|l| l.len() != coords.len() * k) {
        return Err(NetError::InvalidInput(format!("identity logits do not match {} voxels", coords.len())));
    }
    let mut sum = vec![0f32; coords.len() * k];
    for t in 0..n {
        let mut p = match first.take() {
            Some(l) => l,
            None => {
                let moved: Vec<Coord> = coords.iter().map(|&c| grid_symmetry(c, t)).collect();
                net.segment(&moved, features)?
            }
        };
        softmax_rows(&mut p, k);
        if n == 1 {
            return Ok(p);
        }
        sum.iter_mut().zip(&p).for_each(|(s, v)| *s += v);
    }
    let inv = 1.0 / n as f32;
    sum.iter_mut().for_each(|s| *s *= inv);
    Ok(sum)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::collections::HashSet;

    /// Plain reference of Felzenszwalb-Huttenlocher: explicit member lists, a merge
    /// relabels every member.
    fn felzenszwalb_reference(n: usize, edges: &[Edge], k: f32, min_size: usize) -> Vec<usize> {
        let mut sorted = edges.to_vec();
        // Stable: ties keep the input order.
        sorted.sort_by(|x, y| x.w.total_cmp(&y.w));
        let mut comp: Vec<usize> = (0..n).collect();
        let mut internal = vec![0f32; n];
        let size = |comp: &[usize], c: usize| comp.iter().filter(|&&x| x == c).count();
        for e in &sorted {
            let (ca, cb) = (comp[e.a as usize], comp[e.b as usize]);
            if ca == cb {
                continue;
            }
            let (sa, sb) = (size(&comp, ca), size(&comp, cb));
            if e.w <= internal[ca] + k / sa as f32 && e.w <= internal[cb] + k / sb as f32 {
                comp.iter_mut().filter(|x| **x == cb).for_each(|x| *x = ca);
                internal[ca] = e.w;
            }
        }
        for e in &sorted {
            let (ca, cb) = (comp[e.a as usize], comp[e.b as usize]);
            if ca != cb && (size(&comp, ca) < min_size || size(&comp, cb) < min_size) {
                comp.iter_mut().filter(|x| **x == cb).for_each(|x| *x = ca);
            }
        }
        comp
    }

    /// Connected components by breadth-first search.
    fn components(n: usize, edges: &[Edge]) -> Vec<usize> {
        let mut adj = vec![Vec::new(); n];
        for e in edges {
            adj[e.a as usize].push(e.b as usize);
            adj[e.b as usize].push(e.a as usize);
        }
        let mut comp = vec![usize::MAX; n];
        for s in 0..n {
            if comp[s] != usize::MAX {
                continue;
            }
            comp[s] = s;
            let mut queue = std::collections::VecDeque::from([s]);
            while let Some(u) = queue.pop_front() {
                for &v in &adj[u] {
                    if comp[v] == usize::MAX {
                        comp[v] = s;
                        queue.push_back(v);
                    }
                }
            }
        }
        comp
    }

    /// Whether two labellings describe the same partition.
    fn same_partition<A: Copy + Eq + std::hash::Hash, B: Copy + Eq + std::hash::Hash>(a: &[A], b: &[B]) -> bool {
        let mut ab = std::collections::HashMap::new();
        let mut ba = std::collections::HashMap::new();
        a.iter().zip(b).all(|(&x, &y)| *ab.entry(x).or_insert(y) == y && *ba.entry(y).or_insert(x) == x)
    }

    fn random_graph(rng: &mut ChaCha8Rng) -> (usize, Vec<Edge>) {
        let n = rng.random_range(1..40);
        let m = rng.random_range(0..n * 2);
        let edges = (0..m)
            .map(|_| {
                let a = rng.random_range(0..n as u32);
                let b = rng.random_range(0..n as u32);
                // Quantised weights: ties happen and must be broken the same way.
                Edge { a, b, w: rng.random_range(0..20) as f32 * 0.05 }
            })
            .filter(|e| e.a != e.b)
            .collect();
        (n, edges)
    }

    #[test]
    fn segmentation_matches_the_plain_reference_and_connected_components() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..400 {
            let (n, edges) = random_graph(&mut rng);
            let k = rng.random_range(0.0..2.0);
            let min_size = rng.random_range(0..6);
            let got = felzenszwalb(n, &edges, k, min_size);
            let want = felzenszwalb_reference(n, &edges, k, min_size);
            assert!(same_partition(&got, &want), "n {n} k {k} min {min_size}: {got:?} vs {want:?}");
            // Numbered in order of first node.
            let mut next = 0;
            for &s in &got {
                assert!(s <= next);
                next = next.max(s + 1);
            }
            // A huge k, or a minimum size above n, joins every connected component whole.
            let cc = components(n, &edges);
            assert!(same_partition(&felzenszwalb(n, &edges, 1e9, 0), &cc));
            assert!(same_partition(&felzenszwalb(n, &edges, 0.0, n + 1), &cc));
            // Segments never join nodes of different components.
            assert!(got.iter().zip(&cc).all(|(&s, &c)| got.iter().zip(&cc).all(|(&s2, &c2)| s != s2 || c == c2)));
        }
    }

    #[test]
    fn vote_takes_a_voted_class_with_the_largest_sum() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..300 {
            let n = rng.random_range(1..30);
            let k = rng.random_range(1..6);
            let m = rng.random_range(1..=n) as u32;
            let segment: Vec<u32> =
                (0..n).map(|i| if (i as u32) < m { i as u32 } else { rng.random_range(0..m) }).collect();
            let mut probs: Vec<f32> = (0..n * k).map(|_| rng.random_range(0.0..1.0)).collect();
            softmax_rows(&mut probs, k);
            let got = vote(&segment, &probs, k);
            let own = argmax_rows(&probs, k);
            for s in 0..m {
                let members: Vec<usize> = (0..n).filter(|&i| segment[i] == s).collect();
                let voted: Vec<u8> = members.iter().map(|&i| own[i]).collect();
                let class = got[members[0]];
                assert!(members.iter().all(|&i| got[i] == class));
                assert!(voted.contains(&class), "class {class} not among the votes {voted:?}");
                let sum = |c: usize| members.iter().map(|&i| f64::from(probs[i * k + c])).sum::<f64>();
                for &v in &voted {
                    assert!(sum(class as usize) >= sum(v as usize));
                }
            }
        }
        // The case that an unrestricted sum gets wrong: class 2 has the largest sum but no
        // member's vote.
        let probs = [0.45, 0.1, 0.45 - 1e-3, 0.1, 0.45, 0.45 - 1e-3];
        let got = vote(&[0, 0], &probs, 3);
        assert!(got[0] == 0 || got[0] == 1, "{got:?}");
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn eigen_matches_the_definition_on_random_matrices() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..500 {
            let mut a = [[0.0f64; 3]; 3];
            for i in 0..3 {
                for j in i..3 {
                    let v = rng.random_range(-2.0..2.0);
                    a[i][j] = v;
                    a[j][i] = v;
                }
            }
            let (values, vectors) = symmetric_eigen3(a);
            assert!(values[0] <= values[1] && values[1] <= values[2]);
            for (lambda, v) in values.iter().zip(vectors) {
                let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!((norm - 1.0).abs() < 1e-9);
                for i in 0..3 {
                    let av: f64 = (0..3).map(|j| a[i][j] * v[j]).sum();
                    assert!((av - lambda * v[i]).abs() < 1e-9, "{a:?}");
                }
            }
            // The smallest eigenvalue is the minimum of the Rayleigh quotient.
            for _ in 0..50 {
                let u = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0f64)];
                let uu: f64 = u.iter().map(|x| x * x).sum();
                let uau: f64 = (0..3).map(|i| (0..3).map(|j| u[i] * a[i][j] * u[j]).sum::<f64>()).sum();
                assert!(uau / uu >= values[0] - 1e-9);
            }
        }
    }

    #[test]
    fn neighbours_and_normals_match_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut set = HashSet::new();
        while set.len() < 300 {
            set.insert([rng.random_range(-4..4), rng.random_range(-4..4), rng.random_range(-4..4), 0]);
        }
        let coords: Vec<Coord> = set.into_iter().collect();
        let nb = voxel_neighbours(&coords);
        for (i, c) in coords.iter().enumerate() {
            for (slot, o) in nb[i].iter().zip(NEIGHBOUR_OFFSETS) {
                let q = [c[0] + o[0], c[1] + o[1], c[2] + o[2], 0];
                let want = coords.iter().position(|&d| d == q).map_or(NO_NEIGHBOUR, |j| j as u32);
                assert_eq!(*slot, want);
            }
        }
        // A tilted digital plane: normals close to the plane's.
        let mut plane = Vec::new();
        for x in -10..10 {
            for y in -10..10 {
                plane.push([x, y, (0.3 * x as f32 + 0.1 * y as f32).round() as i32, 0]);
            }
        }
        let normals = voxel_normals(&plane, &voxel_neighbours(&plane));
        let want = Vec3::new(-0.3, -0.1, 1.0).normalize();
        let inner: Vec<f32> = plane
            .iter()
            .zip(&normals)
            .filter(|(c, _)| c[0].abs() < 8 && c[1].abs() < 8)
            .map(|(_, n)| n.dot(want))
            .collect();
        let mean = inner.iter().sum::<f32>() / inner.len() as f32;
        assert!(mean > 0.97, "{mean}");
        // Horizontal planes give exactly vertical normals.
        let flat: Vec<Coord> = (0..100).map(|i| [i % 10, i / 10, 3, 0]).collect();
        assert!(voxel_normals(&flat, &voxel_neighbours(&flat)).iter().all(|n| (n.z - 1.0).abs() < 1e-6));
    }

    #[test]
    fn offset_slots_follow_the_table() {
        for (i, o) in NEIGHBOUR_OFFSETS.iter().enumerate() {
            assert_eq!(offset_slot(o[0], o[1], o[2]), i);
        }
    }

    #[test]
    fn edges_list_each_neighbour_pair_once_with_its_weight() {
        let coords: Vec<Coord> = (0..27).map(|i| [i % 3, (i / 3) % 3, i / 9, 0]).collect();
        let nb = voxel_neighbours(&coords);
        let normals = vec![Vec3::Z; 27];
        let features: Vec<f32> = (0..27 * 3).map(|i| (i % 7) as f32 * 0.1 - 0.3).collect();
        let edges = voxel_edges(&nb, &normals, &features, 2.0);
        // Pairs at Chebyshev distance 1 in a 3x3x3 block.
        let mut want = 0;
        for i in 0..27 {
            for j in i + 1..27 {
                let d = (0..3).map(|a| (coords[i][a] - coords[j][a]).abs()).max().unwrap_or(0);
                if d == 1 {
                    want += 1;
                }
            }
        }
        assert_eq!(edges.len(), want);
        for e in &edges {
            let (a, b) = (e.a as usize, e.b as usize);
            let dc: f32 =
                (0..3).map(|c| ((features[a * 3 + c] - features[b * 3 + c]) / 2.0).powi(2)).sum::<f32>().sqrt();
            assert!((e.w - 2.0 * dc).abs() < 1e-6);
        }
    }

    /// A synthetic room: a floor at level 0, a ceiling at level 50 (2.5 m at 5 cm), four
    /// walls and a table top at level 15.
    fn box_room() -> Vec<Coord> {
        let mut v = Vec::new();
        for x in 0..80 {
            for y in 0..60 {
                v.push([x, y, 0, 0]);
                v.push([x, y, 50, 0]);
            }
        }
        for z in 1..50 {
            for x in 0..80 {
                v.push([x, 0, z, 0]);
                v.push([x, 59, z, 0]);
            }
            for y in 1..59 {
                v.push([0, y, z, 0]);
                v.push([79, y, z, 0]);
            }
        }
        for x in 30..50 {
            for y in 20..36 {
                v.push([x, y, 15, 0]);
            }
        }
        v
    }

    #[test]
    fn planes_of_a_box_room_and_of_partial_scans() {
        let params = PlaneParams::default();
        let room = box_room();
        let normals = voxel_normals(&room, &voxel_neighbours(&room));
        let level = |p: Planes| (p.floor.map(|f| f.level), p.ceiling.map(|c| c.level));
        let planes = find_planes(&room, &normals, 0.05, &params);
        assert_eq!(level(planes), (Some(0), Some(50)));
        assert_eq!(planes.floor, Some(Plane { level: 0, lo: 0, hi: 0 }));
        // Without its ceiling: the floor alone; without the floor either: nothing (the table
        // top is too small a share of the footprint).
        let open: Vec<Coord> = room.iter().copied().filter(|c| c[2] < 50).collect();
        let normals = voxel_normals(&open, &voxel_neighbours(&open));
        assert_eq!(level(find_planes(&open, &normals, 0.05, &params)), (Some(0), None));
        let walls: Vec<Coord> = open.iter().copied().filter(|c| c[2] > 0).collect();
        let normals = voxel_normals(&walls, &voxel_neighbours(&walls));
        assert_eq!(find_planes(&walls, &normals, 0.05, &params), Planes::default());
        // A low "ceiling" 1 m above the floor is not one.
        let low: Vec<Coord> = room.iter().copied().filter(|c| c[2] <= 20).collect();
        let normals = voxel_normals(&low, &voxel_neighbours(&low));
        assert_eq!(find_planes(&low, &normals, 0.05, &params).ceiling, None);
    }

    #[test]
    fn plane_detection_finds_the_floor_of_a_generated_room_at_zero() {
        use semrecon_data::synth::{generate_room, RoomConfig};
        let room = generate_room(&RoomConfig { seed: 2_000_003, style: None });
        let cloud = crate::surface::sample_surface(&room.mesh, crate::dataset::points_per_m2(0.05), 0);
        let sample = crate::sample::VoxelSample::from_cloud(&cloud, 0.05).unwrap();
        let normals = voxel_normals(&sample.coords, &voxel_neighbours(&sample.coords));
        let planes = find_planes(&sample.coords, &normals, 0.05, &PlaneParams::default());
        let floor = planes.floor.expect("a floor").level;
        assert!((-1..=0).contains(&floor), "floor at level {floor}");
        let top = sample.coords.iter().map(|c| c[2]).max().unwrap();
        let ceiling = planes.ceiling.expect("a ceiling").level;
        assert!((top - 2..=top).contains(&ceiling), "ceiling at level {ceiling}, top {top}");
    }

    #[test]
    fn refine_is_identity_without_structure_and_deterministic_across_threads() {
        let room = box_room();
        let k = SemanticClass::COUNT;
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut probs: Vec<f32> = (0..room.len() * k).map(|_| rng.random_range(-2.0..2.0)).collect();
        softmax_rows(&mut probs, k);
        let features: Vec<f32> = (0..room.len() * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        let none =
            refine_labels(&room, &features, &probs, k, 0.05, &StructureConfig::new(StructureMode::None)).unwrap();
        assert_eq!(none, argmax_rows(&probs, k));
        for mode in [StructureMode::Segments, StructureMode::Planes, StructureMode::All] {
            let config = StructureConfig::new(mode);
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| refine(&room, &features, &probs, k, 0.05, &config).unwrap())
            };
            let one = run(1);
            assert_eq!(one.labels, run(4).labels, "{mode}");
            assert_eq!(one.labels, run(3).labels, "{mode}");
            if mode.planes() {
                // The floor and ceiling voxels take their classes; the table top (level 15)
                // is never floor or ceiling.
                assert_eq!(one.floor_z, Some(0.025));
                for (c, &l) in room.iter().zip(&one.labels) {
                    let inner = (2..78).contains(&c[0]) && (2..58).contains(&c[1]);
                    if c[2] == 0 && inner {
                        assert_eq!(l, SemanticClass::Floor.id());
                    }
                    if c[2] == 15 {
                        assert!(l != SemanticClass::Floor.id() && l != SemanticClass::Ceiling.id());
                    }
                }
            }
        }
    }

    #[test]
    fn tta_averages_probabilities_over_the_symmetries() {
        use crate::{NetConfig, Weights};
        let config = NetConfig::new("tiny", 3, 4, 0.05);
        let mut net = Segmenter::new(Weights::random(&config, 3), config).unwrap();
        let coords: Vec<Coord> = (0..60).map(|i| [i % 7, (i / 7) % 5, i / 35, 0]).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let features: Vec<f32> = (0..coords.len() * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        let k = net.config().classes;
        // One pass is the network's softmax, with or without the caller's logits.
        let mut want = net.segment(&coords, &features).unwrap();
        let logits = want.clone();
        softmax_rows(&mut want, k);
        assert_eq!(tta_probabilities(&mut net, &coords, &features, 1, None).unwrap(), want);
        assert_eq!(tta_probabilities(&mut net, &coords, &features, 1, Some(logits.clone())).unwrap(), want);
        // Four passes: the mean of the four moved rooms' softmax, row sums 1.
        let mut mean = vec![0f32; want.len()];
        for t in 0..4 {
            let moved: Vec<Coord> = coords.iter().map(|&c| grid_symmetry(c, t)).collect();
            let mut p = net.segment(&moved, &features).unwrap();
            softmax_rows(&mut p, k);
            mean.iter_mut().zip(&p).for_each(|(m, v)| *m += v / 4.0);
        }
        let got = tta_probabilities(&mut net, &coords, &features, 4, Some(logits)).unwrap();
        assert!(got.iter().zip(&mean).all(|(a, b)| (a - b).abs() < 1e-5));
        assert!(got.chunks_exact(k).all(|r| (r.iter().sum::<f32>() - 1.0).abs() < 1e-4));
    }

    #[test]
    fn grid_symmetries_are_bijections_that_keep_coarse_cells() {
        let coords: Vec<Coord> = (-20..20).flat_map(|x| (-20..20).map(move |y| [x, y, 3, 0])).collect();
        for t in 0..8 {
            let moved: HashSet<Coord> = coords.iter().map(|&c| grid_symmetry(c, t)).collect();
            assert_eq!(moved.len(), coords.len());
            // Voxels sharing a 16-voxel cell still share one.
            for c in &coords {
                let d = [c[0] ^ 1, c[1], c[2], c[3]];
                let (mc, md) = (grid_symmetry(*c, t), grid_symmetry(d, t));
                assert_eq!([mc[0] >> 4, mc[1] >> 4], [md[0] >> 4, md[1] >> 4]);
            }
        }
    }
}
