//! The shell of a room: floor, ceiling, four walls with window and door openings cut out,
//! the recessed window panes and door leaves set into the openings, beams under the ceiling
//! and columns (pilasters against walls and free-standing ones, under the beams as in a
//! real frame structure). The shell is closed: from inside, every direction meets a
//! surface, and the openings show glass or a door leaf a few centimetres behind the wall
//! plane, with the reveals in between.

use glam::{Vec2, Vec3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::layout::{footprint, Layout, Rect2};
use super::palette::{jitter, uniform, Palette};
use super::shapes::{MeshBuilder, Rgb, SKIP_NEG_Y, SKIP_NEG_Z, SKIP_POS_Y, SKIP_POS_Z};
use super::RoomStyle;
use crate::class::SemanticClass;

/// Window pane or door leaf.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum OpeningKind {
    Door,
    Window,
}

/// A rectangular hole in a wall (wall frame: s along the wall, z up).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Opening {
    pub(crate) wall: usize,
    pub(crate) s0: f32,
    pub(crate) s1: f32,
    pub(crate) z0: f32,
    pub(crate) z1: f32,
    pub(crate) kind: OpeningKind,
    /// How far behind the wall plane the pane or leaf sits.
    pub(crate) recess: f32,
}

/// Lowest underside of a beam: above every door and window head and every piece of
/// furniture, as in a real room.
const BEAM_CLEARANCE: f32 = 2.3;

/// Adds beams across the short side of the room and columns, registering columns as floor
/// obstacles and both in the wall occupancy. Always adds at least one beam and one column.
pub(crate) fn add_structure(
    b: &mut MeshBuilder,
    layout: &mut Layout,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    style: RoomStyle,
) {
    let (w, d, h) = (layout.width, layout.depth, layout.height);
    let along_x = w >= d; // beams at positions along x, spanning y
    let (long, short) = if along_x { (w, d) } else { (d, w) };
    let n_beams = match style {
        RoomStyle::Hallway => ((long / 3.5) as usize).clamp(2, 5),
        _ => rng.random_range(1..=3),
    };
    let beam_depth = uniform(rng, 0.25, 0.5).min(h - BEAM_CLEARANCE);
    let beam_width = uniform(rng, 0.25, 0.45);
    let beam_color = jitter(rng, pal.structure, 0.02);
    let column_color = jitter(rng, pal.structure, 0.03);
    let mut columns = 0;
    b.place(Vec3::ZERO, 0.0);
    for i in 0..n_beams {
        let p = long * (i as f32 + 1.0) / (n_beams as f32 + 1.0) + uniform(rng, -0.3, 0.3);
        let (min, max, skip) = if along_x {
            (
                Vec3::new(p - beam_width * 0.5, 0.0, h - beam_depth),
                Vec3::new(p + beam_width * 0.5, d, h),
                SKIP_NEG_Y | SKIP_POS_Y | SKIP_POS_Z,
            )
        } else {
            (
                Vec3::new(0.0, p - beam_width * 0.5, h - beam_depth),
                Vec3::new(w, p + beam_width * 0.5, h),
                super::shapes::SKIP_NEG_X | super::shapes::SKIP_POS_X | SKIP_POS_Z,
            )
        };
        b.place(Vec3::ZERO, 0.0);
        b.cuboid(min, max, skip, SemanticClass::Beam, beam_color);
        layout.interest.push((min + max) * 0.5);
        // The walls the beam rests on, and where along them.
        let ends = if along_x { [(0usize, p), (2, w - p)] } else { [(1usize, p), (3, d - p)] };
        for &(k, s) in &ends {
            layout.reserve_wall(k, s - beam_width * 0.5, s + beam_width * 0.5, h - beam_depth, h);
        }
        let pilaster_p = if style == RoomStyle::Hallway { 0.5 } else { 0.35 };
        for &(k, s) in &ends {
            if rng.random_bool(pilaster_p) {
                let cw = beam_width + uniform(rng, 0.0, 0.2);
                let cd = uniform(rng, 0.15, 0.4);
                if add_pilaster(b, layout, k, s, cw, cd, column_color) {
                    columns += 1;
                }
            }
        }
        let free_p = match style {
            RoomStyle::Hallway => 0.0,
            RoomStyle::Conference => 0.15,
            // Rows of tables need the middle of the room.
            RoomStyle::Classroom => 0.1,
            _ => 0.35,
        };
        if short >= 4.5 && rng.random_bool(free_p) {
            let q = short * if rng.random_bool(0.5) { uniform(rng, 0.25, 0.35) } else { uniform(rng, 0.65, 0.75) };
            let c = if along_x { Vec2::new(p, q) } else { Vec2::new(q, p) };
            let size = uniform(rng, 0.3, 0.5).max(beam_width);
            let r = footprint(c, size, size, 0.0);
            if layout.floor_free(&Rect2::new(r.min - Vec2::splat(0.6), r.max + Vec2::splat(0.6))) {
                b.place(c.extend(0.0), 0.0);
                if rng.random_bool(0.5) {
                    b.frustum(
                        Vec3::ZERO,
                        h,
                        size * 0.5,
                        size * 0.5,
                        16,
                        (false, false),
                        SemanticClass::Column,
                        column_color,
                    );
                } else {
                    let half = Vec3::new(size * 0.5, size * 0.5, 0.0);
                    b.cuboid(-half, half + Vec3::Z * h, SKIP_POS_Z | SKIP_NEG_Z, SemanticClass::Column, column_color);
                }
                layout.add_obstacle(r);
                layout.interest.push(c.extend(h * 0.5));
                columns += 1;
            }
        }
    }
    // Every room has a column: fall back to a corner column, then to any pilaster.
    let mut tries = 0;
    while columns == 0 && tries < 64 {
        tries += 1;
        let k = rng.random_range(0..4);
        let cw = uniform(rng, 0.3, 0.6);
        let cd = uniform(rng, 0.25, 0.5);
        let len = layout.walls[k].length;
        let s = if tries < 16 {
            if rng.random_bool(0.5) {
                cw * 0.5
            } else {
                len - cw * 0.5
            }
        } else {
            uniform(rng, cw, len - cw)
        };
        if add_pilaster(b, layout, k, s, cw, cd, column_color) {
            columns += 1;
        }
    }
}

