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
//! Test-time augmentation, which the probabilities given here may come from, is
//! [`crate::tta`].
//!
//! What each step buys on real and generated data, and what it costs against the network
//! call, is measured in docs/model.md ("Structure at inference"): the segment vote raised the
//! real S3DIS fragment's accuracy from 47.1 to 55.7 % at about a tenth of the network's time
//! and is the default of `semrecon segment` and `eval seg`; the planes are right but change
//! almost nothing the network had wrong, so they are opt-in. Everything here is
//! deterministic: the same labels for any number of rayon threads (parallel steps map each
//! voxel on its own; sorting breaks ties by index; the union-find and the sums run in
//! order).
//!
//! 3. **A beam's face starts at its underside.** After the vote, a vertical wall segment that
//!    rises from a horizontal beam segment high above the floor, along most of its lower
//!    edge, and whose plane does not go on below it, is the beam's face ([`beam_faces`]):
//!    S3DIS labels a bulkhead's faces beam, and the network cannot tell such a face from the
//!    strip of wall above a doorway. Part of the segments step (`--no-beam-faces` leaves it
//!    out).
//!
//! The steps live in submodules by concept, re-exported here: `neighbours` (the
//! 26-neighbourhood of the occupied voxels), `normals` (their PCA normals and the 3x3 eigen
//! solver), `segments` (the graph segmentation and the vote), `beam_faces` and `planes`
//! (floor and ceiling). This file holds the configuration and [`refine`], which runs them in order.

mod beam_faces;
mod neighbours;
mod normals;
mod planes;
mod segments;

pub use beam_faces::{beam_faces, BeamFaceParams};
pub use neighbours::{voxel_neighbours, NEIGHBOUR_OFFSETS, NO_NEIGHBOUR};
pub use normals::{symmetric_eigen3, voxel_normals};
pub use planes::{find_planes, plane_corrections, Plane, PlaneCorrections, PlaneMember, PlaneParams, Planes};
pub use segments::{edge_order, felzenszwalb, vote, voxel_edges, Edge, SegmentParams};

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

use rayon::prelude::*;
use semrecon_data::SemanticClass;
use semrecon_sparse::Coord;

use crate::error::{NetError, Result};
use planes::apply_corrections;

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

/// What [`refine`] does and with which parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StructureConfig {
    /// Which steps run.
    pub mode: StructureMode,
    /// The graph segmentation.
    pub segments: SegmentParams,
    /// The planes.
    pub planes: PlaneParams,
    /// After the segment vote, wall faces that rise from a beam's underside become beam
    /// ([`beam_faces`]); `None` leaves the vote as it is. Runs only with the segments.
    pub beam_faces: Option<BeamFaceParams>,
}

impl Default for StructureConfig {
    fn default() -> Self {
        Self {
            mode: StructureMode::default(),
            segments: SegmentParams::default(),
            planes: PlaneParams::default(),
            beam_faces: Some(BeamFaceParams::default()),
        }
    }
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
    /// The segment of every voxel (empty when the vote did not run): what a second label set
    /// can vote over too ([`crate::home_head::label_voxels`]).
    pub segment: Vec<u32>,
    /// Height of the floor plane (metres, voxel centres), when one was found and used.
    pub floor_z: Option<f32>,
    /// Height of the ceiling plane, when one was found and used.
    pub ceiling_z: Option<f32>,
    /// Voxels whose class differs from the network's own.
    pub changed: usize,
    /// Voxels that became beam as faces of a beam ([`beam_faces`]).
    pub beam_face_voxels: usize,
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
/// [`vote`] on the (corrected) probabilities, then (unless `config.beam_faces` is `None`)
/// [`beam_faces`]; plane voxels stay floor / ceiling after the vote, and a vote that gives a voxel a class impossible at its height falls back to the
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
    let mut segment_of = Vec::new();
    let mut beam_face_voxels = 0;
    let mut labels = if mode.segments() {
        let edges = voxel_edges(&neighbours, &normals, features, config.segments.color_weight);
        let segment = felzenszwalb(n, &edges, config.segments.k, config.segments.min_size);
        segments = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
        let mut voted = vote(&segment, p, classes);
        let (wall, beam) = (SemanticClass::Wall.id(), SemanticClass::Beam.id());
        if let Some(params) = &config.beam_faces {
            if classes > wall.max(beam) as usize {
                beam_face_voxels =
                    beam_faces(coords, &neighbours, &normals, &segment, &mut voted, voxel_size, wall, beam, params);
            }
        }
        segment_of = segment;
        voted
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
    Ok(Refinement { labels, segments, segment: segment_of, floor_z, ceiling_z, changed, beam_face_voxels, timing })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::planes::tests::box_room;
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
}
