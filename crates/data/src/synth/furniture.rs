//! Furniture models: tables and desks, chairs (four-legged and swivel), sofas and
//! armchairs, bookcases filled with books (labelled bookcase, as S3DIS does), and boards on
//! walls. Every model is built in its own frame: origin at the centre of its footprint on
//! the floor, front (the side a person uses) facing local +y, footprint
//! `[-width/2, width/2] x [-depth/2, depth/2]`. Sizes follow real furniture (table tops at
//! 0.72-0.76 m, chair seats at about 0.45 m, sofa seats at about 0.42 m).

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::palette::{jitter, uniform, Palette};
use super::shapes::{MeshBuilder, Rgb, SKIP_NEG_Y, SKIP_NEG_Z, SKIP_POS_Z};
use crate::class::SemanticClass;

const TABLE: SemanticClass = SemanticClass::Table;
const CHAIR: SemanticClass = SemanticClass::Chair;
const SOFA: SemanticClass = SemanticClass::Sofa;
const BOOKCASE: SemanticClass = SemanticClass::Bookcase;
const BOARD: SemanticClass = SemanticClass::Board;

/// Standard table-top height (metres), 0.72..0.76.
pub(crate) fn table_height(rng: &mut ChaCha8Rng) -> f32 {
    uniform(rng, 0.72, 0.76)
}

/// A rectangular table `width` x `depth` with its top at `height`: four legs, two panel
/// legs, or a trestle frame. Returns the top's colour.
pub(crate) fn table(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    width: f32,
    depth: f32,
    height: f32,
) -> Rgb {
    let top_color = pal.furniture(rng);
    let leg_color = if rng.random_bool(0.5) { top_color } else { pal.neutral(rng) };
    let t = uniform(rng, 0.025, 0.05);
    let (hw, hd) = (width * 0.5, depth * 0.5);
    b.cuboid(Vec3::new(-hw, -hd, height - t), Vec3::new(hw, hd, height), 0, TABLE, top_color);
    let z = height - t;
    match rng.random_range(0..3) {
        0 => {
            let leg = uniform(rng, 0.04, 0.07);
            let inset = uniform(rng, 0.02, 0.08);
            let round = rng.random_bool(0.4);
            for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let c = Vec3::new(sx * (hw - inset - leg * 0.5), sy * (hd - inset - leg * 0.5), 0.0);
                if round {
                    b.frustum(c, z, leg * 0.5, leg * 0.5, 8, (false, false), TABLE, leg_color);
                } else {
                    let half = Vec3::new(leg * 0.5, leg * 0.5, 0.0);
                    b.cuboid(c - half, c + half + Vec3::Z * z, SKIP_POS_Z, TABLE, leg_color);
                }
            }
            // Apron under the top.
            if rng.random_bool(0.5) {
                let a = uniform(rng, 0.06, 0.1).min(z * 0.3);
                let i = inset + leg * 0.5;
                b.cuboid(
                    Vec3::new(-hw + i, -hd + i, z - a),
                    Vec3::new(hw - i, -hd + i + 0.02, z),
                    SKIP_POS_Z,
                    TABLE,
                    top_color,
                );
                b.cuboid(
                    Vec3::new(-hw + i, hd - i - 0.02, z - a),
                    Vec3::new(hw - i, hd - i, z),
                    SKIP_POS_Z,
                    TABLE,
                    top_color,
                );
            }
        }
        1 => {
            let p = uniform(rng, 0.025, 0.04);
            let inset = uniform(rng, 0.0, 0.1);
            for sx in [-1.0, 1.0] {
                let x = sx * (hw - inset - p * 0.5);
                b.cuboid(
                    Vec3::new(x - p * 0.5, -hd + 0.03, 0.0),
                    Vec3::new(x + p * 0.5, hd - 0.03, z),
                    SKIP_POS_Z,
                    TABLE,
                    leg_color,
                );
            }
            if rng.random_bool(0.6) {
                let zp = uniform(rng, 0.3, 0.45).min(z * 0.6);
                b.cuboid(
                    Vec3::new(-hw + inset + p, -0.01, z - zp),
                    Vec3::new(hw - inset - p, 0.01, z),
                    SKIP_POS_Z,
                    TABLE,
                    leg_color,
                );
            }
        }
        _ => {
            // Trestle: two posts on feet at each end joined by a stretcher.
            let post = uniform(rng, 0.05, 0.08);
            for sx in [-1.0f32, 1.0] {
                let x = sx * (hw - 0.15).max(0.1);
                b.cuboid(
                    Vec3::new(x - 0.03, -hd + 0.05, 0.0),
                    Vec3::new(x + 0.03, hd - 0.05, 0.05),
                    0,
                    TABLE,
                    leg_color,
                );
                b.cuboid(
                    Vec3::new(x - post * 0.5, -post * 0.5, 0.05),
                    Vec3::new(x + post * 0.5, post * 0.5, z),
                    SKIP_NEG_Z | SKIP_POS_Z,
                    TABLE,
                    leg_color,
                );
            }
            let x = (hw - 0.15).max(0.1) - post * 0.5;
            b.cuboid(Vec3::new(-x, -0.02, z * 0.35), Vec3::new(x, 0.02, z * 0.45), 0, TABLE, leg_color);
        }
    }
    top_color
}

