//! Clutter: everything S3DIS files under "clutter". Floor objects (cardboard boxes, bins,
//! potted plants, floor lamps, filing cabinets), objects on tables (monitors, keyboards,
//! laptops, cups, papers, desk lamps, small plants, book piles) and wall objects (radiators
//! under windows, pictures, clocks, screens). Some share the finishes of furniture (a
//! wooden cabinet, a screen as dark as a blackboard) so that colour alone cannot tell them
//! apart. Models use the furniture convention: origin at the footprint centre, front +y.

use glam::{Vec2, Vec3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::palette::{jitter, uniform, Palette};
use super::shapes::{MeshBuilder, SKIP_NEG_Y};
use crate::class::SemanticClass;

const CLUTTER: SemanticClass = SemanticClass::Clutter;

/// Floor clutter kinds, drawn by [`floor_item`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FloorItem {
    Boxes,
    Bin,
    Plant,
    Lamp,
    Cabinet,
}

impl FloorItem {
    /// Footprint (width, depth) and height drawn for this kind.
    pub(crate) fn size(self, rng: &mut ChaCha8Rng) -> (f32, f32, f32) {
        match self {
            Self::Boxes => (uniform(rng, 0.35, 0.7), uniform(rng, 0.3, 0.55), 0.0),
            Self::Bin => {
                let d = uniform(rng, 0.25, 0.4);
                (d, d, uniform(rng, 0.3, 0.5))
            }
            Self::Plant => {
                let d = uniform(rng, 0.3, 0.6);
                (d, d, uniform(rng, 0.6, 1.6))
            }
            Self::Lamp => {
                let d = uniform(rng, 0.3, 0.45);
                (d, d, uniform(rng, 1.4, 1.8))
            }
            Self::Cabinet => (uniform(rng, 0.4, 0.9), uniform(rng, 0.45, 0.6), uniform(rng, 0.6, 1.3)),
        }
    }
}

/// Builds a floor item of `kind` in a `width` x `depth` footprint, `height` tall (when the
/// kind has a height).
pub(crate) fn floor_item(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    kind: FloorItem,
    width: f32,
    depth: f32,
    height: f32,
) {
    match kind {
        FloorItem::Boxes => box_stack(b, rng, pal, width, depth),
        FloorItem::Bin => {
            let r = width.min(depth) * 0.5;
            b.frustum(Vec3::ZERO, height, r * 0.85, r, 14, (false, true), CLUTTER, pal.any(rng));
        }
        FloorItem::Plant => plant(b, rng, pal, width.min(depth) * 0.5, height),
        FloorItem::Lamp => floor_lamp(b, rng, pal, width.min(depth) * 0.5, height),
        FloorItem::Cabinet => cabinet(b, rng, pal, width, depth, height),
    }
}

/// One to three cardboard boxes stacked, each smaller than the one below.
fn box_stack(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, width: f32, depth: f32) {
    let mut z = 0.0;
    let (mut w, mut d) = (width, depth);
    for _ in 0..rng.random_range(1..=3) {
        let h = uniform(rng, 0.2, 0.45);
        let off = Vec2::new(uniform(rng, -0.5, 0.5) * (width - w), uniform(rng, -0.5, 0.5) * (depth - d));
        let color = if rng.random_bool(0.8) { pal.cardboard(rng) } else { pal.any(rng) };
        b.cuboid(
            Vec3::new(off.x - w * 0.5, off.y - d * 0.5, z),
            Vec3::new(off.x + w * 0.5, off.y + d * 0.5, z + h),
            0,
            CLUTTER,
            color,
        );
        z += h;
        w *= uniform(rng, 0.7, 0.95);
        d *= uniform(rng, 0.7, 0.95);
    }
}

