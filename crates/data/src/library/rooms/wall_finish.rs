//! Wall finishes other than plain paint: wood panelling (floor to ceiling, or a wainscot
//! below a rail with paint above), wallpaper (stripes or a small repeat) and brick.
//!
//! Real homes and offices have all of these, and the generated rooms had only paint: on
//! the real ScanNet homes the network called wood-panelled walls door or sofa, a vertical
//! brown plane having meant a door or furniture in everything it had seen. A finish changes
//! only the colours of the wall's vertices, so the class has to come from the geometry (a
//! large plane from floor to ceiling) rather than from the paint.
//!
//! Finishes come from their own random stream (seeded from the room's seed), so every other
//! choice of a room stays as it was and earlier evaluations stay comparable. A patterned wall
//! is tessellated finer ([`WallFinish::patch`]) so that its planks and stripes survive the
//! per-vertex colours.

use glam::Vec2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::HomeRoomKind;
use crate::synth::palette::{jitter, jitter_pick, uniform};
use crate::synth::shapes::{splitmix, Rgb};

/// Wood tones of panelling: light oak to walnut, with a reddish cherry.
const WOODS: [Rgb; 6] = [
    [0.74, 0.58, 0.40],
    [0.62, 0.45, 0.28],
    [0.48, 0.32, 0.20],
    [0.36, 0.24, 0.16],
    [0.60, 0.36, 0.24],
    [0.80, 0.70, 0.54],
];

/// How one wall is finished.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum WallFinish {
    /// The room's paint (the vertices keep their colour).
    Paint,
    /// Vertical boards of `plank` metres from the floor up to `top` (the whole wall when
    /// `top` is past the ceiling), with a darker rail `rail` metres high above them when
    /// they stop short of it.
    Panelling { wood: Rgb, plank: f32, top: f32, rail: f32, seams: bool },
    /// Two-tone wallpaper: vertical stripes of period `period`, or a grid of spots.
    Wallpaper { base: Rgb, figure: Rgb, period: f32, stripes: bool },
    /// Running-bond brick (21.5 x 6.5 cm bricks in 1 cm joints), painted or bare.
    Brick { brick: Rgb, mortar: Rgb },
}

impl WallFinish {
    /// Tessellation patch the wall needs (metres) so that its pattern shows in the vertex
    /// colours; `None` for the builder's default.
    pub(super) fn patch(&self) -> Option<f32> {
        match self {
            WallFinish::Paint => None,
            WallFinish::Panelling { plank, .. } => Some((plank * 0.5).clamp(0.03, 0.06)),
            WallFinish::Wallpaper { period, .. } => Some((period * 0.25).clamp(0.015, 0.05)),
            WallFinish::Brick { .. } => Some(0.022),
        }
    }

    /// The colour of the wall at `s` metres along it and `z` above the floor, `None` where
    /// the paint shows; `hash` varies it per vertex (a few per cent, as paint varies).
    pub(super) fn color_at(&self, s: f32, z: f32, hash: u64) -> Option<Rgb> {
        let grain = |bits: u64| 1.0 + 0.06 * (unit(bits) - 0.5);
        match *self {
            WallFinish::Paint => None,
            WallFinish::Panelling { wood, plank, top, rail, seams } => {
                if z > top + rail {
                    return None;
                }
                if z > top {
                    return Some(scale(wood, 0.8 * grain(hash)));
                }
                let board = (s / plank).floor();
                let tone = 1.0 + 0.16 * (unit(splitmix(board as i64 as u64 ^ 0x5EED)) - 0.5);
                // Grain: slow streaks along the board.
                let streak = 1.0 + 0.05 * (z * 7.0 + board * 1.7).sin();
                let seam = seams && (s / plank).fract() < 0.06;
                let f = if seam { 0.7 } else { tone * streak * grain(hash) };
                Some(scale(wood, f))
            }
            WallFinish::Wallpaper { base, figure, period, stripes } => {
                let u = (s / period).fract();
                let on = if stripes {
                    u < 0.4
                } else {
                    let v = (z / period).fract();
                    let row = (z / period).floor() as i64;
                    // Spots on a half-drop grid.
                    let u = if row % 2 == 0 { u } else { (u + 0.5).fract() };
                    (u - 0.5).powi(2) + (v - 0.5).powi(2) < 0.06
                };
                Some(scale(if on { figure } else { base }, grain(hash)))
            }
            WallFinish::Brick { brick, mortar } => {
                let (length, height, joint) = (0.225, 0.075, 0.01);
                let course = (z / height).floor();
                let shift = if course as i64 % 2 == 0 { 0.0 } else { length * 0.5 };
                let along = s + shift;
                let in_joint = (z / height).fract() * height < joint || (along / length).fract() * length < joint;
                if in_joint {
                    return Some(scale(mortar, grain(hash)));
                }
                let id = splitmix((course as i64 as u64) << 32 ^ (along / length).floor() as i64 as u64);
                Some(scale(brick, (1.0 + 0.2 * (unit(id) - 0.5)) * grain(hash)))
            }
        }
    }
}

