//! Test-time augmentation (TTA): the network run on several copies of a room turned about the
//! vertical axis (and mirrored), with the class scores of every voxel averaged over the copies
//! and the label taken from the average. A network trained with yaw augmentation still labels
//! a room a little differently in each orientation; on real scans, whose errors are not those
//! of the training rooms, averaging the views is a cheap ensemble. Gravity is kept: z stays
//! up in every view, as it is in every room the network saw.
//!
//! The views are the symmetries of the square voxel grid about z ([`GridSymmetry`]): yaws by
//! multiples of 90 degrees, optionally after a mirror in x. They map points onto points
//! exactly in floating point (negations and swaps), and voxels onto voxels: a point turned
//! and re-voxelised lands in the turned voxel, with the same points and so the same mean
//! colour, so turning the voxel coordinates *is* re-voxelising the turned points (the tests
//! check this), without keeping the points. [`Tta`] picks 1 (off, the default), 2 (half
//! turn), 4 (the four yaws) or 8 (the four yaws x the mirror) views: each set is a group, so
//! the average is the same whichever of its views the room arrives in.
//!
//! Each view costs a network call. The views are summed in a fixed order (view 0, 1, ...),
//! each network call is deterministic, so the result has the same bits for any number of
//! rayon threads; one view is exactly the network's softmax, as without TTA.
//! docs/model.md ("Test-time augmentation (session 16)") measures what it buys.

use std::fmt;
use std::str::FromStr;

use semrecon_sparse::Coord;

use crate::error::{NetError, Result};
use crate::inference::Segmenter;
use crate::structure::softmax_rows;

/// A symmetry of the square voxel grid about the z axis: an optional mirror in x (`x -> -x`)
/// followed by `quarter_turns` counter-clockwise turns by 90 degrees about z. On voxel
/// indices negation is `-x - 1` (`!x`): voxel `i` covers `[i, i + 1)` voxel sizes, whose
/// negation is covered by voxel `-i - 1`. That also maps every coarser level's cells onto
/// cells, so the network's downsampling sees the same groups of voxels in every view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GridSymmetry {
    /// Turns by 90 degrees counter-clockwise about +z (0..=3; taken modulo 4).
    pub quarter_turns: u8,
    /// Mirror in x before turning.
    pub mirror_x: bool,
}

impl GridSymmetry {
    /// The identity.
    pub const IDENTITY: Self = Self { quarter_turns: 0, mirror_x: false };

    /// The `t`-th view of [`Tta`] (`t` modulo 8): yaws 0, 180, 90, 270 degrees, then the
    /// same after a mirror in x. The first 1, 2, 4 and 8 views are groups.
    pub const fn view(t: usize) -> Self {
        const YAWS: [u8; 4] = [0, 2, 1, 3];
        Self { quarter_turns: YAWS[t % 4], mirror_x: (t / 4) % 2 == 1 }
    }

    /// The voxel that the points of voxel `c` fall in after the symmetry (batch and z kept).
    pub fn apply(self, c: Coord) -> Coord {
        let [x, y, z, b] = c;
        let x = if self.mirror_x { !x } else { x };
        let (x, y) = match self.quarter_turns % 4 {
            0 => (x, y),
            1 => (!y, x),
            2 => (!x, !y),
            _ => (y, !x),
        };
        [x, y, z, b]
    }

    /// The point `p` (metres) after the symmetry, exact in floating point.
    pub fn apply_point(self, p: [f32; 3]) -> [f32; 3] {
        let [x, y, z] = p;
        let x = if self.mirror_x { -x } else { x };
        let (x, y) = match self.quarter_turns % 4 {
            0 => (x, y),
            1 => (-y, x),
            2 => (-x, -y),
            _ => (y, -x),
        };
        [x, y, z]
    }
}

/// How the views' class scores are averaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TtaMean {
    /// The mean of the views' softmax probabilities (the default).
    #[default]
    Probabilities,
    /// The softmax of the mean of the views' logits.
    Logits,
}

impl TtaMean {
    /// Every kind, in the order of their names.
    pub const ALL: [Self; 2] = [Self::Probabilities, Self::Logits];