/// A potted plant: pot, soil, and a few foliage blobs up to `height`.
pub(crate) fn plant(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, radius: f32, height: f32) {
    let pot_h = (height * uniform(rng, 0.25, 0.4)).min(0.5);
    let pot_r = radius * uniform(rng, 0.5, 0.7);
    let pot = if rng.random_bool(0.5) { jitter(rng, [0.65, 0.35, 0.22], 0.08) } else { pal.any(rng) };
    b.frustum(Vec3::ZERO, pot_h, pot_r * 0.75, pot_r, 12, (false, false), CLUTTER, pot);
    b.frustum(
        Vec3::Z * (pot_h - 0.02),
        0.0001,
        pot_r * 0.97,
        pot_r * 0.97,
        12,
        (false, true),
        CLUTTER,
        [0.25, 0.18, 0.12],
    );
    let stem_top = pot_h + (height - pot_h) * 0.4;
    b.frustum(
        Vec3::Z * (pot_h - 0.02),
        stem_top - pot_h + 0.02,
        0.015,
        0.01,
        6,
        (false, false),
        CLUTTER,
        [0.35, 0.25, 0.15],
    );
    let leaves = pal.leaves(rng);
    let crown = (height - stem_top) * 0.5;
    for _ in 0..rng.random_range(2..=4) {
        // Blobs stay inside the footprint radius, whatever the plant's yaw.
        let r = Vec3::new(
            radius * uniform(rng, 0.45, 0.7),
            radius * uniform(rng, 0.45, 0.7),
            crown * uniform(rng, 0.5, 0.9),
        );
        let c = Vec3::new(
            uniform(rng, -0.2, 0.2) * radius,
            uniform(rng, -0.2, 0.2) * radius,
            (stem_top + r.z).min(height - r.z),
        );
        b.ellipsoid(c, r, 10, 6, CLUTTER, jitter(rng, leaves, 0.05));
    }
}

fn floor_lamp(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, radius: f32, height: f32) {
    let metal = pal.neutral(rng);
    let shade = jitter(rng, [0.9, 0.86, 0.75], 0.06);
    b.frustum(Vec3::ZERO, 0.03, radius * 0.7, radius * 0.65, 16, (false, true), CLUTTER, metal);
    let shade_h = uniform(rng, 0.25, 0.35);
    b.frustum(Vec3::Z * 0.03, height - shade_h - 0.03, 0.012, 0.012, 6, (false, false), CLUTTER, metal);
    b.frustum(Vec3::Z * (height - shade_h), shade_h, radius, radius * 0.7, 16, (true, true), CLUTTER, shade);
}

/// A filing cabinet or sideboard with drawer fronts, often in the furniture's wood.
fn cabinet(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, width: f32, depth: f32, height: f32) {
    let color = pal.furniture(rng);
    let (hw, hd) = (width * 0.5, depth * 0.5);
    b.cuboid(Vec3::new(-hw, -hd, 0.0), Vec3::new(hw, hd - 0.015, height), 0, CLUTTER, color);
    let n = ((height / 0.3).round() as usize).max(2);
    let dh = height / n as f32;
    let handle = pal.neutral(rng);
    for i in 0..n {
        let z = i as f32 * dh;
        b.cuboid(
            Vec3::new(-hw + 0.01, hd - 0.015, z + 0.01),
            Vec3::new(hw - 0.01, hd, z + dh - 0.01),
            SKIP_NEG_Y,
            CLUTTER,
            jitter(rng, color, 0.03),
        );
        b.cuboid(
            Vec3::new(-0.06, hd, z + dh * 0.7),
            Vec3::new(0.06, hd + 0.02, z + dh * 0.7 + 0.02),
            SKIP_NEG_Y,
            CLUTTER,
            handle,
        );
    }
}