/// Deepest bulkhead (a beam along a wall): offices and conference rooms of real buildings
/// (S3DIS's among them) carry ducts and down-stand beams boxed in along their walls, up to
/// about a metre deep, where our cross beams are 0.25-0.5 m.
const WALL_BEAM_MAX_DEPTH: f32 = 1.0;

/// Lowest underside of a bulkhead: boxed-in ducts come down to about door-head height (the
/// openings below are checked), lower than the cross beams' [`BEAM_CLEARANCE`]. A 3 m office
/// then gets bulkheads up to the full metre deep, as real ones are.
const WALL_BEAM_CLEARANCE: f32 = 2.05;

/// Adds bulkheads: beams running the whole length of one or two walls, flush against them,
/// 0.3-0.8 m into the room and 0.3-1.0 m below the ceiling (never lower than
/// [`WALL_BEAM_CLEARANCE`]), labelled beam and painted like the structure. A wall whose openings
/// or earlier beams reach the bulkhead's underside gets a shallower one or none. Reserves
/// the wall above the underside. Returns how many were added.
///
/// Call after the openings are planned, so that window heads are known.
pub(crate) fn add_wall_beams(b: &mut MeshBuilder, layout: &mut Layout, rng: &mut ChaCha8Rng, pal: &Palette) -> usize {
    let h = layout.height;
    let max_depth = (h - WALL_BEAM_CLEARANCE).min(WALL_BEAM_MAX_DEPTH);
    if max_depth < 0.2 {
        return 0;
    }
    let n = if rng.random_bool(0.3) { 2 } else { 1 };
    let first = rng.random_range(0..4usize);
    // Two bulkheads go on opposite walls (a corridor's ducts) or adjacent ones (an L).
    let second = (first + if rng.random_bool(0.5) { 2 } else { 1 }) % 4;
    let color = jitter(rng, pal.structure, 0.02);
    let mut added = 0;
    for &k in [first, second].iter().take(n) {
        let width = uniform(rng, 0.3, 0.8);
        let wanted = uniform(rng, 0.3_f32.min(max_depth), max_depth);
        let len = layout.walls[k].length;
        // The deepest of the wanted, 2/3 and 1/3 of it whose underside is clear of
        // openings and of beams already resting on the wall.
        let depth = [wanted, wanted * 2.0 / 3.0, wanted / 3.0]
            .into_iter()
            .filter(|&dp| dp >= 0.15)
            .find(|&dp| layout.wall_free(k, 0.0, len, h - dp - 0.05, h - dp, 0.0));
        let Some(depth) = depth else { continue };
        let wall = layout.walls[k];
        b.place(wall.start.extend(0.0), wall.yaw);
        b.cuboid(
            Vec3::new(0.0, 0.0, h - depth),
            Vec3::new(len, width, h),
            super::shapes::SKIP_NEG_X | super::shapes::SKIP_POS_X | SKIP_NEG_Y | SKIP_POS_Z,
            SemanticClass::Beam,
            color,
        );
        layout.reserve_wall(k, 0.0, len, h - depth, h);
        layout.interest.push(wall.point(len * 0.5, width * 0.5).extend(h - depth * 0.5));
        added += 1;
    }
    added
}

