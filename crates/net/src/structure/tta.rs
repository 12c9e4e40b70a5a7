//! Test-time augmentation: the network run on the room turned by multiples of 90 degrees about
//! z and mirrored, and the class probabilities averaged. The eight symmetries of the square
//! grid map voxels onto voxels and coarser cells onto cells, so nothing is resampled; z stays
//! up, as it is in every room. Each symmetry costs a network call, which is why it is opt-in.

use semrecon_sparse::Coord;

use super::softmax_rows;
use crate::error::{NetError, Result};
use crate::inference::Segmenter;

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