/// Things on a table top of `width` x `depth` at `height`: a workstation (monitor,
/// keyboard, mouse, cup, lamp) when `workstation`, otherwise laptops, cups, papers, plants
/// and book piles. Items are laid out in columns across the width so they never overlap.
#[allow(clippy::too_many_arguments)]
pub(crate) fn table_items(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    width: f32,
    depth: f32,
    height: f32,
    workstation: bool,
) -> usize {
    let mut count = 0;
    let (hw, hd) = (width * 0.5, depth * 0.5);
    if workstation {
        let x = uniform(rng, -0.15, 0.15) * width;
        monitor(b, rng, pal, Vec3::new(x, -hd + 0.2, height));
        let kb = pal.neutral(rng);
        b.cuboid(Vec3::new(x - 0.22, 0.0, height), Vec3::new(x + 0.22, 0.15, height + 0.025), 0, CLUTTER, kb);
        b.cuboid(Vec3::new(x + 0.3, 0.03, height), Vec3::new(x + 0.36, 0.13, height + 0.03), 0, CLUTTER, kb);
        count += 3;
        let side = if x > 0.0 { -1.0 } else { 1.0 };
        if hw > 0.55 {
            cup(b, rng, pal, Vec3::new(side * (hw - 0.15), hd - 0.2, height));
            count += 1;
        }
        // The back corner away from the monitor holds a lamp or a pile of paper (the
        // monitor reaches at most 0.33 m past the centre towards it).
        if hw >= 0.6 {
            let corner = Vec3::new(side * (hw - 0.17), -hd + 0.2, height);
            if rng.random_bool(0.5) {
                desk_lamp(b, rng, pal, corner);
                count += 1;
            } else if rng.random_bool(0.6) {
                papers(b, rng, corner);
                count += 1;
            }
        }
        return count;
    }
    // Free-form: one item per 0.45 m column, each on one side of the table.
    let columns = ((width - 0.1) / 0.45).floor().max(1.0) as usize;
    for i in 0..columns {
        if !rng.random_bool(0.55) {
            continue;
        }
        let x = -hw + 0.05 + (i as f32 + 0.5) * (width - 0.1) / columns as f32;
        let y = if rng.random_bool(0.5) { hd - 0.22 } else { -hd + 0.22 };
        let y = if depth < 0.6 { 0.0 } else { y };
        let base = Vec3::new(x, y, height);
        match rng.random_range(0..5) {
            0 => laptop(b, rng, pal, base, y >= 0.0),
            1 => cup(b, rng, pal, base),
            2 => papers(b, rng, base),
            3 => {
                let saved = b.push(base, 0.0);
                let h = uniform(rng, 0.2, 0.35);
                plant(b, rng, pal, 0.1, h);
                b.pop(saved);
            }
            _ => book_pile(b, rng, pal, base),
        }
        count += 1;
    }
    count
}

fn monitor(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, at: Vec3) {
    let body = if rng.random_bool(0.7) { jitter(rng, [0.12, 0.12, 0.13], 0.03) } else { pal.neutral(rng) };
    let screen = jitter(rng, [0.05, 0.06, 0.08], 0.02);
    let (w, h) = (uniform(rng, 0.5, 0.65), uniform(rng, 0.3, 0.38));
    b.cuboid(at + Vec3::new(-0.12, -0.1, 0.0), at + Vec3::new(0.12, 0.08, 0.015), 0, CLUTTER, body);
    b.cuboid(at + Vec3::new(-0.025, -0.06, 0.015), at + Vec3::new(0.025, -0.03, 0.15), 0, CLUTTER, body);
    let z0 = at.z + uniform(rng, 0.1, 0.16);
    b.cuboid(Vec3::new(at.x - w * 0.5, at.y - 0.03, z0), Vec3::new(at.x + w * 0.5, at.y, z0 + h), 0, CLUTTER, body);
    b.set_noise(0.02);
    b.rect(
        Vec3::new(at.x - w * 0.5 + 0.015, at.y + 0.001, z0 + 0.02),
        Vec3::X * (w - 0.03),
        Vec3::Z * (h - 0.035),
        Vec3::Y,
        CLUTTER,
        screen,
    );
    b.set_noise(0.06);
}

fn cup(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, at: Vec3) {
    let r = uniform(rng, 0.035, 0.045);
    b.frustum(at, uniform(rng, 0.08, 0.11), r * 0.9, r, 10, (false, true), CLUTTER, pal.any(rng));
}

fn papers(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, at: Vec3) {
    let t = uniform(rng, 0.003, 0.02);
    b.cuboid(
        at + Vec3::new(-0.105, -0.15, 0.0),
        at + Vec3::new(0.105, 0.15, t),
        0,
        CLUTTER,
        jitter(rng, [0.93, 0.93, 0.9], 0.04),
    );
}