/// The finishes of a room's four walls.
pub(super) fn draw_finishes(rng: &mut ChaCha8Rng, kind: HomeRoomKind, height: f32) -> [WallFinish; 4] {
    let mut walls = [WallFinish::Paint; 4];
    // Bathrooms keep their paint and tiles.
    if kind == HomeRoomKind::Bathroom || rng.random_bool(0.6) {
        return walls;
    }
    let finish = match rng.random_range(0..20) {
        0..=3 => {
            let wood = jitter_pick(rng, &WOODS, 0.05);
            WallFinish::Panelling {
                wood,
                plank: uniform(rng, 0.08, 0.2),
                top: height + 1.0,
                rail: 0.0,
                seams: rng.random_bool(0.5),
            }
        }
        4..=9 => {
            // A wainscot: wood, or boards painted white or a colour.
            let wood = if rng.random_bool(0.6) {
                jitter_pick(rng, &WOODS, 0.05)
            } else {
                jitter_pick(
                    rng,
                    &[[0.92, 0.92, 0.90], [0.85, 0.86, 0.84], [0.35, 0.45, 0.50], [0.55, 0.60, 0.50]],
                    0.04,
                )
            };
            let top = uniform(rng, 0.8, 1.4).min(height - 0.3);
            WallFinish::Panelling {
                wood,
                plank: uniform(rng, 0.08, 0.3),
                top,
                rail: uniform(rng, 0.03, 0.08),
                seams: rng.random_bool(0.7),
            }
        }
        10..=16 => {
            let base = jitter_pick(
                rng,
                &[[0.90, 0.88, 0.82], [0.85, 0.80, 0.70], [0.78, 0.84, 0.82], [0.80, 0.76, 0.82], [0.60, 0.66, 0.58]],
                0.04,
            );
            let figure = if rng.random_bool(0.5) {
                // The same hue, darker or lighter.
                base.map(|c| (c * uniform(rng, 0.7, 0.85)).clamp(0.0, 1.0))
            } else {
                jitter_pick(
                    rng,
                    &[[0.55, 0.30, 0.30], [0.30, 0.40, 0.55], [0.70, 0.62, 0.40], [0.35, 0.50, 0.35]],
                    0.05,
                )
            };
            WallFinish::Wallpaper { base, figure, period: uniform(rng, 0.05, 0.25), stripes: rng.random_bool(0.5) }
        }
        _ => {
            let (brick, mortar) = if rng.random_bool(0.7) {
                (
                    jitter_pick(rng, &[[0.62, 0.32, 0.24], [0.70, 0.45, 0.32], [0.52, 0.28, 0.22]], 0.05),
                    [0.70, 0.68, 0.64],
                )
            } else {
                (jitter(rng, [0.92, 0.91, 0.88], 0.03), [0.80, 0.79, 0.76])
            };
            WallFinish::Brick { brick, mortar }
        }
    };
    if rng.random_bool(0.5) {
        walls = [finish; 4];
    } else {
        walls[rng.random_range(0..4)] = finish;
    }
    walls
}

/// Position along a wall (metres from its start) of a point whose floor-plane projection is `p`.
pub(super) fn along_wall(start: Vec2, dir: Vec2, p: Vec2) -> f32 {
    (p - start).dot(dir)
}

fn scale(c: Rgb, f: f32) -> Rgb {
    c.map(|x| (x * f).clamp(0.0, 1.0))
}

fn unit(bits: u64) -> f32 {
    (bits & 0xFFFF) as f32 / 65535.0
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;

    #[test]
    fn every_finish_is_drawn_and_colours_stay_in_range() {
        let mut seen = [0usize; 4];
        for seed in 0..400 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            for f in draw_finishes(&mut rng, HomeRoomKind::LivingRoom, 2.7) {
                let i = match f {
                    WallFinish::Paint => 0,
                    WallFinish::Panelling { .. } => 1,
                    WallFinish::Wallpaper { .. } => 2,
                    WallFinish::Brick { .. } => 3,
                };
                seen[i] += 1;
                for k in 0..50 {
                    let (s, z) = (k as f32 * 0.037, k as f32 * 0.051);
                    if let Some(c) = f.color_at(s, z, splitmix(k)) {
                        assert!(c.iter().all(|x| (0.0..=1.0).contains(x)), "{f:?} gave {c:?}");
                    }
                }
            }
        }
        assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
        // Most walls stay painted.
        assert!(seen[0] > seen[1] + seen[2] + seen[3], "{seen:?}");
    }

    #[test]
    fn a_wainscot_leaves_the_paint_above_its_rail() {
        let f = WallFinish::Panelling { wood: WOODS[0], plank: 0.1, top: 1.0, rail: 0.05, seams: true };
        assert!(f.color_at(0.33, 0.5, 1).is_some());
        assert!(f.color_at(0.33, 1.02, 1).is_some());
        assert!(f.color_at(0.33, 1.2, 1).is_none());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        assert_eq!(draw_finishes(&mut rng, HomeRoomKind::Bathroom, 2.5), [WallFinish::Paint; 4]);
    }
}