/// An office desk: a table, often with a drawer pedestal under one side (part of the desk).
pub(crate) fn desk(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    width: f32,
    depth: f32,
    height: f32,
) -> Rgb {
    let color = table(b, rng, pal, width, depth, height);
    if rng.random_bool(0.6) && width > 1.0 {
        let pw = uniform(rng, 0.38, 0.45);
        let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let x0 = side * (width * 0.5 - 0.1 - pw * 0.5);
        let top = height - 0.06;
        b.cuboid(
            Vec3::new(x0 - pw * 0.5, -depth * 0.5 + 0.08, 0.0),
            Vec3::new(x0 + pw * 0.5, depth * 0.5 - 0.1, top),
            0,
            TABLE,
            color,
        );
        // Drawer fronts as thin slabs on the front face.
        let n = rng.random_range(2..=4);
        let dh = (top - 0.05) / n as f32;
        for i in 0..n {
            let z0 = 0.04 + i as f32 * dh;
            b.cuboid(
                Vec3::new(x0 - pw * 0.5 + 0.015, depth * 0.5 - 0.1, z0 + 0.008),
                Vec3::new(x0 + pw * 0.5 - 0.015, depth * 0.5 - 0.085, z0 + dh - 0.008),
                SKIP_NEG_Y,
                TABLE,
                jitter(rng, color, 0.04),
            );
        }
    }
    color
}

/// A round table of radius `radius` on a central pedestal.
pub(crate) fn round_table(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, radius: f32, height: f32) -> Rgb {
    let top = pal.furniture(rng);
    let base = if rng.random_bool(0.5) { top } else { pal.neutral(rng) };
    let t = uniform(rng, 0.025, 0.045);
    b.frustum(Vec3::Z * (height - t), t, radius, radius, 24, (true, true), TABLE, top);
    b.frustum(Vec3::Z * 0.03, height - t - 0.03, 0.04, 0.04, 10, (false, false), TABLE, base);
    b.frustum(Vec3::ZERO, 0.03, radius * 0.55, radius * 0.5, 16, (false, true), TABLE, base);
    top
}

/// The look and size of a chair, drawn once for a set of matching chairs (around one
/// table, at the desks of one office).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ChairStyle {
    /// Swivel office chair on a five-star base, else four legs.
    pub(crate) swivel: bool,
    /// Side of the square footprint.
    pub(crate) size: f32,
    seat_color: Rgb,
    frame_color: Rgb,
    back_color: Rgb,
    seat_h: f32,
    seat_t: f32,
    back_t: f32,
    back_h: f32,
    back_gap: f32,
    arms: bool,
    leg: f32,
}

impl ChairStyle {
    /// Draws a chair style; `swivel` chooses the kind.
    pub(crate) fn draw(rng: &mut ChaCha8Rng, pal: &Palette, swivel: bool) -> Self {
        let seat_color = if rng.random_bool(0.75) { pal.upholstery(rng) } else { pal.furniture(rng) };
        let frame_color = if rng.random_bool(0.5) { pal.neutral(rng) } else { pal.furniture(rng) };
        let back_color = if rng.random_bool(0.8) { seat_color } else { frame_color };
        Self {
            swivel,
            size: if swivel { uniform(rng, 0.56, 0.64) } else { uniform(rng, 0.45, 0.52) },
            seat_color,
            frame_color,
            back_color,
            seat_h: uniform(rng, 0.43, 0.49),
            seat_t: uniform(rng, 0.04, 0.08),
            back_t: uniform(rng, 0.03, 0.07),
            back_h: uniform(rng, 0.35, 0.55),
            back_gap: uniform(rng, 0.02, 0.12),
            arms: rng.random_bool(0.6),
            leg: uniform(rng, 0.025, 0.04),
        }
    }
}