/// A column against wall `k` at `s`, `width` along the wall and `depth` into the room, if
/// the wall and floor there are free.
#[allow(clippy::too_many_arguments)]
pub(crate) fn add_pilaster(
    b: &mut MeshBuilder,
    layout: &mut Layout,
    k: usize,
    s: f32,
    width: f32,
    depth: f32,
    color: [f32; 3],
) -> bool {
    let h = layout.height;
    let wall = layout.walls[k];
    let (s0, s1) = ((s - width * 0.5).max(0.0), (s + width * 0.5).min(wall.length));
    let center = wall.point((s0 + s1) * 0.5, depth * 0.5);
    let r = footprint(center, s1 - s0, depth, wall.yaw);
    if s1 - s0 < 0.2 || !layout.wall_free(k, s0, s1, 0.0, BEAM_CLEARANCE, 0.05) || !layout.floor_free(&r) {
        return false;
    }
    b.place(wall.start.extend(0.0), wall.yaw);
    b.cuboid(Vec3::new(s0, 0.0, 0.0), Vec3::new(s1, depth, h), SKIP_NEG_Y | SKIP_POS_Z, SemanticClass::Column, color);
    layout.reserve_wall(k, s0, s1, 0.0, h);
    layout.add_obstacle(r);
    layout.interest.push(center.extend(h * 0.5));
    // A pilaster in a corner also takes the end of the neighbouring wall.
    if s0 <= 1e-4 {
        let prev = (k + 3) % 4;
        let len = layout.walls[prev].length;
        layout.reserve_wall(prev, len - depth, len, 0.0, h);
    }
    if s1 >= wall.length - 1e-4 {
        layout.reserve_wall((k + 1) % 4, 0.0, depth, 0.0, h);
    }
    true
}

/// Chooses doors and windows for the style and reserves their wall spans (and the floor in
/// front of doors). At least one door and one window.
pub(crate) fn plan_openings(layout: &mut Layout, rng: &mut ChaCha8Rng, style: RoomStyle) -> Vec<Opening> {
    let mut openings = Vec::new();
    // A classroom has its windows along one long wall and its doors in the other.
    let classroom_walls = (style == RoomStyle::Classroom).then(|| {
        let long = if layout.width >= layout.depth { [0, 2] } else { [1, 3] };
        let i = rng.random_range(0..2);
        (long[i], long[1 - i])
    });
    // Doors.
    let (door_walls, n_doors): (Vec<usize>, usize) = match (style, classroom_walls) {
        (RoomStyle::Hallway, _) => {
            let long = if layout.width >= layout.depth { vec![0, 2] } else { vec![1, 3] };
            (long, rng.random_range(2..=4))
        }
        (_, Some((_, doors))) => (vec![doors], rng.random_range(1..=2)),
        _ => (vec![0, 1, 2, 3], rng.random_range(1..=2)),
    };
    let mut tries = 0;
    while (openings.len() < n_doors || openings.is_empty()) && tries < 200 {
        tries += 1;
        let k = door_walls[rng.random_range(0..door_walls.len())];
        let double = matches!(style, RoomStyle::Conference | RoomStyle::Lounge) && rng.random_bool(0.3);
        let dw = if double { uniform(rng, 1.5, 1.8) } else { uniform(rng, 0.85, 1.0) };
        let dh = uniform(rng, 2.03, 2.2);
        let len = layout.walls[k].length;
        if len < dw + 1.2 {
            continue;
        }
        let s = uniform(rng, 0.5 + dw * 0.5, len - 0.5 - dw * 0.5);
        if try_add_opening(layout, &mut openings, k, s, dw, 0.0, dh, OpeningKind::Door, uniform(rng, 0.03, 0.07)) {
            // Also leave the swing of the door free on the floor.
            let wall = layout.walls[k];
            let swing = footprint(wall.point(s, 0.5), dw + 0.2, 1.0, wall.yaw);
            layout.add_keepout(swing);
        }
    }
    // Extra door at the end of a hallway.
    if style == RoomStyle::Hallway && rng.random_bool(0.5) {
        let k = if layout.width >= layout.depth { 1 } else { 0 };
        let len = layout.walls[k].length;
        let dw = uniform(rng, 0.85, 1.0).min(len - 0.8);
        if try_add_opening(
            layout,
            &mut openings,
            k,
            len * 0.5,
            dw,
            0.0,
            uniform(rng, 2.03, 2.2),
            OpeningKind::Door,
            0.05,
        ) {
            let wall = layout.walls[k];
            layout.add_keepout(footprint(wall.point(len * 0.5, 0.5), dw + 0.2, 1.0, wall.yaw));
        }
    }
    // Windows on one or two outside walls.
    let outside: Vec<usize> = match (style, classroom_walls) {
        (_, Some((windows, _))) => vec![windows],
        (RoomStyle::Hallway, _) => {
            let ends = if layout.width >= layout.depth { [1, 3] } else { [0, 2] };
            let long = if layout.width >= layout.depth { 2 } else { 1 };
            if rng.random_bool(0.5) {
                vec![ends[rng.random_range(0..2)]]
            } else {
                vec![long]
            }
        }
        _ => {
            let first = rng.random_range(0..4);
            if rng.random_bool(0.35) {
                vec![first, (first + 1) % 4]
            } else {
                vec![first]
            }
        }
    };
    add_windows(layout, &mut openings, rng, &outside, style == RoomStyle::Classroom, true);
    openings
}