    /// `probabilities` or `logits`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Probabilities => "probabilities",
            Self::Logits => "logits",
        }
    }
}

impl fmt::Display for TtaMean {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for TtaMean {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| format!("`{s}`: expected probabilities or logits"))
    }
}

/// A test-time augmentation setting: how many views ([`GridSymmetry::view`]) and how their
/// scores are averaged. The default is off (one view).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tta {
    views: usize,
    mean: TtaMean,
}

impl Default for Tta {
    fn default() -> Self {
        Self::OFF
    }
}

impl Tta {
    /// The numbers of views allowed: 1 (off), 2 (half turn), 4 (the four yaws), 8 (the four
    /// yaws x a mirror in x).
    pub const VIEWS: [usize; 4] = [1, 2, 4, 8];

    /// One view: the network alone.
    pub const OFF: Self = Self { views: 1, mean: TtaMean::Probabilities };

    /// `views` views (one of [`Tta::VIEWS`]), probabilities averaged.
    ///
    /// # Errors
    /// [`NetError::TtaViews`] for any other number.
    pub fn new(views: usize) -> Result<Self> {
        if Self::VIEWS.contains(&views) {
            Ok(Self { views, mean: TtaMean::Probabilities })
        } else {
            Err(NetError::TtaViews(views))
        }
    }

    /// The same views, averaged as `mean` says.
    pub fn with_mean(self, mean: TtaMean) -> Self {
        Self { mean, ..self }
    }

    /// Number of views (network calls).
    pub fn views(&self) -> usize {
        self.views
    }

    /// How the views are averaged.
    pub fn mean(&self) -> TtaMean {
        self.mean
    }

    /// Whether more than one view runs.
    pub fn is_on(&self) -> bool {
        self.views > 1
    }

    /// The views, in the order they are summed.
    pub fn symmetries(&self) -> impl Iterator<Item = GridSymmetry> {
        (0..self.views).map(GridSymmetry::view)
    }

    /// Class probabilities of every voxel, averaged over the views; with one view, the
    /// softmax of the network's logits, bit for bit. `identity_logits`, the network's scores
    /// of the unmoved voxels when the caller has them already, saves the first network call.
    /// The views are summed in their order, so the result is the same for any number of
    /// threads.
    ///
    /// # Shapes
    /// `coords`: `[v]` distinct voxels (any order); `features`: `[v, in_channels]`;
    /// `identity_logits`: `[v, classes]`; result `[v, classes]` in the order of `coords`.
    ///
    /// # Errors
    /// Those of [`Segmenter::segment`]; [`NetError::InvalidInput`] for identity logits of
    /// another length.
    pub fn probabilities(
        &self,
        net: &mut Segmenter,
        coords: &[Coord],
        features: &[f32],
        identity_logits: Option<Vec<f32>>,
    ) -> Result<Vec<f32>> {
        let k = net.config().classes;
        if identity_logits.as_ref().is_some_and(|l| l.len() != coords.len() * k) {
            return Err(NetError::InvalidInput(format!("identity logits do not match {} voxels", coords.len())));
        }
        let mut first = identity_logits;
        let mut sum: Vec<f32> = Vec::new();
        for symmetry in self.symmetries() {
            let mut scores = match first.take() {
                Some(l) => l,
                None if symmetry == GridSymmetry::IDENTITY => net.segment(coords, features)?,
                None => {
                    let moved: Vec<Coord> = coords.iter().map(|&c| symmetry.apply(c)).collect();
                    net.segment(&moved, features)?
                }
            };
            if self.views == 1 {
                softmax_rows(&mut scores, k);
                return Ok(scores);
            }
            if self.mean == TtaMean::Probabilities {
                softmax_rows(&mut scores, k);
            }
            if sum.is_empty() {
                sum = scores;
            } else {
                sum.iter_mut().zip(&scores).for_each(|(s, v)| *s += v);
            }
        }
        let inv = 1.0 / self.views as f32;
        sum.iter_mut().for_each(|s| *s *= inv);
        if self.mean == TtaMean::Logits {
            softmax_rows(&mut sum, k);
        }
        Ok(sum)
    }

