//! Colours of a synthetic room. A room draws its own scheme (wall paint, floor covering,
//! ceiling, wood tone of its furniture, fabrics) and every object varies around it, so that
//! colour carries some of the class signal but never all of it: walls, ceilings, doors,
//! beams, columns and whiteboards can all be off-white; tables, bookcases, doors and
//! clutter cabinets share wood tones; chairs and sofas share fabrics.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::shapes::Rgb;

/// Uniform in `[lo, hi)` (any order, equal ends allowed).
pub(crate) fn uniform(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.random::<f32>()
}

/// One of `options`, uniformly.
pub(crate) fn pick<T: Copy>(rng: &mut ChaCha8Rng, options: &[T]) -> T {
    options[rng.random_range(0..options.len())]
}

/// [`jitter`] of one of `options`.
pub(crate) fn jitter_pick(rng: &mut ChaCha8Rng, options: &[Rgb], amount: f32) -> Rgb {
    let base = pick(rng, options);
    jitter(rng, base, amount)
}

/// `base` with its brightness scaled by up to ±`amount` and each channel moved by up to
/// ±`amount`/2: the object-to-object variation of one material.
pub(crate) fn jitter(rng: &mut ChaCha8Rng, base: Rgb, amount: f32) -> Rgb {
    let b = 1.0 + uniform(rng, -amount, amount);
    let mut out = base;
    for c in &mut out {
        *c = (*c * b + uniform(rng, -amount, amount) * 0.5).clamp(0.0, 1.0);
    }
    out
}

const OFF_WHITES: [Rgb; 6] = [
    [0.92, 0.91, 0.88],
    [0.88, 0.86, 0.80],
    [0.85, 0.82, 0.74],
    [0.90, 0.90, 0.92],
    [0.80, 0.80, 0.78],
    [0.86, 0.80, 0.70],
];
const WOODS: [Rgb; 6] = [
    [0.78, 0.62, 0.42],
    [0.62, 0.45, 0.28],
    [0.45, 0.30, 0.18],
    [0.86, 0.74, 0.56],
    [0.35, 0.22, 0.14],
    [0.70, 0.55, 0.40],
];
const NEUTRALS: [Rgb; 6] = [
    [0.15, 0.15, 0.16],
    [0.35, 0.36, 0.38],
    [0.60, 0.61, 0.62],
    [0.82, 0.82, 0.80],
    [0.25, 0.25, 0.28],
    [0.92, 0.92, 0.90],
];
const FABRICS: [Rgb; 10] = [
    [0.20, 0.22, 0.30],
    [0.55, 0.12, 0.12],
    [0.20, 0.35, 0.55],
    [0.35, 0.35, 0.36],
    [0.15, 0.15, 0.15],
    [0.55, 0.45, 0.30],
    [0.25, 0.42, 0.30],
    [0.70, 0.55, 0.20],
    [0.45, 0.25, 0.40],
    [0.60, 0.60, 0.58],
];
const FLOORS: [Rgb; 7] = [
    [0.40, 0.40, 0.42],
    [0.30, 0.32, 0.38],
    [0.62, 0.48, 0.32],
    [0.75, 0.72, 0.66],
    [0.50, 0.45, 0.40],
    [0.28, 0.24, 0.22],
    [0.58, 0.58, 0.55],
];

/// The colour scheme of one room; objects take these through [`jitter`].
pub(crate) struct Palette {
    pub(crate) wall: Rgb,
    pub(crate) floor: Rgb,
    pub(crate) ceiling: Rgb,
    /// Beams and columns: painted like the walls or the ceiling, sometimes bare concrete.
    pub(crate) structure: Rgb,
    pub(crate) door: Rgb,
    pub(crate) frame: Rgb,
    pub(crate) glass: Rgb,
    /// Main wood or laminate of the room's furniture.
    pub(crate) wood: Rgb,
    /// Second furniture finish (metal legs, grey laminate).
    pub(crate) metal: Rgb,
    /// Upholstery of chairs and sofas.
    pub(crate) fabric: Rgb,
}

impl Palette {
    /// Draws a scheme.
    pub(crate) fn draw(rng: &mut ChaCha8Rng) -> Self {
        let wall = jitter_pick(rng, &OFF_WHITES, 0.04);
        let ceiling = jitter_pick(rng, &OFF_WHITES[..4], 0.03);
        let structure = match rng.random_range(0..3) {
            0 => jitter(rng, wall, 0.02),
            1 => jitter(rng, ceiling, 0.02),
            _ => jitter(rng, [0.62, 0.61, 0.58], 0.05),
        };
        let wood = pick(rng, &WOODS);
        let door = match rng.random_range(0..3) {
            0 => jitter(rng, wood, 0.05),
            1 => jitter(rng, wall, 0.03),
            _ => jitter_pick(rng, &NEUTRALS, 0.05),
        };
        Self {
            wall,
            floor: jitter_pick(rng, &FLOORS, 0.05),
            ceiling,
            structure,
            door,
            frame: jitter_pick(rng, &[[0.9, 0.9, 0.9], [0.3, 0.3, 0.32], [0.6, 0.6, 0.62], wood], 0.03),
            glass: jitter_pick(rng, &[[0.70, 0.82, 0.92], [0.55, 0.62, 0.66], [0.85, 0.88, 0.90]], 0.05),
            wood,
            metal: pick(rng, &NEUTRALS),
            fabric: pick(rng, &FABRICS),
        }
    }

    /// A furniture finish: mostly the room's wood, otherwise another wood or a neutral.
    pub(crate) fn furniture(&self, rng: &mut ChaCha8Rng) -> Rgb {
        match rng.random_range(0..6) {
            0..=2 => jitter(rng, self.wood, 0.05),
            3 => jitter_pick(rng, &WOODS, 0.05),
            _ => jitter_pick(rng, &NEUTRALS, 0.05),
        }
    }

    /// An upholstery colour: mostly the room's fabric.
    pub(crate) fn upholstery(&self, rng: &mut ChaCha8Rng) -> Rgb {
        if rng.random_bool(0.6) {
            jitter(rng, self.fabric, 0.06)
        } else {
            jitter_pick(rng, &FABRICS, 0.08)
        }
    }

    /// A neutral (metal, plastic) finish.
    pub(crate) fn neutral(&self, rng: &mut ChaCha8Rng) -> Rgb {
        if rng.random_bool(0.5) {
            jitter(rng, self.metal, 0.05)
        } else {
            jitter_pick(rng, &NEUTRALS, 0.05)
        }
    }

    /// Any colour at all (book spines, cups, boxes): saturated or not.
    pub(crate) fn any(&self, rng: &mut ChaCha8Rng) -> Rgb {
        match rng.random_range(0..4) {
            0 => pick(rng, &FABRICS),
            1 => pick(rng, &NEUTRALS),
            2 => pick(rng, &WOODS),
            _ => [uniform(rng, 0.1, 0.9), uniform(rng, 0.1, 0.9), uniform(rng, 0.1, 0.9)],
        }
    }

    /// Foliage green.
    pub(crate) fn leaves(&self, rng: &mut ChaCha8Rng) -> Rgb {
        jitter(rng, [0.22, 0.42, 0.18], 0.12)
    }

    /// Corrugated cardboard.
    pub(crate) fn cardboard(&self, rng: &mut ChaCha8Rng) -> Rgb {
        jitter(rng, [0.70, 0.55, 0.36], 0.06)
    }
}