/// Adds windows (one sill and head height for all) on the walls `outside`: 3-5 of them
/// when `many`, else 1-4, at least one. When `any_wall` and the outside walls have no room
/// left, any wall will do; rooms of a flat pass `false` (an inside wall has a neighbour
/// behind it, not daylight).
pub(crate) fn add_windows(
    layout: &mut Layout,
    openings: &mut Vec<Opening>,
    rng: &mut ChaCha8Rng,
    outside: &[usize],
    many: bool,
    any_wall: bool,
) {
    if outside.is_empty() {
        return;
    }
    let h = layout.height;
    let sill = uniform(rng, 0.8, 1.0);
    let head = uniform(rng, 2.0, 2.2).min(h - 0.4);
    let mut windows = 0;
    let mut tries = 0;
    let wanted = if many { rng.random_range(3..=5) } else { rng.random_range(1..=4) };
    while (windows < wanted && tries < 60) || (windows == 0 && tries < 400) {
        tries += 1;
        let k = outside[rng.random_range(0..outside.len())];
        let k = if tries > 200 && any_wall { rng.random_range(0..4) } else { k };
        let len = layout.walls[k].length;
        let ww = uniform(rng, 0.8, 1.8).min(len - 1.0);
        if ww < 0.6 {
            continue;
        }
        let s = uniform(rng, 0.4 + ww * 0.5, len - 0.4 - ww * 0.5);
        if try_add_opening(layout, openings, k, s, ww, sill, head, OpeningKind::Window, uniform(rng, 0.08, 0.2)) {
            windows += 1;
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn try_add_opening(
    layout: &mut Layout,
    openings: &mut Vec<Opening>,
    k: usize,
    s: f32,
    width: f32,
    z0: f32,
    z1: f32,
    kind: OpeningKind,
    recess: f32,
) -> bool {
    let (s0, s1) = (s - width * 0.5, s + width * 0.5);
    // Keep 10 cm of wall around openings for the casing.
    if s0 < 0.25 || s1 > layout.walls[k].length - 0.25 || !layout.wall_free(k, s0 - 0.1, s1 + 0.1, 0.0, z1 + 0.1, 0.0) {
        return false;
    }
    if kind == OpeningKind::Door {
        let wall = layout.walls[k];
        let swing = footprint(wall.point(s, 0.5), width + 0.2, 1.0, wall.yaw);
        if !layout.floor_free(&swing) {
            return false;
        }
    }
    // Below a window sill the wall stays usable for desks and sofas, not for bookcases.
    layout.reserve_wall(k, s0 - 0.1, s1 + 0.1, if kind == OpeningKind::Window { z0 - 0.02 } else { 0.0 }, z1 + 0.1);
    let wall = layout.walls[k];
    layout.interest.push(wall.point(s, 0.0).extend((z0 + z1) * 0.5));
    openings.push(Opening { wall: k, s0, s1, z0, z1, kind, recess });
    true
}

/// Emits wall `k` of `layout`, floor to ceiling in `color`, with holes for the `openings`
/// in it (leaves `b` placed in the wall's frame).
pub(crate) fn wall_with_openings(b: &mut MeshBuilder, layout: &Layout, k: usize, openings: &[Opening], color: Rgb) {
    let wall = layout.walls[k];
    let holes: Vec<[f32; 4]> = openings.iter().filter(|o| o.wall == k).map(|o| [o.s0, o.s1, o.z0, o.z1]).collect();
    b.place(wall.start.extend(0.0), wall.yaw);
    b.rect_with_holes(
        Vec3::ZERO,
        Vec3::X * wall.length,
        Vec3::Z * layout.height,
        Vec3::Y,
        &holes,
        SemanticClass::Wall,
        color,
    );
}

/// Emits floor, ceiling and walls with their openings, panes, leaves, reveals and casings.
pub(crate) fn build_shell(
    b: &mut MeshBuilder,
    layout: &Layout,
    openings: &[Opening],
    rng: &mut ChaCha8Rng,
    pal: &Palette,
) {
    build_surfaces(b, layout, openings, rng, pal);
    for o in openings {
        let wall = layout.walls[o.wall];
        b.place(wall.start.extend(0.0), wall.yaw);
        match o.kind {
            OpeningKind::Window => window(b, o, rng, pal),
            OpeningKind::Door => door(b, o, rng, pal),
        }
    }
    b.set_noise(0.06);
}

/// Emits floor, ceiling (with its light panels) and the four walls with holes for the
/// `openings`, but nothing in the holes: [`build_shell`] fills them with panes and leaves, a
/// flat's rooms fill some with passages to the next room instead.
pub(crate) fn build_surfaces(
    b: &mut MeshBuilder,
    layout: &Layout,
    openings: &[Opening],
    rng: &mut ChaCha8Rng,
    pal: &Palette,
) {
    let (w, d, h) = (layout.width, layout.depth, layout.height);
    b.place(Vec3::ZERO, 0.0);
    b.set_noise(0.05);
    b.rect(Vec3::ZERO, Vec3::X * w, Vec3::Y * d, Vec3::Z, SemanticClass::Floor, pal.floor);
    b.rect(Vec3::Z * h, Vec3::X * w, Vec3::Y * d, -Vec3::Z, SemanticClass::Ceiling, pal.ceiling);
    // Recessed light panels on a regular grid: part of the ceiling (as S3DIS labels
    // them), but brighter than the paint around them.
    let (pw, pd) = if rng.random_bool(0.5) { (0.6, 0.6) } else { (1.2, 0.3) };
    let pitch = uniform(rng, 2.0, 2.8);
    let (nx, ny) = (((w / pitch).floor() as usize).max(1), ((d / pitch).floor() as usize).max(1));
    let light = jitter(rng, [0.97, 0.97, 0.95], 0.02);
    b.set_noise(0.02);
    for i in 0..nx {
        for j in 0..ny {
            let c = Vec2::new(w * (i as f32 + 0.5) / nx as f32, d * (j as f32 + 0.5) / ny as f32);
            let corner = Vec3::new(c.x - pw * 0.5, c.y - pd * 0.5, h - 0.005);
            b.rect(corner, Vec3::X * pw, Vec3::Y * pd, -Vec3::Z, SemanticClass::Ceiling, light);
        }
    }
    b.set_noise(0.05);
    for k in 0..4 {
        wall_with_openings(b, layout, k, openings, pal.wall);
    }
}

/// Reveals of an opening (wall frame): the four sides of the hole between the wall plane
/// and the recessed pane or leaf, facing into the hole.
fn reveals(
    b: &mut MeshBuilder,
    o: &Opening,
    side: SemanticClass,
    bottom: SemanticClass,
    color: [f32; 3],
    bottom_color: [f32; 3],
) {
    let r = o.recess;
    let depth = Vec3::Y * -r;
    let (ws, hz) = (Vec3::X * (o.s1 - o.s0), Vec3::Z * (o.z1 - o.z0));
    let p00 = Vec3::new(o.s0, 0.0, o.z0);
    b.rect(p00, depth, hz, Vec3::X, side, color);
    b.rect(p00 + ws, depth, hz, -Vec3::X, side, color);
    b.rect(p00 + hz, depth, ws, -Vec3::Z, side, color);
    b.rect(p00, depth, ws, Vec3::Z, bottom, bottom_color);
}

pub(crate) fn window(b: &mut MeshBuilder, o: &Opening, rng: &mut ChaCha8Rng, pal: &Palette) {
    reveals(b, o, SemanticClass::Wall, SemanticClass::Wall, pal.wall, jitter(rng, pal.wall, 0.03));
    let r = o.recess;
    b.set_noise(0.02);
    let glass = jitter(rng, pal.glass, 0.04);
    b.rect(
        Vec3::new(o.s0, -r, o.z0),
        Vec3::X * (o.s1 - o.s0),
        Vec3::Z * (o.z1 - o.z0),
        Vec3::Y,
        SemanticClass::Window,
        glass,
    );
    b.set_noise(0.04);
    let frame = jitter(rng, pal.frame, 0.03);
    let fw = uniform(rng, 0.04, 0.07);
    let t0 = -r;
    let t1 = -r + uniform(rng, 0.04, 0.07).min(r - 0.01);
    let bar = |b: &mut MeshBuilder, s0: f32, s1: f32, z0: f32, z1: f32| {
        b.cuboid(Vec3::new(s0, t0, z0), Vec3::new(s1, t1, z1), SKIP_NEG_Y, SemanticClass::Window, frame);
    };
    bar(b, o.s0, o.s0 + fw, o.z0, o.z1);
    bar(b, o.s1 - fw, o.s1, o.z0, o.z1);
    bar(b, o.s0 + fw, o.s1 - fw, o.z0, o.z0 + fw);
    bar(b, o.s0 + fw, o.s1 - fw, o.z1 - fw, o.z1);
    let panes = ((o.s1 - o.s0) / 0.7).round().max(1.0) as usize;
    for i in 1..panes {
        let s = o.s0 + (o.s1 - o.s0) * i as f32 / panes as f32;
        bar(b, s - fw * 0.4, s + fw * 0.4, o.z0 + fw, o.z1 - fw);
    }
    if rng.random_bool(0.4) {
        let z = o.z0 + (o.z1 - o.z0) * 0.7;
        bar(b, o.s0 + fw, o.s1 - fw, z - fw * 0.4, z + fw * 0.4);
    }
}

pub(crate) fn door(b: &mut MeshBuilder, o: &Opening, rng: &mut ChaCha8Rng, pal: &Palette) {
    let leaf_color = jitter(rng, pal.door, 0.03);
    let casing_color = if rng.random_bool(0.5) { jitter(rng, pal.door, 0.02) } else { jitter(rng, pal.frame, 0.03) };
    reveals(b, o, SemanticClass::Door, SemanticClass::Floor, casing_color, pal.floor);
    let r = o.recess;
    let width = o.s1 - o.s0;
    b.rect(
        Vec3::new(o.s0, -r, o.z0),
        Vec3::X * width,
        Vec3::Z * (o.z1 - o.z0),
        Vec3::Y,
        SemanticClass::Door,
        leaf_color,
    );
    // Casing around the opening, proud of the wall.
    let (cw, ct) = (uniform(rng, 0.05, 0.09), uniform(rng, 0.01, 0.025));
    let casing = |b: &mut MeshBuilder, s0: f32, s1: f32, z0: f32, z1: f32| {
        b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, ct, z1), SKIP_NEG_Y, SemanticClass::Door, casing_color);
    };
    casing(b, o.s0 - cw, o.s0, 0.0, o.z1 + cw);
    casing(b, o.s1, o.s1 + cw, 0.0, o.z1 + cw);
    casing(b, o.s0, o.s1, o.z1, o.z1 + cw);
    // Handles; a double door gets a centre seam and two.
    let metal = pal.neutral(rng);
    let handle = |b: &mut MeshBuilder, s: f32| {
        b.cuboid(
            Vec3::new(s - 0.01, -r, 0.98),
            Vec3::new(s + 0.01, -r + 0.05, 1.02),
            SKIP_NEG_Y,
            SemanticClass::Door,
            metal,
        );
        b.cuboid(
            Vec3::new(s - 0.12, -r + 0.05, 0.985),
            Vec3::new(s + 0.01, -r + 0.07, 1.015),
            0,
            SemanticClass::Door,
            metal,
        );
    };
    if width > 1.3 {
        let mid = (o.s0 + o.s1) * 0.5;
        b.cuboid(
            Vec3::new(mid - 0.005, -r, 0.0),
            Vec3::new(mid + 0.005, -r + 0.01, o.z1),
            SKIP_NEG_Y | SKIP_NEG_Z | SKIP_POS_Z,
            SemanticClass::Door,
            casing_color,
        );
        handle(b, mid - 0.06);
        handle(b, mid + 0.18);
    } else if rng.random_bool(0.5) {
        handle(b, o.s1 - 0.06);
    } else {
        handle(b, o.s0 + 0.18);
    }
}

/// An open door (b placed in the wall's frame, as for [`door`]): the opening goes through a
/// wall `0.1-0.2` m thick into a small room or corridor behind it (floor, walls and ceiling
/// as far as the view through the doorway reaches), and the leaf (two for an opening wider
/// than 1.3 m) stands swung into the room by 25-95 degrees about its hinge, reaching at most
/// 0.85 m from the wall (the floor kept free in front of doors). Real scans catch doors
/// open as often as shut; the leaf is then a free-standing panel, easy to take for clutter.
pub(crate) fn open_door(b: &mut MeshBuilder, o: &Opening, rng: &mut ChaCha8Rng, pal: &Palette, room_height: f32) {
    let thickness = uniform(rng, 0.1, 0.2);
    let leaf_color = jitter(rng, pal.door, 0.03);
    let casing_color = if rng.random_bool(0.5) { jitter(rng, pal.door, 0.02) } else { jitter(rng, pal.frame, 0.03) };
    let through = Opening { recess: thickness, ..*o };
    reveals(b, &through, SemanticClass::Door, SemanticClass::Floor, casing_color, pal.floor);
    let (cw, ct) = (uniform(rng, 0.05, 0.09), uniform(rng, 0.01, 0.025));
    for (s0, s1, z0, z1) in
        [(o.s0 - cw, o.s0, 0.0, o.z1 + cw), (o.s1, o.s1 + cw, 0.0, o.z1 + cw), (o.s0, o.s1, o.z1, o.z1 + cw)]
    {
        b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, ct, z1), SKIP_NEG_Y, SemanticClass::Door, casing_color);
    }
    // Beyond: a box from the wall's back face, a little wider than the doorway.
    let (sa, sb) = (o.s0 - uniform(rng, 0.3, 1.5), o.s1 + uniform(rng, 0.3, 1.5));
    let (y0, y1) = (-thickness, -thickness - uniform(rng, 1.0, 2.5));
    let (span, reach) = (Vec3::X * (sb - sa), Vec3::Y * (y0 - y1));
    let h = room_height;
    let beyond_wall = jitter(rng, pal.wall, 0.05);
    let beyond_floor = jitter(rng, pal.floor, 0.05);
    b.rect(Vec3::new(sa, y1, 0.0), span, reach, Vec3::Z, SemanticClass::Floor, beyond_floor);
    b.rect(Vec3::new(sa, y1, h), span, reach, -Vec3::Z, SemanticClass::Ceiling, jitter(rng, pal.ceiling, 0.03));
    b.rect(Vec3::new(sa, y1, 0.0), span, Vec3::Z * h, Vec3::Y, SemanticClass::Wall, beyond_wall);
    b.rect(Vec3::new(sa, y1, 0.0), reach, Vec3::Z * h, Vec3::X, SemanticClass::Wall, beyond_wall);
    b.rect(Vec3::new(sb, y1, 0.0), reach, Vec3::Z * h, -Vec3::X, SemanticClass::Wall, beyond_wall);
    b.rect_with_holes(
        Vec3::new(sa, y0, 0.0),
        span,
        Vec3::Z * h,
        -Vec3::Y,
        &[[o.s0 - sa, o.s1 - sa, o.z0, o.z1]],
        SemanticClass::Wall,
        beyond_wall,
    );
    // The leaves: hinged at an edge of the opening, turned into the room.
    let width = o.s1 - o.s0;
    let leaves: Vec<(f32, bool, f32)> = if width > 1.3 {
        vec![(o.s0, true, width * 0.5), (o.s1, false, width * 0.5)]
    } else if rng.random_bool(0.5) {
        vec![(o.s0, true, width)]
    } else {
        vec![(o.s1, false, width)]
    };
    for (hinge, at_start, w) in leaves {
        let max_angle = if w > 0.85 { (0.85 / w).asin().to_degrees() } else { 95.0 };
        let angle = uniform(rng, 25.0_f32.min(max_angle), max_angle).to_radians();
        let yaw = if at_start { angle } else { std::f32::consts::PI - angle };
        let saved = b.push(Vec3::new(hinge, 0.0, 0.0), yaw);
        let (y_lo, y_hi) = if at_start { (-0.04, 0.0) } else { (0.0, 0.04) };
        b.cuboid(
            Vec3::new(0.01, y_lo, o.z0 + 0.01),
            Vec3::new(w - 0.01, y_hi, o.z1 - 0.01),
            0,
            SemanticClass::Door,
            leaf_color,
        );
        let metal = pal.neutral(rng);
        for (a, c) in [(y_hi, y_hi + 0.05), (y_lo - 0.05, y_lo)] {
            b.cuboid(Vec3::new(w - 0.14, a, 0.98), Vec3::new(w - 0.06, c, 1.02), 0, SemanticClass::Door, metal);
        }
        b.pop(saved);
    }
}

