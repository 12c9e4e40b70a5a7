//! Which directions of translation the surfaces in view hold, counted from the model's
//! normals rather than read from the normal matrix's eigenvalues.
//!
//! A point-to-plane residual sees a translation `t` only through `n · t`: a view of vertical
//! walls and a flush door holds nothing along the vertical. The normal matrix `Σ n nᵀ` says
//! so for perfect normals, but a ray-cast model's normals carry noise (a few degrees), and
//! that noise lends every axis an eigenvalue of about `σ²` of the largest: a condition of
//! 1e-2, as healthy as a view of a room's corner, and a translation sigma of 0.2 mm, while
//! the alignment slides 0.35 m up the wall in 25 frames (`synth-loop:3:noisy`, frames
//! 1135-1210, docs/benchmarks_log.md, "Session 42"). Counting instead the surface points
//! whose normal leans towards a direction by a real angle (`min_tilt`, well past the
//! noise) tells a noisy wall from a wall with a shelf, a floor strip or a door lintel in
//! view.

use glam::Vec3;

use crate::linalg::symmetric_eigen;

/// The directions of translation that a view's surfaces leave unheld, in the view's camera
/// frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TranslationSupport {
    /// Unit directions along which too few surface points lean (at most three; the first
    /// `unheld_count` are meaningful).
    pub unheld: [Vec3; 3],
    /// How many of `unheld` are set.
    pub unheld_count: usize,
    /// The smallest fraction of surface points leaning towards any of the three principal
    /// directions of the normals (1 for a view without surface): the diagnostic
    /// `tracking.csv` reports.
    pub weakest_fraction: f32,
}

impl TranslationSupport {
    /// The unheld directions.
    pub(crate) fn unheld(&self) -> &[Vec3] {
        &self.unheld[..self.unheld_count]
    }
}

/// Side of the square blocks of model pixels whose normals are averaged before they are
/// counted: a ray-cast model's normals scatter by about 12 degrees per axis at 2 m (15 % of a
/// bare wall's pixels lean 17 degrees towards a direction along it: `synth-loop:1:noisy`
/// frame 1380), and averaging 16 of them cuts that about four times, while a real second
/// surface keeps its lean over a block.
pub(crate) const SUPPORT_BLOCK: usize = 4;

/// The translation support of the surface `normals` of a `width`-pixel-wide view (zero
/// vectors are pixels without a surface), from the normals averaged over blocks of
/// [`SUPPORT_BLOCK`] x [`SUPPORT_BLOCK`] pixels and weighted by the surface pixels in each:
/// along each principal direction `e` of their `Σ n nᵀ`, the fraction of surface pixels
/// whose block's normal has `|n · e| >= min_tilt`; a direction whose fraction is below
/// `min_fraction` is unheld. The principal directions are where a hold is weakest: a
/// direction between two of them has at least the smaller one's support from the normals
/// leaning both ways.
pub(crate) fn translation_support(
    normals: &[Vec3],
    width: usize,
    min_tilt: f32,
    min_fraction: f32,
) -> TranslationSupport {
    let blocks = block_normals(normals, width);
    let mut scatter = [[0.0f64; 3]; 3];
    let mut count = 0usize;
    for (n, pixels) in &blocks {
        let v = n.to_array().map(f64::from);
        for i in 0..3 {
            for j in 0..3 {
                scatter[i][j] += *pixels as f64 * v[i] * v[j];
            }
        }
        count += pixels;
    }
    let mut support = TranslationSupport { unheld: [Vec3::ZERO; 3], unheld_count: 0, weakest_fraction: 1.0 };
    if count == 0 {
        return support;
    }
    let (_, directions) = symmetric_eigen(&scatter);
    for e in directions {
        let e = Vec3::new(e[0] as f32, e[1] as f32, e[2] as f32).normalize_or_zero();
        let leaning: usize = blocks.iter().filter(|(n, _)| n.dot(e).abs() >= min_tilt).map(|(_, pixels)| pixels).sum();
        let fraction = leaning as f32 / count as f32;
        support.weakest_fraction = support.weakest_fraction.min(fraction);
        if fraction < min_fraction && e != Vec3::ZERO {
            support.unheld[support.unheld_count] = e;
            support.unheld_count += 1;
        }
    }
    support
}