/// A chair of `style` in its square footprint, seat at about 0.45 m, with a little
/// per-chair colour variation.
pub(crate) fn chair(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, style: &ChairStyle) {
    let ChairStyle { swivel, size, seat_h, seat_t, back_t, back_h, back_gap, arms, leg, .. } = *style;
    let seat_color = jitter(rng, style.seat_color, 0.02);
    let frame_color = jitter(rng, style.frame_color, 0.02);
    let back_color = jitter(rng, style.back_color, 0.02);
    let (width, depth) = (size, size);
    let (hw, hd) = (width * 0.5, depth * 0.5);
    let sw = if swivel { width * 0.8 } else { width };
    let seat_min = Vec3::new(-sw * 0.5, -hd + back_t, seat_h - seat_t);
    let seat_max = Vec3::new(sw * 0.5, if swivel { hd - 0.05 } else { hd }, seat_h);
    b.cuboid(seat_min, seat_max, 0, CHAIR, seat_color);
    // Back rest behind the seat.
    let back_w = sw * 0.92;
    let back_z0 = seat_h + back_gap;
    b.cuboid(
        Vec3::new(-back_w * 0.5, -hd, back_z0),
        Vec3::new(back_w * 0.5, -hd + back_t, seat_h + back_h),
        0,
        CHAIR,
        back_color,
    );
    if swivel {
        // Struts from seat to back, gas column, five-star base with casters.
        b.cuboid(
            Vec3::new(-0.03, -hd + back_t, seat_h - seat_t - 0.02),
            Vec3::new(0.03, -hd + back_t + 0.12, back_z0 + 0.05),
            0,
            CHAIR,
            frame_color,
        );
        b.frustum(Vec3::Z * 0.08, seat_h - seat_t - 0.08, 0.028, 0.028, 8, (false, false), CHAIR, frame_color);
        let reach = hw.min(hd) - 0.03;
        for k in 0..5 {
            let yaw = std::f32::consts::TAU * k as f32 / 5.0 + 0.3;
            let saved = b.push(Vec3::ZERO, yaw);
            b.cuboid(Vec3::new(0.0, -0.02, 0.05), Vec3::new(reach, 0.02, 0.09), 0, CHAIR, frame_color);
            b.cuboid(Vec3::new(reach - 0.04, -0.02, 0.0), Vec3::new(reach, 0.02, 0.05), 0, CHAIR, frame_color);
            b.pop(saved);
        }
        if arms {
            for sx in [-1.0, 1.0] {
                let x = sx * (sw * 0.5 - 0.03);
                b.cuboid(
                    Vec3::new(x - 0.015, -0.05, seat_h),
                    Vec3::new(x + 0.015, 0.0, seat_h + 0.2),
                    SKIP_NEG_Z,
                    CHAIR,
                    frame_color,
                );
                b.cuboid(
                    Vec3::new(x - 0.03, -0.2, seat_h + 0.2),
                    Vec3::new(x + 0.03, 0.1, seat_h + 0.23),
                    0,
                    CHAIR,
                    frame_color,
                );
            }
        }
    } else {
        let z = seat_h - seat_t;
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let c = Vec3::new(sx * (sw * 0.5 - leg * 0.5 - 0.01), sy * (hd - leg * 0.5 - 0.01), 0.0);
            let half = Vec3::new(leg * 0.5, leg * 0.5, 0.0);
            b.cuboid(c - half, c + half + Vec3::Z * z, SKIP_POS_Z, CHAIR, frame_color);
            if sy < 0.0 {
                // Back posts run up to the back rest.
                b.cuboid(
                    Vec3::new(c.x - leg * 0.5, -hd, seat_h),
                    Vec3::new(c.x + leg * 0.5, -hd + leg.min(back_t), back_z0),
                    SKIP_NEG_Z | SKIP_POS_Z,
                    CHAIR,
                    frame_color,
                );
            }
        }
    }
}