/// A door leaf standing open in a doorway of a flat: hinged at the opening's `s0` edge
/// (`at_start`) or its `s1` edge, turned `angle` radians into the room from the wall.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Leaf {
    pub(crate) at_start: bool,
    pub(crate) angle: f32,
}

/// One side of a doorway between two rooms of a flat (b placed in the wall's frame, as for
/// [`door`]): the casing around the opening on this side, the reveals lining the hole through
/// the wall's `thickness` when `reveals` (one of the two rooms draws them, so that they are
/// not doubled), and the leaf when it swings into this room. Unlike [`open_door`] nothing is
/// made up behind the wall: the next room is really there. Returns the leaf's footprint in
/// the wall frame (along the wall, into the room), for the scan planner to walk around.
#[allow(clippy::too_many_arguments)]
pub(crate) fn passage(
    b: &mut MeshBuilder,
    o: &Opening,
    rng: &mut ChaCha8Rng,
    pal: &Palette,
    thickness: f32,
    reveals_here: bool,
    leaf: Option<Leaf>,
) -> Option<Rect2> {
    let casing_color = if rng.random_bool(0.5) { jitter(rng, pal.door, 0.02) } else { jitter(rng, pal.frame, 0.03) };
    if reveals_here {
        let through = Opening { recess: thickness, ..*o };
        reveals(b, &through, SemanticClass::Door, SemanticClass::Floor, casing_color, pal.floor);
    }
    let (cw, ct) = (uniform(rng, 0.05, 0.09), uniform(rng, 0.01, 0.025));
    for (s0, s1, z0, z1) in
        [(o.s0 - cw, o.s0, 0.0, o.z1 + cw), (o.s1, o.s1 + cw, 0.0, o.z1 + cw), (o.s0, o.s1, o.z1, o.z1 + cw)]
    {
        b.cuboid(Vec3::new(s0, 0.0, z0), Vec3::new(s1, ct, z1), SKIP_NEG_Y, SemanticClass::Door, casing_color);
    }
    let leaf = leaf?;
    let w = o.s1 - o.s0;
    let leaf_color = jitter(rng, pal.door, 0.03);
    let hinge = if leaf.at_start { o.s0 } else { o.s1 };
    let yaw = if leaf.at_start { leaf.angle } else { std::f32::consts::PI - leaf.angle };
    let saved = b.push(Vec3::new(hinge, 0.0, 0.0), yaw);
    let (y_lo, y_hi) = if leaf.at_start { (-0.04, 0.0) } else { (0.0, 0.04) };
    b.cuboid(
        Vec3::new(0.01, y_lo, o.z0 + 0.01),
        Vec3::new(w - 0.01, y_hi, o.z1 - 0.01),
        0,
        SemanticClass::Door,
        leaf_color,
    );
    let metal = pal.neutral(rng);
    for (a, c) in [(y_hi, y_hi + 0.05), (y_lo - 0.05, y_lo)] {
        b.cuboid(Vec3::new(w - 0.14, a, 0.98), Vec3::new(w - 0.06, c, 1.02), 0, SemanticClass::Door, metal);
    }
    b.pop(saved);
    // The leaf's box (handles included) turned about the hinge, as a floor footprint.
    let (sin, cos) = yaw.sin_cos();
    let corners = [(0.0, y_lo - 0.05), (w, y_lo - 0.05), (0.0, y_hi + 0.05), (w, y_hi + 0.05)]
        .map(|(x, y): (f32, f32)| Vec2::new(hinge + x * cos - y * sin, x * sin + y * cos));
    let lo = corners.iter().fold(Vec2::splat(f32::INFINITY), |a, c| a.min(*c));
    let hi = corners.iter().fold(Vec2::splat(f32::NEG_INFINITY), |a, c| a.max(*c));
    Some(Rect2::new(lo, hi.max(lo)))
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;

    /// Bulkheads added to `layout` with a palette drawn from `rng`: how many, and the
    /// vertices of their beam-labelled triangles.
    fn wall_beam_vertices(rng: &mut ChaCha8Rng, layout: &mut Layout, seed: u64) -> (usize, Vec<Vec3>) {
        let pal = Palette::draw(rng);
        let mut b = MeshBuilder::new(0.12, seed);
        let added = add_wall_beams(&mut b, layout, rng, &pal);
        let mesh = b.finish();
        let vertices = mesh
            .triangles
            .iter()
            .zip(&mesh.triangle_labels)
            .filter(|(_, &l)| l == SemanticClass::Beam as u8)
            .flat_map(|(t, _)| t.map(|i| mesh.positions[i as usize]))
            .collect();
        (added, vertices)
    }

    /// Bulkheads hang from the ceiling against a wall, never below the clearance, and a
    /// window whose head reaches the drawn underside makes that wall's bulkhead shallower
    /// or leaves it out, never cut through.
    #[test]
    fn wall_beams_hang_against_walls_above_openings() {
        let mut total = 0;
        for seed in 0..40u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut layout = Layout::new(6.0, 5.0, 3.2);
            // A tall window on every wall: its head at 2.6 m.
            for k in 0..4 {
                layout.reserve_wall(k, 1.0, 2.5, 0.8, 2.6);
            }
            let (added, beam_vertices) = wall_beam_vertices(&mut rng, &mut layout, seed);
            total += added;
            assert_eq!(beam_vertices.is_empty(), added == 0, "seed {seed}");
            for p in beam_vertices {
                assert!(p.z >= 2.65 - 1e-4 && p.z <= 3.2 + 1e-4, "seed {seed}: beam vertex at {p}");
                let to_wall = p.x.min(6.0 - p.x).min(p.y).min(5.0 - p.y);
                assert!(to_wall <= 0.8 + 1e-4, "seed {seed}: beam vertex {p} is {to_wall} m from every wall");
            }
        }
        assert!(total >= 30, "only {total} bulkheads over 40 seeds");
    }

    /// Without openings in the way a tall office's bulkheads reach down to door-head height
    /// (a metre deep), as the boxed-in ducts of real offices do, and never lower.
    #[test]
    fn wall_beams_reach_door_head_height_in_tall_rooms() {
        let mut lowest = f32::MAX;
        for seed in 0..40u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut layout = Layout::new(6.0, 5.0, 3.1);
            let (_, beam_vertices) = wall_beam_vertices(&mut rng, &mut layout, seed);
            lowest = beam_vertices.iter().fold(lowest, |low, p| low.min(p.z));
        }
        assert!(lowest >= WALL_BEAM_CLEARANCE - 1e-4, "a bulkhead comes down to {lowest} m");
        assert!(lowest < 2.3, "no bulkhead deeper than 0.8 m in 40 rooms 3.1 m high (lowest {lowest} m)");
    }

    /// An open door's leaf stands in the room within reach of its hinge (never beyond the
    /// 0.85 m kept free in front of doors), and everything behind the wall plane is the
    /// space seen through the doorway.
    #[test]
    fn open_doors_swing_into_the_kept_free_floor() {
        for seed in 0..40u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let pal = Palette::draw(&mut rng);
            let width = if seed % 3 == 0 { 1.6 } else { 0.9 };
            let o =
                Opening { wall: 0, s0: 2.0, s1: 2.0 + width, z0: 0.0, z1: 2.1, kind: OpeningKind::Door, recess: 0.05 };
            let mut b = MeshBuilder::new(0.12, seed);
            b.place(Vec3::ZERO, 0.0);
            open_door(&mut b, &o, &mut rng, &pal, 2.8);
            let mesh = b.finish();
            let mut leaf_reach = 0.0f32;
            for (p, &l) in mesh.positions.iter().zip(&mesh.vertex_labels) {
                assert!(p.z >= -1e-4 && p.z <= 2.8 + 1e-4, "seed {seed}: {p}");
                if p.y > 0.03 {
                    // In the room: only the leaf and its handles.
                    assert_eq!(l, SemanticClass::Door.id(), "seed {seed}: {p} in the room is class {l}");
                    assert!(p.y <= 0.85 + 0.1, "seed {seed}: leaf reaches {p}");
                    assert!(p.x >= o.s0 - 0.15 && p.x <= o.s1 + 0.15, "seed {seed}: leaf at {p}");
                    leaf_reach = leaf_reach.max(p.y);
                }
            }
            assert!(leaf_reach > 0.25, "seed {seed}: the leaf does not stand open ({leaf_reach} m)");
        }
    }
}
