//! The home head: a second label set for homes ([`HomeClass`]: ScanNet's 20 classes and the
//! ceiling) on the same network, stored beside the S3DIS head in the same weights file
//! (tensors named `home_head.*`).
//!
//! S3DIS calls beds, cabinets, counters, toilets, sinks, curtains and pictures all `clutter`.
//! The home head splits what the S3DIS head calls furniture or clutter into the 16 object
//! classes of the home set; the shell (ceiling, floor, wall, beam, column, door, window)
//! keeps the S3DIS head's decision, and its chairs and sofas bound the head's
//! ([`allowed_objects`]), which was tuned on real scans (pseudo-labels, scan imitation)
//! and which a head trained on generated rooms alone should not overrule.
//!
//! It is a small MLP (one hidden ReLU layer) over what the S3DIS head reads of a voxel (its
//! batch-normed, rectified decoder features), the S3DIS class probabilities, and the voxel's
//! height above the floor (a bed's top is at half a metre, a counter's at ninety
//! centimetres: the network's convolutions are translation invariant and see no height). The
//! backbone is frozen: the head is fitted on features of rooms furnished from the furniture
//! catalogues (`examples/train_home_head.rs`), so adding it changes no S3DIS label.

use rayon::prelude::*;
use semrecon_data::class::{SemanticClass, UNLABELED};
use semrecon_data::home_class::HomeClass;
use semrecon_sparse::Coord;

use crate::error::{NetError, Result};
use crate::structure::softmax_rows;
use crate::weights::{Tensor, Weights};

/// Prefix of the home head's tensors in a weights file.
pub const HOME_HEAD_PREFIX: &str = "home_head.";

/// Inputs besides the head features: the S3DIS probabilities, then the height.
const HEIGHT_INPUTS: usize = 1;

/// Heights are clamped to this range (metres above the floor) before they enter the head.
const HEIGHT_RANGE: (f32, f32) = (-0.5, 3.0);

/// Tensor names: `[in, hidden]`, `[hidden]`, `[hidden, objects]`, `[objects]`.
const TENSORS: [&str; 4] = ["hidden.weight", "hidden.bias", "out.weight", "out.bias"];

/// The home head's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct HomeHead {
    /// Input width: head features, S3DIS classes, height.
    inputs: usize,
    hidden: usize,
    /// `[inputs, hidden]`.
    w1: Vec<f32>,
    b1: Vec<f32>,
    /// `[hidden, OBJECTS]`.
    w2: Vec<f32>,
    b2: Vec<f32>,
}

/// Number of outputs: the object classes, in [`HomeClass::OBJECTS`] order.
pub const OBJECTS: usize = HomeClass::OBJECTS.len();

impl HomeHead {
    /// Input width for a network with `head_channels` decoder channels and `classes` S3DIS
    /// classes.
    pub fn input_width(head_channels: usize, classes: usize) -> usize {
        head_channels + classes + HEIGHT_INPUTS
    }

    /// A head from its parameters.
    ///
    /// # Shapes
    /// `w1`: `[inputs, hidden]`; `b1`: `[hidden]`; `w2`: `[hidden, OBJECTS]`; `b2`: `[OBJECTS]`.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] when the lengths do not agree.
    pub fn new(inputs: usize, hidden: usize, w1: Vec<f32>, b1: Vec<f32>, w2: Vec<f32>, b2: Vec<f32>) -> Result<Self> {
        if w1.len() != inputs * hidden || b1.len() != hidden || w2.len() != hidden * OBJECTS || b2.len() != OBJECTS {
            return Err(NetError::InvalidInput(format!(
                "home head of {inputs} inputs and {hidden} hidden units: tensors of {}, {}, {}, {} values",
                w1.len(),
                b1.len(),
                w2.len(),
                b2.len()
            )));
        }
        Ok(Self { inputs, hidden, w1, b1, w2, b2 })
    }