/// The mean unit normal of each block of [`SUPPORT_BLOCK`] x [`SUPPORT_BLOCK`] pixels that has
/// a surface (blocks at the right and bottom edges may be smaller), with its count of surface
/// pixels.
fn block_normals(normals: &[Vec3], width: usize) -> Vec<(Vec3, usize)> {
    if width == 0 {
        return Vec::new();
    }
    let height = normals.len() / width;
    let mut blocks = Vec::with_capacity(normals.len() / (SUPPORT_BLOCK * SUPPORT_BLOCK) + 1);
    for y0 in (0..height).step_by(SUPPORT_BLOCK) {
        for x0 in (0..width).step_by(SUPPORT_BLOCK) {
            let (mut sum, mut pixels) = (Vec3::ZERO, 0usize);
            for y in y0..(y0 + SUPPORT_BLOCK).min(height) {
                for n in &normals[y * width + x0..y * width + (x0 + SUPPORT_BLOCK).min(width)] {
                    if *n != Vec3::ZERO {
                        sum += *n;
                        pixels += 1;
                    }
                }
            }
            let mean = sum.normalize_or_zero();
            if pixels > 0 && mean != Vec3::ZERO {
                blocks.push((mean, pixels));
            }
        }
    }
    blocks
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// `count` unit normals around `mean`, each turned by noise of about `spread` radians.
    fn noisy(mean: Vec3, count: usize, spread: f32, rng: &mut impl Rng) -> Vec<Vec3> {
        (0..count)
            .map(|_| {
                let jitter =
                    Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                (mean + spread * jitter).normalize()
            })
            .collect()
    }

    #[test]
    fn walls_leave_the_vertical_unheld_and_a_floor_strip_holds_it() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // A corner of two walls and a door (the camera's y is vertical): normals 5 degrees
        // noisy, and pixels without a surface; rows of 100 pixels.
        let mut normals = noisy(Vec3::new(-0.6, 0.0, -0.8), 6000, 0.09, &mut rng);
        normals.extend(noisy(Vec3::new(0.8, 0.0, -0.6), 3000, 0.09, &mut rng));
        normals.extend(std::iter::repeat_n(Vec3::ZERO, 2000));
        let walls = translation_support(&normals, 100, 0.3, 0.02);
        assert_eq!(walls.unheld_count, 1, "{walls:?}");
        assert!(walls.unheld()[0].y.abs() > 0.99, "{walls:?}");
        assert!(walls.weakest_fraction < 0.002, "{walls:?}");
        // The normal matrix's own conditioning calls the same view healthy: noise lends the
        // vertical an eigenvalue of about a hundredth of the largest.
        let mut scatter = [[0.0f64; 3]; 3];
        for n in &normals {
            for i in 0..3 {
                for j in 0..3 {
                    scatter[i][j] += f64::from(n[i] * n[j]);
                }
            }
        }
        let (values, _) = symmetric_eigen(&scatter);
        assert!(values[0] / values[2] > 1e-3, "{values:?}");
        // A strip of floor, 5 % of the view, holds it.
        normals.extend(noisy(Vec3::new(0.0, -1.0, 0.0), 500, 0.09, &mut rng));
        let with_floor = translation_support(&normals, 100, 0.3, 0.02);
        assert_eq!(with_floor.unheld_count, 0, "{with_floor:?}");
        assert!(with_floor.weakest_fraction > 0.04, "{with_floor:?}");
    }

    #[test]
    fn a_bare_wall_leaves_both_slides_unheld_and_no_surface_leaves_none() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Normals as noisy as a ray-cast wall's at 2 m (about 12 degrees per axis): 15-20 %
        // of the pixels lean 17 degrees along the wall one way or another, their blocks'
        // means hardly any.
        let wall = noisy(Vec3::new(0.0, 0.0, -1.0), 4000, 0.35, &mut rng);
        let leaning = wall.iter().filter(|n| n.x.abs() >= 0.3).count() as f32 / wall.len() as f32;
        assert!(leaning > 0.1, "{leaning}");
        let support = translation_support(&wall, 100, 0.3, 0.02);
        assert_eq!(support.unheld_count, 2, "{support:?}");
        for e in support.unheld() {
            assert!(e.z.abs() < 0.05 && (e.length() - 1.0).abs() < 1e-5, "{support:?}");
        }
        let empty = translation_support(&[Vec3::ZERO; 10], 5, 0.3, 0.02);
        assert_eq!((empty.unheld_count, empty.weakest_fraction), (0, 1.0));
        // A fraction of 0 turns the check off.
        assert_eq!(translation_support(&wall, 100, 0.3, 0.0).unheld_count, 0);
    }
}
