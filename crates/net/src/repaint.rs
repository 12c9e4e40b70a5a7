//! Repainting whole classes: an augmentation that keeps the colour from naming the class.
//!
//! In generated rooms colour carries much of the class: doors, tables and bookcases come in
//! wood, walls in paint. Real rooms break that often: wood-panelled or brick walls (the real
//! ScanNet homes' wood-panelled walls were called door and sofa), white doors, white or black
//! furniture. [`repaint_classes`] gives, in a fraction of the samples, every point of a class
//! the tone of another material while keeping each point's brightness relative to the class's
//! mean, so the shading, texture and seams of the surface survive and only the material
//! changes. The labels are untouched: the network must then find the class in the shape.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use semrecon_data::{LabeledPointCloud, SemanticClass};

/// The classes that get repainted: the large planes and the furniture whose colours differ
/// most between generated and real rooms.
pub const REPAINTED_CLASSES: [SemanticClass; 6] = [
    SemanticClass::Wall,
    SemanticClass::Door,
    SemanticClass::Table,
    SemanticClass::Bookcase,
    SemanticClass::Chair,
    SemanticClass::Sofa,
];

/// Materials a class may be repainted in (sRGB, 0..1): whites and greys, black, woods from
/// oak to walnut, brick, and a few paints and fabrics.
const TONES: [[f32; 3]; 16] = [
    [0.93, 0.93, 0.91],
    [0.86, 0.84, 0.80],
    [0.70, 0.70, 0.70],
    [0.45, 0.45, 0.47],
    [0.15, 0.15, 0.16],
    [0.78, 0.62, 0.44],
    [0.62, 0.45, 0.28],
    [0.45, 0.30, 0.19],
    [0.32, 0.21, 0.14],
    [0.62, 0.32, 0.24],
    [0.55, 0.62, 0.70],
    [0.35, 0.45, 0.60],
    [0.60, 0.70, 0.55],
    [0.80, 0.72, 0.50],
    [0.55, 0.25, 0.25],
    [0.85, 0.78, 0.80],
];

/// Repaints each class of [`REPAINTED_CLASSES`] present in `cloud`, independently with
/// probability `probability`, in one of the tones above (a little jittered): a point's new
/// colour is the tone times its luminance over the class's mean luminance.
pub fn repaint_classes(cloud: &mut LabeledPointCloud, probability: f32, rng: &mut ChaCha8Rng) {
    for class in REPAINTED_CLASSES {
        // Always drawn, so that each class's choice does not depend on the others'.
        let draw: f32 = rng.random();
        let tone = TONES[rng.random_range(0..TONES.len())];
        let jitter: [f32; 3] = std::array::from_fn(|_| 1.0 + 0.1 * (rng.random::<f32>() - 0.5));
        if draw >= probability {
            continue;
        }
        let id = class.id();
        let (mut sum, mut count) = (0.0f64, 0usize);
        for (c, &l) in cloud.colors.iter().zip(&cloud.labels) {
            if l == id {
                sum += f64::from(luminance(*c));
                count += 1;
            }
        }
        if count == 0 || sum <= 0.0 {
            continue;
        }
        let mean = (sum / count as f64) as f32;
        for (c, &l) in cloud.colors.iter_mut().zip(&cloud.labels) {
            if l == id {
                let relative = (luminance(*c) / mean).min(2.0);
                for k in 0..3 {
                    c[k] = (tone[k] * jitter[k] * relative * 255.0).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
}

/// Rec. 601 luma of an sRGB colour, 0..255.
fn luminance(c: [u8; 3]) -> f32 {
    0.299 * f32::from(c[0]) + 0.587 * f32::from(c[1]) + 0.114 * f32::from(c[2])
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use rand::SeedableRng;

    use super::*;

    fn cloud() -> LabeledPointCloud {
        let n = 40;
        LabeledPointCloud {
            positions: (0..n).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect(),
            colors: (0..n).map(|i| [100 + i as u8, 120, 140 - i as u8]).collect(),
            labels: (0..n)
                .map(|i| if i % 2 == 0 { SemanticClass::Wall.id() } else { SemanticClass::Floor.id() })
                .collect(),
        }
    }

    #[test]
    fn repainting_keeps_labels_relative_brightness_and_other_classes() {
        let before = cloud();
        let mut after = before.clone();
        repaint_classes(&mut after, 1.0, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(before.labels, after.labels);
        assert_eq!(before.positions, after.positions);
        let wall = SemanticClass::Wall.id();
        let mut changed = 0;
        for ((b, a), &l) in before.colors.iter().zip(&after.colors).zip(&before.labels) {
            if l == wall {
                changed += usize::from(b != a);
            } else {
                assert_eq!(b, a, "a floor point changed");
            }
        }
        assert!(changed > 0);
        // Brighter before, brighter after (up to rounding).
        let walls: Vec<(f32, f32)> = before
            .colors
            .iter()
            .zip(&after.colors)
            .zip(&before.labels)
            .filter(|(_, &l)| l == wall)
            .map(|((b, a), _)| (luminance(*b), luminance(*a)))
            .collect();
        for w in walls.windows(2) {
            if w[1].0 > w[0].0 + 2.0 {
                assert!(w[1].1 >= w[0].1 - 1.0, "{w:?}");
            }
        }
    }

    #[test]
    fn probability_zero_changes_nothing() {
        let before = cloud();
        let mut after = before.clone();
        repaint_classes(&mut after, 0.0, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(before.colors, after.colors);
    }
}