    /// The head stored in `weights`, if it has one.
    ///
    /// # Errors
    /// [`NetError::TensorShape`] / [`NetError::MissingTensor`] naming the file when some of
    /// its tensors are there but not all, or of inconsistent shapes.
    pub fn from_weights(weights: &Weights) -> Result<Option<Self>> {
        let present =
            TENSORS.iter().filter(|t| weights.tensors().contains_key(&format!("{HOME_HEAD_PREFIX}{t}"))).count();
        if present == 0 {
            return Ok(None);
        }
        let get = |t: &str| -> Result<&Tensor> {
            let name = format!("{HOME_HEAD_PREFIX}{t}");
            weights
                .tensors()
                .get(&name)
                .ok_or_else(|| NetError::MissingTensor { file: weights.source().to_string(), tensor: name })
        };
        let w1 = get(TENSORS[0])?;
        let shape_err = |t: &str, got: &Tensor, expected: Vec<usize>| NetError::TensorShape {
            file: weights.source().to_string(),
            tensor: format!("{HOME_HEAD_PREFIX}{t}"),
            expected,
            got: got.shape.clone(),
        };
        let [inputs, hidden] = w1.shape[..] else {
            return Err(shape_err(TENSORS[0], w1, vec![0, 0]));
        };
        let expected = [vec![inputs, hidden], vec![hidden], vec![hidden, OBJECTS], vec![OBJECTS]];
        let mut parts = Vec::new();
        for (t, e) in TENSORS.iter().zip(expected) {
            let tensor = get(t)?;
            if tensor.shape != e || tensor.data.len() != e.iter().product::<usize>() {
                return Err(shape_err(t, tensor, e));
            }
            parts.push(tensor.data.clone());
        }
        let [w1, b1, w2, b2]: [Vec<f32>; 4] =
            parts.try_into().map_err(|_| NetError::InvalidInput("home head".into()))?;
        Self::new(inputs, hidden, w1, b1, w2, b2).map(Some)
    }

    /// The head's tensors under their names in a weights file.
    pub fn tensors(&self) -> Vec<(String, Tensor)> {
        let shapes = [vec![self.inputs, self.hidden], vec![self.hidden], vec![self.hidden, OBJECTS], vec![OBJECTS]];
        let data = [&self.w1, &self.b1, &self.w2, &self.b2];
        TENSORS
            .iter()
            .zip(shapes)
            .zip(data)
            .map(|((t, shape), d)| (format!("{HOME_HEAD_PREFIX}{t}"), Tensor { shape, data: d.clone() }))
            .collect()
    }

    /// Input width.
    pub fn inputs(&self) -> usize {
        self.inputs
    }

    /// Hidden units.
    pub fn hidden(&self) -> usize {
        self.hidden
    }

    /// Object-class scores of one input row.
    ///
    /// # Shapes
    /// `row`: `[inputs]`; result `[OBJECTS]`.
    pub fn scores(&self, row: &[f32]) -> [f32; OBJECTS] {
        let mut h = self.b1.clone();
        for (i, &x) in row.iter().enumerate().take(self.inputs) {
            if x != 0.0 {
                let w = &self.w1[i * self.hidden..(i + 1) * self.hidden];
                for (hj, wj) in h.iter_mut().zip(w) {
                    *hj += x * wj;
                }
            }
        }
        let mut out = [0f32; OBJECTS];
        out.copy_from_slice(&self.b2);
        for (j, &hj) in h.iter().enumerate() {
            if hj > 0.0 {
                let w = &self.w2[j * OBJECTS..(j + 1) * OBJECTS];
                for (o, wo) in out.iter_mut().zip(w) {
                    *o += hj * wo;
                }
            }
        }
        out
    }

    /// The object class of one input row (highest score).
    pub fn object_class(&self, row: &[f32]) -> HomeClass {
        let s = self.scores(row);
        let best = (0..OBJECTS).fold(0, |b, k| if s[k] > s[b] { k } else { b });
        HomeClass::OBJECTS[best]
    }