    /// The class of every voxel: the argmax of [`probabilities`](Self::probabilities) (the
    /// first class on ties).
    ///
    /// # Shapes
    /// As [`probabilities`](Self::probabilities); result `[v]`.
    ///
    /// # Errors
    /// As [`probabilities`](Self::probabilities).
    pub fn labels(&self, net: &mut Segmenter, coords: &[Coord], features: &[f32]) -> Result<Vec<u8>> {
        let k = net.config().classes;
        Ok(crate::inference::argmax_rows(&self.probabilities(net, coords, features, None)?, k))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::inference::color_features;
    use crate::{NetConfig, Weights};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use semrecon_sparse::voxelize;
    use std::collections::{HashMap, HashSet};

    fn tiny_net(seed: u64) -> Segmenter {
        let config = NetConfig::new("tiny", 3, 4, 0.05);
        Segmenter::new(Weights::random(&config, seed), config).unwrap()
    }

    /// A small irregular room of voxels with random colour features.
    fn room(seed: u64) -> (Vec<Coord>, Vec<f32>) {
        let coords: Vec<Coord> = (0..60).map(|i| [i % 7 - 3, (i / 7) % 5 + 2, i / 35, 0]).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let features = (0..coords.len() * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        (coords, features)
    }

    #[test]
    fn only_one_two_four_and_eight_views() {
        for n in [0, 3, 5, 6, 7, 9, 16] {
            let e = Tta::new(n).unwrap_err();
            assert!(matches!(e, NetError::TtaViews(v) if v == n));
            assert!(e.to_string().contains("1, 2, 4 or 8"), "{e}");
        }
        for n in Tta::VIEWS {
            assert_eq!(Tta::new(n).unwrap().views(), n);
        }
        assert_eq!(Tta::default(), Tta::OFF);
        assert!(!Tta::OFF.is_on());
        assert_eq!("Logits".parse::<TtaMean>(), Ok(TtaMean::Logits));
        assert!("median".parse::<TtaMean>().is_err());
    }

    #[test]
    fn one_view_is_the_network_softmax_bit_for_bit() {
        let mut net = tiny_net(3);
        let (coords, features) = room(1);
        let k = net.config().classes;
        let logits = net.segment(&coords, &features).unwrap();
        let mut want = logits.clone();
        softmax_rows(&mut want, k);
        for tta in [Tta::OFF, Tta::OFF.with_mean(TtaMean::Logits)] {
            assert_eq!(tta.probabilities(&mut net, &coords, &features, None).unwrap(), want);
            assert_eq!(tta.probabilities(&mut net, &coords, &features, Some(logits.clone())).unwrap(), want);
        }
        // Labels: those of the network's own logits.
        assert_eq!(Tta::OFF.labels(&mut net, &coords, &features).unwrap(), crate::inference::argmax_rows(&logits, k));
        assert!(Tta::OFF.probabilities(&mut net, &coords, &features, Some(vec![0.0; 3])).is_err());
    }

    #[test]
    fn views_are_summed_in_order_whatever_the_threads() {
        let (coords, features) = room(2);
        let mut net = tiny_net(5);
        let k = net.config().classes;
        for mean in TtaMean::ALL {
            let tta = Tta::new(8).unwrap().with_mean(mean);
            // By hand: view 0 + view 1 + ... in order, then / 8.
            let mut sum = vec![0f32; coords.len() * k];
            for t in 0..8 {
                let moved: Vec<Coord> = coords.iter().map(|&c| GridSymmetry::view(t).apply(c)).collect();
                let mut s = net.segment(&moved, &features).unwrap();
                if mean == TtaMean::Probabilities {
                    softmax_rows(&mut s, k);
                }
                sum.iter_mut().zip(&s).for_each(|(a, b)| *a += b);
            }
            sum.iter_mut().for_each(|a| *a *= 1.0 / 8.0);
            if mean == TtaMean::Logits {
                softmax_rows(&mut sum, k);
            }
            let runs: Vec<Vec<f32>> = [1, 3]
                .into_iter()
                .map(|threads| {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                    let mut net = tiny_net(5);
                    pool.install(|| tta.probabilities(&mut net, &coords, &features, None)).unwrap()
                })
                .collect();
            assert_eq!(runs[0], sum, "{mean}");
            assert_eq!(runs[1], sum, "{mean}");
            assert!(sum.chunks_exact(k).all(|r| (r.iter().sum::<f32>() - 1.0).abs() < 1e-4));
        }
    }

    #[test]
    fn symmetries_are_exact() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let points: Vec<[f32; 3]> = (0..500).map(|_| [0; 3].map(|_| rng.random_range(-3.0f32..3.0))).collect();
        let coords: Vec<Coord> = (-20..20).flat_map(|x| (-20..20).map(move |y| [x, y, 3, 0])).collect();
        let quarter = GridSymmetry { quarter_turns: 1, mirror_x: false };
        let mirror = GridSymmetry { quarter_turns: 0, mirror_x: true };
        for (&p, &c) in points.iter().zip(&coords) {
            // Four quarter turns, and two mirrors, give back the input.
            let (mut q, mut d) = (p, c);
            for _ in 0..4 {
                q = quarter.apply_point(q);
                d = quarter.apply(d);
            }
            assert_eq!((q, d), (p, c));
            assert_eq!(mirror.apply_point(mirror.apply_point(p)), p);
            assert_eq!(mirror.apply(mirror.apply(c)), c);
            // A quarter turn is counter-clockwise: +x goes to +y.
            assert_eq!(quarter.apply_point([1.0, 0.0, 2.0]), [0.0, 1.0, 2.0]);
        }
        // The eight views are distinct bijections that keep the coarse cells together.
        let images: HashSet<Vec<Coord>> =
            (0..8).map(|t| coords.iter().map(|&c| GridSymmetry::view(t).apply(c)).collect()).collect();
        assert_eq!(images.len(), 8);
        for t in 0..8 {
            let s = GridSymmetry::view(t);
            let moved: HashSet<Coord> = coords.iter().map(|&c| s.apply(c)).collect();
            assert_eq!(moved.len(), coords.len());
            for c in &coords {
                let d = [c[0] ^ 1, c[1] ^ 3, c[2], c[3]];
                let (mc, md) = (s.apply(*c), s.apply(d));
                assert_eq!([mc[0] >> 4, mc[1] >> 4], [md[0] >> 4, md[1] >> 4]);
            }
        }
        // 1, 2, 4 and 8 views are groups: closed under composition.
        for n in Tta::VIEWS {
            let views: HashSet<Vec<Coord>> =
                (0..n).map(|t| coords.iter().map(|&c| GridSymmetry::view(t).apply(c)).collect()).collect();
            for a in 0..n {
                for b in 0..n {
                    let ab: Vec<Coord> =
                        coords.iter().map(|&c| GridSymmetry::view(a).apply(GridSymmetry::view(b).apply(c))).collect();
                    assert!(views.contains(&ab), "{n} views: {a} after {b}");
                }
            }
        }
    }

    /// Turning the points and voxelising them again gives the turned voxels, with the same
    /// mean colours and the same voxel for every point.
    #[test]
    fn turned_voxels_are_the_turned_points_voxelised() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let voxel = 0.05f32;
        // Points inside voxels (not on their faces, where floor(-x) != -floor(x) - 1).
        let points: Vec<[f32; 3]> = (0..3000)
            .map(|_| [0; 3].map(|_| (rng.random_range(-40i32..40) as f32 + rng.random_range(0.05f32..0.95)) * voxel))
            .collect();
        let colors: Vec<[u8; 3]> = (0..points.len()).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
        let feats = color_features(&colors);
        let base = voxelize(&points, &feats, 3, voxel, 0).unwrap();
        let by_coord = |v: &semrecon_sparse::Voxelization| -> HashMap<Coord, Vec<u32>> {
            v.tensor
                .coords()
                .iter()
                .enumerate()
                .map(|(i, &c)| (c, v.tensor.features()[i * 3..i * 3 + 3].iter().map(|f| f.to_bits()).collect()))
                .collect()
        };
        let base_map = by_coord(&base);
        for t in 0..8 {
            let s = GridSymmetry::view(t);
            let moved: Vec<[f32; 3]> = points.iter().map(|&p| s.apply_point(p)).collect();
            let v = voxelize(&moved, &feats, 3, voxel, 0).unwrap();
            let want: HashMap<Coord, Vec<u32>> = base_map.iter().map(|(&c, f)| (s.apply(c), f.clone())).collect();
            assert_eq!(by_coord(&v), want, "view {t}");
            for (i, (&a, &b)) in base.point_to_voxel.iter().zip(&v.point_to_voxel).enumerate() {
                let (ca, cb) = (base.tensor.coords()[a as usize], v.tensor.coords()[b as usize]);
                assert_eq!(s.apply(ca), cb, "view {t}, point {i}");
            }
        }
    }