/// A sofa (or, narrow, an armchair) in a `width` x `depth` footprint: base, seat cushions,
/// back, arms, short feet.
pub(crate) fn sofa(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, width: f32, depth: f32) {
    let fabric = pal.upholstery(rng);
    let cushion = if rng.random_bool(0.7) { fabric } else { pal.upholstery(rng) };
    let feet = pal.furniture(rng);
    let (hw, hd) = (width * 0.5, depth * 0.5);
    let foot = uniform(rng, 0.04, 0.12);
    let seat_h = uniform(rng, 0.40, 0.46);
    let cushion_t = uniform(rng, 0.1, 0.16);
    let back_t = uniform(rng, 0.15, 0.25);
    let back_top = uniform(rng, 0.72, 0.9);
    let arm_w = uniform(rng, 0.1, 0.2);
    let arm_h = uniform(rng, 0.55, 0.66).min(back_top);
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        let c = Vec3::new(sx * (hw - 0.06), sy * (hd - 0.06), 0.0);
        b.cuboid(c - Vec3::new(0.025, 0.025, 0.0), c + Vec3::new(0.025, 0.025, foot), SKIP_POS_Z, SOFA, feet);
    }
    let base_top = seat_h - cushion_t;
    b.cuboid(Vec3::new(-hw, -hd, foot), Vec3::new(hw, hd, base_top), 0, SOFA, fabric);
    b.cuboid(Vec3::new(-hw, -hd, base_top), Vec3::new(hw, -hd + back_t, back_top), SKIP_NEG_Z, SOFA, fabric);
    for sx in [-1.0, 1.0] {
        let x0 = if sx < 0.0 { -hw } else { hw - arm_w };
        b.cuboid(Vec3::new(x0, -hd + back_t, base_top), Vec3::new(x0 + arm_w, hd, arm_h), SKIP_NEG_Z, SOFA, fabric);
    }
    let inner = width - 2.0 * arm_w;
    let seats = ((inner / 0.6).round() as usize).max(1);
    let cw = inner / seats as f32;
    for i in 0..seats {
        let x0 = -hw + arm_w + i as f32 * cw;
        b.cuboid(
            Vec3::new(x0 + 0.005, -hd + back_t, base_top),
            Vec3::new(x0 + cw - 0.005, hd - 0.01, seat_h),
            SKIP_NEG_Z,
            SOFA,
            jitter(rng, cushion, 0.03),
        );
        if rng.random_bool(0.5) {
            // Loose back cushion leaning on the back.
            b.cuboid(
                Vec3::new(x0 + 0.02, -hd + back_t, seat_h),
                Vec3::new(x0 + cw - 0.02, -hd + back_t + 0.12, back_top - 0.05),
                SKIP_NEG_Z | SKIP_NEG_Y,
                SOFA,
                jitter(rng, cushion, 0.03),
            );
        }
    }
}

/// A bookcase `width` x `depth` x `height`: sides, top, plinth, back, shelves, and books
/// (class bookcase) standing on the shelves with gaps.
pub(crate) fn bookcase(b: &mut MeshBuilder, rng: &mut ChaCha8Rng, pal: &Palette, width: f32, depth: f32, height: f32) {
    let wood = pal.furniture(rng);
    let (hw, hd) = (width * 0.5, depth * 0.5);
    let t = uniform(rng, 0.018, 0.03);
    let plinth = uniform(rng, 0.05, 0.1);
    b.cuboid(Vec3::new(-hw, -hd, 0.0), Vec3::new(-hw + t, hd, height), 0, BOOKCASE, wood);
    b.cuboid(Vec3::new(hw - t, -hd, 0.0), Vec3::new(hw, hd, height), 0, BOOKCASE, wood);
    b.cuboid(Vec3::new(-hw + t, -hd, height - t), Vec3::new(hw - t, hd, height), 0, BOOKCASE, wood);
    b.cuboid(Vec3::new(-hw + t, -hd + t, 0.0), Vec3::new(hw - t, hd - 0.01, plinth), 0, BOOKCASE, wood);
    b.cuboid(Vec3::new(-hw + t, -hd, plinth), Vec3::new(hw - t, -hd + t * 0.5, height - t), SKIP_NEG_Y, BOOKCASE, wood);
    let n = ((height - plinth) / uniform(rng, 0.3, 0.4)).round().max(2.0) as usize;
    let pitch = (height - plinth - t) / n as f32;
    let inner_w = width - 2.0 * t;
    for i in 0..n {
        let z = plinth + i as f32 * pitch;
        if i > 0 {
            b.cuboid(Vec3::new(-hw + t, -hd + t * 0.5, z - t), Vec3::new(hw - t, hd, z), 0, BOOKCASE, wood);
        }
        // Books: runs of upright volumes with gaps, some shelves half empty.
        let fill = uniform(rng, 0.3, 1.0);
        let mut x = -hw + t + uniform(rng, 0.0, 0.1);
        let end = -hw + t + inner_w * fill;
        let depth_max = (depth - t).min(0.3);
        while x < end - 0.02 {
            if rng.random_bool(0.08) {
                x += uniform(rng, 0.05, 0.2);
                continue;
            }
            let bw = uniform(rng, 0.015, 0.06);
            if x + bw > hw - t - 0.005 {
                break;
            }
            let bh = uniform(rng, 0.6, 0.92) * (pitch - t);
            let bd = uniform(rng, 0.6, 1.0) * depth_max;
            let color = pal.any(rng);
            b.cuboid(
                Vec3::new(x, -hd + t * 0.5 + 0.005, z),
                Vec3::new(x + bw, -hd + t * 0.5 + 0.005 + bd, z + bh),
                SKIP_NEG_Z | SKIP_NEG_Y,
                BOOKCASE,
                color,
            );
            x += bw + if rng.random_bool(0.15) { uniform(rng, 0.005, 0.03) } else { 0.001 };
        }
    }
}