    /// The home class of every voxel: the shell's from the S3DIS labels, objects from the
    /// head among those [`allowed_objects`] leaves.
    ///
    /// # Shapes
    /// `inputs`: `[v, inputs]` ([`head_inputs`]); `s3dis_labels`: `[v]`; result `[v]`
    /// [`HomeClass`] ids.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] when the lengths do not agree.
    pub fn home_labels(&self, inputs: &[f32], s3dis_labels: &[u8]) -> Result<Vec<u8>> {
        self.home_labels_voted(inputs, s3dis_labels, None)
    }

    /// [`home_labels`](Self::home_labels), the head's object probabilities summed over each
    /// segment of `segment` (the structure step's geometric segments: one label per surface
    /// patch, as the S3DIS labels get) when given.
    ///
    /// # Shapes
    /// As [`home_labels`](Self::home_labels); `segment`: `[v]` segment ids.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] when the lengths do not agree.
    pub fn home_labels_voted(&self, inputs: &[f32], s3dis_labels: &[u8], segment: Option<&[u32]>) -> Result<Vec<u8>> {
        if inputs.len() != s3dis_labels.len() * self.inputs || segment.is_some_and(|s| s.len() != s3dis_labels.len()) {
            return Err(NetError::InvalidInput(format!(
                "{} head inputs and {} segment ids for {} voxels of {} values",
                inputs.len(),
                segment.map_or(0, <[u32]>::len),
                s3dis_labels.len(),
                self.inputs
            )));
        }
        if let Some(segment) = segment {
            return Ok(self.vote(inputs, s3dis_labels, segment));
        }
        Ok(s3dis_labels
            .par_iter()
            .enumerate()
            .map(|(v, &l)| match shell_class(l) {
                Some(c) => c.id(),
                None => {
                    let scores = self.scores(&inputs[v * self.inputs..(v + 1) * self.inputs]);
                    let allowed = allowed_objects(l);
                    let best =
                        allowed.iter().copied().fold(allowed[0], |b, k| if scores[k] > scores[b] { k } else { b });
                    HomeClass::OBJECTS[best].id()
                }
            })
            .collect())
    }
}

/// The home class of every voxel of a forward pass that read the head features
/// ([`crate::Segmenter::segment_points_with_features`]), given the voxels' S3DIS labels
/// (the network's, or after the structure step) and, to vote over, the structure step's
/// segments: the floor found from those labels, then [`HomeHead::home_labels_voted`].
///
/// # Shapes
/// `s3dis_labels`: `[v]` for the `v` voxels of `scores`; result `[v]` [`HomeClass`] ids.
///
/// # Errors
/// [`NetError::InvalidInput`] when the scores hold no head features or the lengths differ.
pub fn label_voxels(
    head: &HomeHead,
    scores: &crate::PointScores,
    s3dis_labels: &[u8],
    segment: Option<&[u32]>,
    classes: usize,
    voxel_size: f32,
) -> Result<Vec<u8>> {
    if s3dis_labels.len() != scores.coords.len() {
        return Err(NetError::InvalidInput(format!(
            "{} labels for {} voxels",
            s3dis_labels.len(),
            scores.coords.len()
        )));
    }
    if scores.head_features.is_empty() && !scores.coords.is_empty() {
        return Err(NetError::InvalidInput("the scores hold no head features".into()));
    }
    let floor = floor_level(&scores.coords, s3dis_labels);
    let inputs = head_inputs(&scores.coords, &scores.head_features, &scores.logits, classes, voxel_size, floor)?;
    head.home_labels_voted(&inputs, s3dis_labels, segment)
}