    /// A room with the symmetries of the square (colours included) is the same input in
    /// every view: each view's scores are the unmoved room's, read at the turned voxels, and
    /// the averaged labels are the same on every voxel and its turned images.
    #[test]
    fn a_symmetric_room_gets_the_same_labels_in_every_view() {
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let mut colour: HashMap<Coord, [f32; 3]> = HashMap::new();
        for x in -6..6 {
            for y in -6..6 {
                for z in 0..3 {
                    let c = [x, y, z, 0];
                    if colour.contains_key(&c) || rng.random_range(0.0..1.0) < 0.4 {
                        continue;
                    }
                    let f = [0; 3].map(|_| rng.random_range(-1.0f32..1.0));
                    for t in 0..8 {
                        colour.insert(GridSymmetry::view(t).apply(c), f);
                    }
                }
            }
        }
        let mut coords: Vec<Coord> = colour.keys().copied().collect();
        coords.sort_unstable();
        let row: HashMap<Coord, usize> = coords.iter().enumerate().map(|(i, &c)| (c, i)).collect();
        let features: Vec<f32> = coords.iter().flat_map(|c| colour[c]).collect();
        let mut net = tiny_net(17);
        let k = net.config().classes;
        let base = net.segment(&coords, &features).unwrap();
        for t in 0..8 {
            let s = GridSymmetry::view(t);
            let moved: Vec<Coord> = coords.iter().map(|&c| s.apply(c)).collect();
            let got = net.segment(&moved, &features).unwrap();
            for (i, c) in moved.iter().enumerate() {
                let j = row[c];
                assert_eq!(got[i * k..(i + 1) * k], base[j * k..(j + 1) * k], "view {t}");
            }
        }
        for n in Tta::VIEWS {
            let labels = Tta::new(n).unwrap().labels(&mut net, &coords, &features).unwrap();
            for t in 0..n {
                let s = GridSymmetry::view(t);
                for (i, &c) in coords.iter().enumerate() {
                    assert_eq!(labels[row[&s.apply(c)]], labels[i], "{n} views, view {t}");
                }
            }
        }
    }

    /// Averaged over a group of views, the scores of a room turned by one of its views are
    /// the room's scores at the turned voxels (within rounding: the views are summed in
    /// another order).
    #[test]
    fn averaged_scores_turn_with_the_room() {
        let (coords, features) = room(19);
        let mut net = tiny_net(23);
        for n in [2, 4, 8] {
            let tta = Tta::new(n).unwrap();
            let base = tta.probabilities(&mut net, &coords, &features, None).unwrap();
            for g in 1..n {
                let moved: Vec<Coord> = coords.iter().map(|&c| GridSymmetry::view(g).apply(c)).collect();
                let got = tta.probabilities(&mut net, &moved, &features, None).unwrap();
                assert!(got.iter().zip(&base).all(|(a, b)| (a - b).abs() < 1e-5), "{n} views, turned by {g}");
            }
        }
        // One view is not invariant: the network itself is not.
        let moved: Vec<Coord> = coords.iter().map(|&c| GridSymmetry::view(2).apply(c)).collect();
        assert_ne!(net.segment(&moved, &features).unwrap(), net.segment(&coords, &features).unwrap());
    }
}