fn laptop(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, at: Vec3, facing_front: bool) {
    let color = pal.neutral(rng);
    let saved = b.push(at, if facing_front { 0.0 } else { std::f32::consts::PI });
    b.cuboid(Vec3::new(-0.16, -0.11, 0.0), Vec3::new(0.16, 0.11, 0.02), 0, CLUTTER, color);
    b.cuboid(Vec3::new(-0.16, -0.12, 0.02), Vec3::new(0.16, -0.11, 0.24), 0, CLUTTER, color);
    b.pop(saved);
}

fn book_pile(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, at: Vec3) {
    let mut z = at.z;
    for _ in 0..rng.random_range(1..=4) {
        let (w, d, t) = (uniform(rng, 0.15, 0.24), uniform(rng, 0.2, 0.3), uniform(rng, 0.015, 0.05));
        let saved = b.push(Vec3::new(at.x, at.y, z), uniform(rng, -0.3, 0.3));
        b.cuboid(Vec3::new(-w * 0.5, -d * 0.5, 0.0), Vec3::new(w * 0.5, d * 0.5, t), 0, CLUTTER, pal.any(rng));
        b.pop(saved);
        z += t;
    }
}

fn desk_lamp(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, at: Vec3) {
    let c = pal.any(rng);
    b.frustum(at, 0.025, 0.08, 0.07, 12, (false, true), CLUTTER, c);
    b.frustum(at + Vec3::Z * 0.025, 0.35, 0.012, 0.012, 6, (false, false), CLUTTER, c);
    b.frustum(at + Vec3::new(0.0, 0.0, 0.3), 0.12, 0.09, 0.04, 12, (true, true), CLUTTER, c);
}

/// A radiator in the wall frame under a window: `s0..s1` along the wall, `z0..z1` high.
pub(crate) fn radiator(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, s0: f32, s1: f32, z0: f32, z1: f32) {
    let color = jitter(rng, [0.88, 0.88, 0.86], 0.04);
    let depth = uniform(rng, 0.07, 0.11);
    b.cuboid(Vec3::new(s0, 0.03, z0), Vec3::new(s1, 0.03 + depth, z1), SKIP_NEG_Y, CLUTTER, color);
    for s in [s0 + 0.05, s1 - 0.05] {
        b.cuboid(Vec3::new(s - 0.01, 0.0, z0 + 0.05), Vec3::new(s + 0.01, 0.03, z0 + 0.09), SKIP_NEG_Y, CLUTTER, color);
    }
}

/// Wall clutter kinds, drawn by [`wall_item`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WallItem {
    Picture,
    Clock,
    Screen,
}

/// A wall item in the wall frame centred at `s` along the wall and `z` high, `width` x
/// `height`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn wall_item(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    kind: WallItem,
    s: f32,
    z: f32,
    width: f32,
    height: f32,
) {
    let (s0, s1, z0, z1) = (s - width * 0.5, s + width * 0.5, z - height * 0.5, z + height * 0.5);
    match kind {
        WallItem::Picture => {
            let frame = pal.furniture(rng);
            b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, 0.02, z1), SKIP_NEG_Y, CLUTTER, frame);
            b.set_noise(0.12);
            b.rect(
                Vec3::new(s0 + 0.04, 0.021, z0 + 0.04),
                Vec3::X * (width - 0.08),
                Vec3::Z * (height - 0.08),
                Vec3::Y,
                CLUTTER,
                pal.any(rng),
            );
            b.set_noise(0.06);
        }
        WallItem::Clock => {
            b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, 0.04, z1), SKIP_NEG_Y, CLUTTER, pal.any(rng));
            b.rect(
                Vec3::new(s0 + 0.02, 0.041, z0 + 0.02),
                Vec3::X * (width - 0.04),
                Vec3::Z * (height - 0.04),
                Vec3::Y,
                CLUTTER,
                jitter(rng, [0.95, 0.95, 0.93], 0.02),
            );
        }
        WallItem::Screen => {
            let body = jitter(rng, [0.1, 0.1, 0.11], 0.03);
            b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, 0.06, z1), SKIP_NEG_Y, CLUTTER, body);
        }
    }
}