impl HomeHead {
    /// The segment vote: per segment, the softmax of the head's scores summed over its object
    /// voxels; each object voxel takes its allowed class of highest sum.
    fn vote(&self, inputs: &[f32], s3dis_labels: &[u8], segment: &[u32]) -> Vec<u8> {
        let n = s3dis_labels.len();
        let probs: Vec<[f32; OBJECTS]> = (0..n)
            .into_par_iter()
            .map(|v| {
                if shell_class(s3dis_labels[v]).is_some() {
                    return [0.0; OBJECTS];
                }
                let mut p = self.scores(&inputs[v * self.inputs..(v + 1) * self.inputs]);
                softmax_rows(&mut p, OBJECTS);
                p
            })
            .collect();
        let segments = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
        // Summed in voxel order: the same bits for any thread count.
        let mut sums = vec![[0f32; OBJECTS]; segments];
        for (v, p) in probs.iter().enumerate() {
            for (a, b) in sums[segment[v] as usize].iter_mut().zip(p) {
                *a += b;
            }
        }
        (0..n)
            .map(|v| match shell_class(s3dis_labels[v]) {
                Some(c) => c.id(),
                None => {
                    let sum = &sums[segment[v] as usize];
                    let allowed = allowed_objects(s3dis_labels[v]);
                    let best = allowed.iter().copied().fold(allowed[0], |b, k| if sum[k] > sum[b] { k } else { b });
                    HomeClass::OBJECTS[best].id()
                }
            })
            .collect()
    }
}

/// Indices into [`HomeClass::OBJECTS`] of the classes the head may give a voxel the S3DIS
/// head calls `s3dis` (not a shell class). The S3DIS head's chairs and sofas, classes it
/// shares with the home set, were tuned on real scans and score higher than the home head's
/// on rooms of unseen furniture (chair 96.5 against 83.6 % IoU, sofa 86.8 against 80.3:
/// docs/model.md, "A second label set for homes"): a chair stays a chair, a sofa may only
/// become a bed (real beds were called sofa), and what it calls table, bookcase, board or
/// clutter may become any object but a chair or a sofa.
pub fn allowed_objects(s3dis: u8) -> &'static [usize] {
    const CHAIR: [usize; 1] = [2];
    const SOFA_OR_BED: [usize; 2] = [3, 1];
    const NOT_SEATS: [usize; 14] = [0, 1, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15];
    match SemanticClass::from_id(s3dis) {
        Some(SemanticClass::Chair) => &CHAIR,
        Some(SemanticClass::Sofa) => &SOFA_OR_BED,
        _ => &NOT_SEATS,
    }
}

/// The home class of a voxel whose S3DIS label is a shell class (kept as it is), `None` for
/// furniture and clutter (the head decides) and for unlabelled voxels too.
pub fn shell_class(s3dis: u8) -> Option<HomeClass> {
    match SemanticClass::from_id(s3dis)? {
        c @ (SemanticClass::Ceiling
        | SemanticClass::Floor
        | SemanticClass::Wall
        | SemanticClass::Beam
        | SemanticClass::Column
        | SemanticClass::Window
        | SemanticClass::Door) => HomeClass::from_s3dis(c),
        _ => None,
    }
}

/// The floor's height in voxel units: the median z of the voxels labelled floor, else the
/// lowest voxel (a scan with no floor in view).
///
/// # Shapes
/// `coords`: `[v]`; `s3dis_labels`: `[v]`.
pub fn floor_level(coords: &[Coord], s3dis_labels: &[u8]) -> f32 {
    let mut z: Vec<i32> =
        coords.iter().zip(s3dis_labels).filter(|(_, &l)| l == SemanticClass::Floor.id()).map(|(c, _)| c[2]).collect();
    if z.is_empty() {
        return coords.iter().map(|c| c[2]).min().unwrap_or(0) as f32;
    }
    let mid = z.len() / 2;
    *z.select_nth_unstable(mid).1 as f32
}