/// Kind of board on a wall.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum BoardKind {
    White,
    Black,
    Cork,
}

/// A board in the wall frame (local x along the wall, +y into the room): `s0..s1` along
/// the wall, `z0..z1` high, with a frame and, for chalk and marker boards, a tray below.
#[allow(clippy::too_many_arguments)]
pub(crate) fn board(
    b: &mut MeshBuilder,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    s0: f32,
    s1: f32,
    z0: f32,
    z1: f32,
    kind: BoardKind,
) {
    let surface: Rgb = match kind {
        BoardKind::White => jitter(rng, [0.93, 0.93, 0.92], 0.03),
        BoardKind::Black => super::palette::jitter_pick(rng, &[[0.12, 0.2, 0.16], [0.12, 0.12, 0.13]], 0.03),
        BoardKind::Cork => jitter(rng, [0.66, 0.5, 0.32], 0.05),
    };
    let frame: Rgb = match kind {
        BoardKind::Cork => pal.furniture(rng),
        _ => jitter(rng, [0.7, 0.71, 0.72], 0.04),
    };
    let t = uniform(rng, 0.015, 0.03);
    let f = uniform(rng, 0.02, 0.04);
    b.set_noise(0.03);
    b.cuboid(Vec3::new(s0 + f, 0.0, z0 + f), Vec3::new(s1 - f, t, z1 - f), SKIP_NEG_Y, BOARD, surface);
    for (a, c) in [
        (Vec3::new(s0, 0.0, z0), Vec3::new(s0 + f, t + 0.008, z1)),
        (Vec3::new(s1 - f, 0.0, z0), Vec3::new(s1, t + 0.008, z1)),
        (Vec3::new(s0 + f, 0.0, z0), Vec3::new(s1 - f, t + 0.008, z0 + f)),
        (Vec3::new(s0 + f, 0.0, z1 - f), Vec3::new(s1 - f, t + 0.008, z1)),
    ] {
        b.cuboid(a, c, SKIP_NEG_Y, BOARD, frame);
    }
    if kind != BoardKind::Cork {
        b.cuboid(Vec3::new(s0 + 0.1, 0.0, z0 - 0.03), Vec3::new(s1 - 0.1, 0.07, z0), SKIP_NEG_Y, BOARD, frame);
    }
    if kind == BoardKind::Cork {
        // Pinned notes: part of the board, like drawings on a whiteboard.
        for _ in 0..rng.random_range(3..10) {
            let (w, h) = (uniform(rng, 0.1, 0.25), uniform(rng, 0.1, 0.3));
            let s = uniform(rng, s0 + f + 0.02, (s1 - f - w - 0.02).max(s0 + f + 0.02));
            let z = uniform(rng, z0 + f + 0.02, (z1 - f - h - 0.02).max(z0 + f + 0.02));
            let paper = jitter(rng, [0.92, 0.92, 0.88], 0.08);
            b.rect(Vec3::new(s, t + 0.002, z), Vec3::X * w, Vec3::Z * h, Vec3::Y, BOARD, paper);
        }
    }
    b.set_noise(0.06);
}