/// The home head's input rows: the head features, the softmax of the S3DIS logits and the
/// height above the floor (metres, clamped) of every voxel.
///
/// # Shapes
/// `coords`: `[v]`; `head_features`: `[v, c]`; `logits`: `[v, classes]`; result
/// `[v, c + classes + 1]`.
///
/// # Errors
/// [`NetError::InvalidInput`] when the lengths do not agree.
pub fn head_inputs(
    coords: &[Coord],
    head_features: &[f32],
    logits: &[f32],
    classes: usize,
    voxel_size: f32,
    floor_level: f32,
) -> Result<Vec<f32>> {
    let v = coords.len();
    if v == 0 {
        return Ok(Vec::new());
    }
    if !head_features.len().is_multiple_of(v) || logits.len() != v * classes {
        return Err(NetError::InvalidInput(format!(
            "{} head features and {} logits for {v} voxels of {classes} classes",
            head_features.len(),
            logits.len()
        )));
    }
    let c = head_features.len() / v;
    let width = HomeHead::input_width(c, classes);
    let mut probs = logits.to_vec();
    softmax_rows(&mut probs, classes);
    let mut out = Vec::with_capacity(v * width);
    for (i, coord) in coords.iter().enumerate() {
        out.extend_from_slice(&head_features[i * c..(i + 1) * c]);
        out.extend_from_slice(&probs[i * classes..(i + 1) * classes]);
        let height = ((coord[2] as f32 + 0.5 - floor_level) * voxel_size).clamp(HEIGHT_RANGE.0, HEIGHT_RANGE.1);
        out.push(height);
    }
    Ok(out)
}

/// Ground truth for the head: the [`HomeClass::OBJECTS`] index of a voxel's home label, or
/// `None` for the shell and unscored voxels.
pub fn object_index(home_label: u8) -> Option<usize> {
    if home_label == UNLABELED {
        return None;
    }
    HomeClass::OBJECTS.iter().position(|c| c.id() == home_label)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The plain reference: matrices written out as sums.
    fn reference(head: &HomeHead, row: &[f32]) -> Vec<f32> {
        let h: Vec<f32> = (0..head.hidden)
            .map(|j| {
                (head.b1[j] + (0..head.inputs).map(|i| row[i] * head.w1[i * head.hidden + j]).sum::<f32>()).max(0.0)
            })
            .collect();
        (0..OBJECTS)
            .map(|k| head.b2[k] + (0..head.hidden).map(|j| h[j] * head.w2[j * OBJECTS + k]).sum::<f32>())
            .collect()
    }

    fn random_head(inputs: usize, hidden: usize, seed: u32) -> HomeHead {
        let mut x = seed.wrapping_mul(2_654_435_761).max(1);
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x as f32 / u32::MAX as f32) * 2.0 - 1.0
        };
        let mut v = |n: usize| (0..n).map(|_| next()).collect::<Vec<f32>>();
        HomeHead::new(inputs, hidden, v(inputs * hidden), v(hidden), v(hidden * OBJECTS), v(OBJECTS)).unwrap()
    }

    #[test]
    fn scores_match_the_plain_reference() {
        for seed in 1..5 {
            let head = random_head(7, 5, seed);
            let row: Vec<f32> = (0..7).map(|i| ((i * 37 + seed as usize) % 11) as f32 * 0.2 - 1.0).collect();
            let got = head.scores(&row);
            for (a, b) in got.iter().zip(reference(&head, &row)) {
                assert!((a - b).abs() < 1e-5, "{a} {b}");
            }
        }
    }

    #[test]
    fn the_shell_keeps_the_s3dis_label_and_objects_come_from_the_head() {
        let head = random_head(4, 3, 9);
        let rows = vec![0.5f32; 4 * 3];
        let labels = head
            .home_labels(&rows, &[SemanticClass::Beam.id(), SemanticClass::Clutter.id(), SemanticClass::Ceiling.id()])
            .unwrap();
        assert_eq!(labels[0], HomeClass::Wall.id());
        let seats = head.home_labels(&rows[..8], &[SemanticClass::Chair.id(), SemanticClass::Sofa.id()]).unwrap();
        assert_eq!(seats[0], HomeClass::Chair.id());
        assert!([HomeClass::Sofa.id(), HomeClass::Bed.id()].contains(&seats[1]));
        assert!(HomeClass::from_id(labels[1]).unwrap().is_object());
        assert_eq!(labels[2], HomeClass::Ceiling.id());
        assert!(head.home_labels(&rows, &[0, 1]).is_err());
    }

    #[test]
    fn the_vote_gives_each_segment_one_object_class() {
        let head = random_head(4, 6, 11);
        let rows: Vec<f32> = (0..4 * 6).map(|i| ((i * 7) % 5) as f32 * 0.4 - 0.8).collect();
        let clutter = SemanticClass::Clutter.id();
        let s3dis = [clutter, clutter, clutter, SemanticClass::Wall.id(), clutter, clutter];
        let segment = [0, 0, 0, 0, 1, 1];
        let voted = head.home_labels_voted(&rows, &s3dis, Some(&segment)).unwrap();
        assert_eq!(voted[0], voted[1]);
        assert_eq!(voted[1], voted[2]);
        assert_eq!(voted[3], HomeClass::Wall.id());
        assert_eq!(voted[4], voted[5]);
        // One voxel per segment: the vote is the head's own choice.
        let alone = head.home_labels_voted(&rows, &s3dis, Some(&[0, 1, 2, 3, 4, 5])).unwrap();
        assert_eq!(alone, head.home_labels(&rows, &s3dis).unwrap());
        assert!(head.home_labels_voted(&rows, &s3dis, Some(&[0, 1])).is_err());
    }

    #[test]
    fn allowed_objects_name_the_right_classes() {
        let names = |l: SemanticClass| -> Vec<HomeClass> {
            allowed_objects(l.id()).iter().map(|&k| HomeClass::OBJECTS[k]).collect()
        };
        assert_eq!(names(SemanticClass::Chair), [HomeClass::Chair]);
        assert_eq!(names(SemanticClass::Sofa), [HomeClass::Sofa, HomeClass::Bed]);
        let others = names(SemanticClass::Clutter);
        assert_eq!(others.len(), OBJECTS - 2);
        assert!(!others.contains(&HomeClass::Chair) && !others.contains(&HomeClass::Sofa));
    }

    #[test]
    fn tensors_round_trip_through_weights() {
        let head = random_head(6, 4, 3);
        let weights = Weights::from_tensors(head.tensors().into_iter().collect());
        assert_eq!(HomeHead::from_weights(&weights).unwrap(), Some(head));
        assert_eq!(HomeHead::from_weights(&Weights::from_tensors(Default::default())).unwrap(), None);
        let mut partial: std::collections::BTreeMap<String, Tensor> =
            random_head(6, 4, 3).tensors().into_iter().collect();
        partial.remove("home_head.out.bias");
        assert!(HomeHead::from_weights(&Weights::from_tensors(partial)).is_err());
    }

    #[test]
    fn inputs_hold_features_probabilities_and_height() {
        let coords: [Coord; 2] = [[0, 0, 0, 0], [0, 0, 20, 0]];
        let labels = [SemanticClass::Floor.id(), SemanticClass::Clutter.id()];
        let floor = floor_level(&coords, &labels);
        assert_eq!(floor, 0.0);
        let rows = head_inputs(&coords, &[1.0, 2.0, 3.0, 4.0], &[0.0, 0.0, 1.0, 1.0], 2, 0.05, floor).unwrap();
        assert_eq!(rows.len(), 2 * 5);
        assert_eq!(&rows[..4], &[1.0, 2.0, 0.5, 0.5]);
        assert!((rows[4] - 0.025).abs() < 1e-6 && (rows[9] - 1.025).abs() < 1e-6);
        assert_eq!(object_index(HomeClass::Bed.id()), Some(1));
        assert_eq!(object_index(HomeClass::Wall.id()), None);
        assert_eq!(object_index(UNLABELED), None);
    }
}
