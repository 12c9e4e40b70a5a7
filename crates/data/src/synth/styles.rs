//! Per-style furnishing recipes (office, conference room, lounge, hallway, and the
//! held-out classroom) on top of the occupancy bookkeeping of [`layout`](super::layout):
//! which pieces go where (desks against walls with their chairs, a conference table with
//! chairs all around, sofas facing a coffee table, benches and notice boards along a
//! corridor, rows of tables facing a board), then a last pass that guarantees every room
//! holds every furniture class.

use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::clutter::{self, FloorItem, WallItem};
use super::furniture::{self, table_height, BoardKind, ChairStyle};
use super::layout::{footprint, Layout, Rect2, WallSlot};
use super::palette::{pick, uniform, Palette};
use super::shapes::MeshBuilder;
use super::shell::{Opening, OpeningKind};
use super::RoomStyle;
use crate::class::SemanticClass;

use std::f32::consts::{FRAC_PI_2, PI};

/// Everything a recipe needs: the mesh being built, the occupancy, the RNG, the colours.
pub(crate) struct Furnisher<'a> {
    pub(crate) b: &'a mut MeshBuilder,
    pub(crate) layout: &'a mut Layout,
    pub(crate) rng: &'a mut ChaCha8Rng,
    pub(crate) pal: &'a Palette,
    /// The chairs at the desks of this room, once drawn (most offices match).
    pub(crate) desk_chairs: Option<ChairStyle>,
}

const ALL_WALLS: [usize; 4] = [0, 1, 2, 3];

impl Furnisher<'_> {
    /// Furnishes the room in `style`, then fills in any furniture class still missing.
    pub(crate) fn furnish(&mut self, style: RoomStyle, openings: &[Opening]) {
        self.radiators(openings);
        match style {
            RoomStyle::Office => self.office(),
            RoomStyle::Conference => self.conference(),
            RoomStyle::Lounge => self.lounge(),
            RoomStyle::Hallway => self.hallway(),
            RoomStyle::Classroom => self.classroom(openings),
        }
        self.ensure_classes();
    }

    fn long_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [0, 2]
        } else {
            [1, 3]
        }
    }

    fn short_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [1, 3]
        } else {
            [0, 2]
        }
    }

    fn has(&self, class: SemanticClass) -> bool {
        self.b.mesh.triangle_labels.contains(&class.id())
    }

    fn office(&mut self) {
        if let Some((slot, depth)) = self.sofa_on_wall(&ALL_WALLS, 1.4, 2.0) {
            if self.rng.random_bool(0.5) {
                self.coffee_table(&slot, depth);
            }
        }
        let n_desks = ((self.layout.width + self.layout.depth) / 3.5) as usize + self.rng.random_range(0..=1);
        for _ in 0..n_desks {
            let w = uniform(self.rng, 1.2, 1.8);
            let d = uniform(self.rng, 0.6, 0.8);
            self.desk_with_chair(&ALL_WALLS, w, d);
        }
        for _ in 0..self.rng.random_range(1..=3) {
            let (w, d, h) = (uniform(self.rng, 0.8, 1.2), uniform(self.rng, 0.3, 0.4), uniform(self.rng, 1.6, 2.1));
            self.bookcase(&ALL_WALLS, w, d, h, 40);
        }
        let n = self.rng.random_range(1..=2);
        self.boards(&ALL_WALLS, n, 1.0, 2.0);
        if self.rng.random_bool(0.5) {
            let r = uniform(self.rng, 0.4, 0.55);
            self.free_table(r * 2.0, r * 2.0, true, 0.5, false);
        }
        let n = self.rng.random_range(3..=7);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.wall_clutter(n, &[WallItem::Picture, WallItem::Clock]);
    }

    fn conference(&mut self) {
        let (long, short) = (self.layout.width.max(self.layout.depth), self.layout.width.min(self.layout.depth));
        let along_x = self.layout.width >= self.layout.depth;
        let tw = uniform(self.rng, 2.4, 4.5).min(long - 2.8).max(1.4);
        let td = uniform(self.rng, 1.0, 1.4).min(short - 2.6).max(0.8);
        let yaw = if along_x { 0.0 } else { FRAC_PI_2 };
        let c = Vec2::new(self.layout.width, self.layout.depth) * 0.5
            + Vec2::new(uniform(self.rng, -0.3, 0.3), uniform(self.rng, -0.2, 0.2));
        if !self.table_with_chairs(c, tw, td, yaw, false, true) {
            self.free_table(tw * 0.7, td, false, 0.65, true);
        }
        let ends = self.short_walls();
        self.boards(&ends, 1, 1.5, 2.6);
        if self.rng.random_bool(0.5) {
            let (w, h) = (uniform(self.rng, 1.0, 1.6), uniform(self.rng, 0.6, 0.9));
            self.wall_item(&ends, WallItem::Screen, w, h, 1.1, 1.9);
        }
        let sides = self.long_walls();
        self.sofa_on_wall(&sides, 1.4, 2.2);
        let (w, d, h) = (uniform(self.rng, 0.8, 1.4), uniform(self.rng, 0.35, 0.45), uniform(self.rng, 0.8, 2.0));
        self.bookcase(&ALL_WALLS, w, d, h, 40);
        // A credenza (side table) with things on it.
        let (w, d) = (uniform(self.rng, 1.2, 2.0), uniform(self.rng, 0.4, 0.5));
        let h = table_height(self.rng);
        self.wall_table(&sides, w, d, h, false);
        let n = self.rng.random_range(2..=5);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.wall_clutter(n, &[WallItem::Picture, WallItem::Clock]);
    }

    fn lounge(&mut self) {
        if let Some((slot, depth)) = self.sofa_on_wall(&ALL_WALLS, 1.8, 2.6) {
            if let Some((c, w, yaw)) = self.coffee_table(&slot, depth) {
                // Armchairs on both sides of the coffee table, turned towards it.
                let dir = Vec2::from_angle(yaw);
                for side in [-1.0f32, 1.0] {
                    if self.rng.random_bool(0.7) {
                        let aw = uniform(self.rng, 0.75, 0.95);
                        let ad = uniform(self.rng, 0.75, 0.9);
                        let center = c + dir * side * (w * 0.5 + 0.35 + ad * 0.5);
                        let chair_yaw = yaw - side * FRAC_PI_2;
                        self.free_sofa_at(center, aw, ad, chair_yaw);
                    }
                }
            }
        }
        if self.rng.random_bool(0.6) {
            self.sofa_on_wall(&ALL_WALLS, 1.4, 2.2);
        }
        for _ in 0..self.rng.random_range(1..=3) {
            let (w, d, h) = (uniform(self.rng, 0.7, 1.2), uniform(self.rng, 0.3, 0.4), uniform(self.rng, 1.0, 2.0));
            self.bookcase(&ALL_WALLS, w, d, h, 40);
        }
        // A dining or games table with chairs.
        let round = self.rng.random_bool(0.5);
        let (w, d) = if round {
            let r = uniform(self.rng, 0.45, 0.6);
            (r * 2.0, r * 2.0)
        } else {
            (uniform(self.rng, 1.2, 1.8), uniform(self.rng, 0.8, 0.9))
        };
        self.free_table(w, d, round, 0.6, true);
        self.boards(&ALL_WALLS, 1, 0.8, 1.6);
        for _ in 0..self.rng.random_range(1..=2) {
            self.floor_item(FloorItem::Lamp);
        }
        for _ in 0..self.rng.random_range(1..=3) {
            self.floor_item(FloorItem::Plant);
        }
        let n = self.rng.random_range(1..=4);
        self.floor_clutter(n);
        let n = self.rng.random_range(1..=3);
        self.wall_clutter(n, &[WallItem::Picture, WallItem::Picture, WallItem::Clock]);
    }

    fn hallway(&mut self) {
        let sides = self.long_walls();
        let width = self.layout.width.min(self.layout.depth);
        for _ in 0..self.rng.random_range(1..=2) {
            let d = uniform(self.rng, 0.55, 0.7).min(width - 1.3);
            let w = uniform(self.rng, 1.2, 2.0);
            if let Some(slot) = self.layout.wall_slot(self.rng, &sides, w, d, 0.02, 0.85, 40) {
                self.layout.take_wall_slot(&slot, w, d, 0.85);
                self.b.place_on_floor(slot.center, slot.yaw);
                furniture::sofa(self.b, self.rng, self.pal, w, d);
            }
        }
        for _ in 0..self.rng.random_range(1..=2) {
            let (w, d, h) = (uniform(self.rng, 0.7, 1.1), uniform(self.rng, 0.28, 0.36), uniform(self.rng, 1.0, 2.0));
            self.bookcase(&sides, w, d, h, 40);
        }
        let (w, d) = (uniform(self.rng, 0.8, 1.4), uniform(self.rng, 0.35, 0.5));
        let h = table_height(self.rng);
        self.wall_table(&sides, w, d, h, true);
        let n = self.rng.random_range(1..=2);
        self.boards(&sides, n, 0.8, 1.6);
        let n = self.rng.random_range(2..=5);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.wall_clutter(n, &[WallItem::Picture, WallItem::Clock]);
    }

    /// A classroom: a board centred on one short (front) wall, the teacher's desk between it
    /// and the class, rows of matching student tables with their chairs facing the board,
    /// bookcases and a reading corner at the back, notice board, posters, clutter. The
    /// windows are along one long wall (see `shell::plan_openings`).
    fn classroom(&mut self, openings: &[Opening]) {
        let short = self.short_walls();
        let [front, back] = if self.rng.random_bool(0.5) { short } else { [short[1], short[0]] };
        let fw = self.layout.walls[front];
        let len = fw.length;
        // Distance from the front wall to the back wall.
        let room_len = self.layout.walls[(front + 1) % 4].length;

        // The board, as near the middle of the front wall as the wall allows.
        let bw = uniform(self.rng, 2.4, 4.0).min(len - 1.0);
        let kind = pick(self.rng, &[BoardKind::White, BoardKind::White, BoardKind::Black]);
        let z0 = uniform(self.rng, 0.85, 0.95);
        let z1 = (z0 + uniform(self.rng, 1.0, 1.2)).min(2.15);
        // Centre, then 0.2 m steps out to alternate sides.
        let offsets = (0..16).map(|i| (i / 2) as f32 * 0.2 * if i % 2 == 0 { 1.0 } else { -1.0 });
        let centred = offsets.map(|o| len * 0.5 + o).find(|&s| {
            let (s0, s1) = (s - bw * 0.5, s + bw * 0.5);
            s0 >= 0.2 && s1 <= len - 0.2 && self.layout.wall_free(front, s0, s1, z0 - 0.05, z1 + 0.05, 0.1)
        });
        match centred {
            Some(s) => self.build_on_wall(front, s, bw, z0, z1, |f, s0, s1| {
                furniture::board(f.b, f.rng, f.pal, s0, s1, z0, z1, kind);
            }),
            None => {
                self.boards(&[front], 1, 1.5, 2.5);
            }
        }
        // A clock above the board when the ceiling leaves room for it.
        if self.layout.height - z1 > 0.6 && self.rng.random_bool(0.6) {
            self.wall_item(&[front], WallItem::Clock, 0.3, 0.3, z1 + 0.12, self.layout.height - 0.15);
        }

        // The teacher's desk, off-centre in front of the board, its user side (and chair)
        // towards the board so that the teacher faces the class.
        let (dw, dd) = (uniform(self.rng, 1.2, 1.6), uniform(self.rng, 0.65, 0.8));
        let dh = table_height(self.rng);
        let swivel = self.rng.random_bool(0.6);
        let teacher = ChairStyle::draw(self.rng, self.pal, swivel);
        let gap = uniform(self.rng, 0.08, 0.2);
        let desk_t = 0.25 + teacher.size + gap + dd * 0.5;
        let desk_yaw = fw.yaw + PI;
        let side = if self.rng.random_bool(0.5) { 1.0 } else { -1.0 };
        for _ in 0..12 {
            let s = len * 0.5 + side * uniform(self.rng, 0.1, 0.3) * len;
            let (center, chair) = (fw.point(s, desk_t), fw.point(s, desk_t - dd * 0.5 - gap - teacher.size * 0.5));
            let r = footprint(center, dw, dd, desk_yaw);
            if self.layout.floor_free(&r) && self.layout.floor_free(&footprint(chair, teacher.size, teacher.size, 0.0))
            {
                self.layout.add_obstacle(r);
                self.layout.interest.push(center.extend(dh));
                self.b.place_on_floor(center, desk_yaw);
                furniture::desk(self.b, self.rng, self.pal, dw, dd, dh);
                let workstation = self.rng.random_bool(0.5);
                clutter::table_items(self.b, self.rng, self.pal, dw, dd, dh, workstation);
                let yaw = fw.yaw + uniform(self.rng, -0.3, 0.3);
                self.chair_at(chair, yaw, &teacher);
                break;
            }
        }

        // Rows of student tables (single desks or two-seat tables), all alike, each with
        // its chairs behind it facing the board; aisles between the columns.
        let pairs = self.rng.random_bool(0.6);
        let (tw, seats) = if pairs { (uniform(self.rng, 1.1, 1.4), 2) } else { (uniform(self.rng, 0.6, 0.75), 1) };
        let td = uniform(self.rng, 0.5, 0.6);
        let th = table_height(self.rng);
        let student = ChairStyle::draw(self.rng, self.pal, false);
        let cs = student.size;
        // Far enough from the table that the footprints, turned a little, stay apart.
        let chair_gap = uniform(self.rng, 0.1, 0.18);
        let row_gap = uniform(self.rng, 0.25, 0.4);
        let pitch = td + chair_gap + cs + row_gap;
        let first = desk_t + dd * 0.5 + uniform(self.rng, 0.55, 0.8);
        let last = room_len - uniform(self.rng, 0.8, 1.1);
        let rows = ((last - first + row_gap) / pitch).floor().max(1.0) as usize;
        let margin = uniform(self.rng, 0.6, 0.85);
        let aisle = uniform(self.rng, 0.5, 0.75);
        let cols = (((len - 2.0 * margin + aisle) / (tw + aisle)).floor() as usize).max(1);
        let block = cols as f32 * tw + (cols - 1) as f32 * aisle;
        let slack = ((len - 2.0 * margin - block) * 0.5).max(0.0);
        let s_first = (len - block) * 0.5 + uniform(self.rng, -slack, slack) + tw * 0.5;
        // Matching tables: every one is built from the same draws, of a generator of its own.
        let table_seed: u64 = self.rng.random();
        for row in 0..rows {
            let t = first + row as f32 * pitch + td * 0.5;
            for col in 0..cols {
                let s = s_first + col as f32 * (tw + aisle);
                let center = fw.point(s, t);
                let r = footprint(center, tw, td, desk_yaw);
                if !self.layout.floor_free(&r) {
                    continue;
                }
                self.layout.add_obstacle(r);
                self.layout.interest.push(center.extend(th));
                self.b.place_on_floor(center, desk_yaw);
                furniture::table(self.b, &mut ChaCha8Rng::seed_from_u64(table_seed), self.pal, tw, td, th);
                if self.rng.random_bool(0.5) {
                    clutter::table_items(self.b, self.rng, self.pal, tw, td, th, false);
                }
                for seat in 0..seats {
                    if self.rng.random_bool(0.08) {
                        continue;
                    }
                    let x = s - tw * 0.5 + (seat as f32 + 0.5) * tw / seats as f32;
                    let chair = fw.point(x, t + td * 0.5 + chair_gap + cs * 0.5);
                    let yaw = desk_yaw + uniform(self.rng, -0.12, 0.12);
                    self.chair_at(chair, yaw, &student);
                }
            }
        }

        // The back: bookcases, a reading corner, a notice board; the long wall without
        // windows gets some too.
        let windows: Vec<usize> = openings.iter().filter(|o| o.kind == OpeningKind::Window).map(|o| o.wall).collect();
        let inner = self.long_walls().into_iter().find(|k| !windows.contains(k)).unwrap_or(back);
        for _ in 0..self.rng.random_range(1..=3) {
            let (w, d, h) = (uniform(self.rng, 0.8, 1.2), uniform(self.rng, 0.3, 0.4), uniform(self.rng, 1.0, 2.0));
            self.bookcase(&[back, back, inner], w, d, h, 40);
        }
        if self.rng.random_bool(0.6) {
            self.sofa_on_wall(&[back], 1.2, 1.8);
        }
        self.boards(&[back, inner], 1, 0.8, 1.6);
        let n = self.rng.random_range(1..=3);
        self.wall_clutter(n, &[WallItem::Picture, WallItem::Picture, WallItem::Clock]);
        self.floor_item(FloorItem::Bin);
        if self.rng.random_bool(0.5) {
            self.floor_item(FloorItem::Plant);
        }
        let n = self.rng.random_range(1..=3);
        self.floor_clutter(n);
    }

    /// Radiators under some windows (clutter).
    fn radiators(&mut self, openings: &[Opening]) {
        for o in openings.iter().filter(|o| o.kind == OpeningKind::Window) {
            if !self.rng.random_bool(0.5) || o.z0 < 0.5 {
                continue;
            }
            let wall = self.layout.walls[o.wall];
            let (s0, s1) = (o.s0 + 0.05, o.s1 - 0.05);
            let r = footprint(wall.point((s0 + s1) * 0.5, 0.07), s1 - s0, 0.14, wall.yaw);
            if !self.layout.floor_free(&r) {
                continue;
            }
            self.b.place(wall.start.extend(0.0), wall.yaw);
            let z1 = o.z0 - uniform(self.rng, 0.12, 0.2);
            clutter::radiator(self.b, self.rng, s0, s1, 0.12, z1);
            self.layout.reserve_wall(o.wall, s0, s1, 0.0, o.z0);
            self.layout.add_obstacle(r);
        }
    }

    /// A desk against a wall with a chair pulled out in front of it and a workstation on top.
    fn desk_with_chair(&mut self, walls: &[usize], w: f32, d: f32) -> bool {
        let h = table_height(self.rng);
        let Some(slot) = self.layout.wall_slot(self.rng, walls, w, d, 0.01, h, 30) else {
            return false;
        };
        self.layout.take_wall_slot(&slot, w, d, h);
        self.b.place_on_floor(slot.center, slot.yaw);
        furniture::desk(self.b, self.rng, self.pal, w, d, h);
        clutter::table_items(self.b, self.rng, self.pal, w, d, h, true);
        let style = match self.desk_chairs {
            Some(style) if self.rng.random_bool(0.8) => style,
            _ => {
                let swivel = self.rng.random_bool(0.7);
                let style = ChairStyle::draw(self.rng, self.pal, swivel);
                self.desk_chairs.get_or_insert(style);
                style
            }
        };
        let cs = style.size;
        let normal = self.layout.walls[slot.wall].normal;
        let along = self.layout.walls[slot.wall].dir;
        let center = slot.center
            + normal * (d * 0.5 + uniform(self.rng, 0.06, 0.25) + cs * 0.5)
            + along * uniform(self.rng, -0.15, 0.15) * w;
        let yaw = slot.yaw + PI + uniform(self.rng, -0.35, 0.35);
        self.chair_at(center, yaw, &style);
        true
    }

    /// A chair of `size` x `size` at `center` turned by `yaw`, if the floor is free there.
    fn chair_at(&mut self, center: Vec2, yaw: f32, style: &ChairStyle) -> bool {
        let r = footprint(center, style.size, style.size, yaw);
        if !self.layout.floor_free(&r) {
            return false;
        }
        self.layout.add_obstacle(r);
        self.layout.interest.push(center.extend(0.5));
        self.b.place_on_floor(center, yaw);
        furniture::chair(self.b, self.rng, style);
        true
    }

    fn bookcase(&mut self, walls: &[usize], w: f32, d: f32, h: f32, tries: usize) -> bool {
        let Some(slot) = self.layout.wall_slot(self.rng, walls, w, d, 0.01, h, tries) else {
            return false;
        };
        self.layout.take_wall_slot(&slot, w, d, h);
        self.b.place_on_floor(slot.center, slot.yaw);
        furniture::bookcase(self.b, self.rng, self.pal, w, d, h);
        true
    }

    /// A sofa against a wall; returns its slot and depth.
    fn sofa_on_wall(&mut self, walls: &[usize], min_w: f32, max_w: f32) -> Option<(WallSlot, f32)> {
        let w = uniform(self.rng, min_w, max_w);
        let d = uniform(self.rng, 0.8, 0.95);
        let slot = self.layout.wall_slot(self.rng, walls, w, d, 0.03, 0.9, 40)?;
        self.layout.take_wall_slot(&slot, w, d, 0.9);
        self.b.place_on_floor(slot.center, slot.yaw);
        furniture::sofa(self.b, self.rng, self.pal, w, d);
        Some((slot, d))
    }

    fn free_sofa_at(&mut self, center: Vec2, w: f32, d: f32, yaw: f32) -> bool {
        let r = footprint(center, w, d, yaw);
        if !self.layout.floor_free(&r) {
            return false;
        }
        self.layout.add_obstacle(r);
        self.layout.interest.push(center.extend(0.45));
        self.b.place_on_floor(center, yaw);
        furniture::sofa(self.b, self.rng, self.pal, w, d);
        true
    }

    /// A low table in front of a sofa; returns its centre, width and yaw.
    fn coffee_table(&mut self, sofa: &WallSlot, sofa_depth: f32) -> Option<(Vec2, f32, f32)> {
        let wall = self.layout.walls[sofa.wall];
        let (w, d) = (uniform(self.rng, 0.8, 1.3), uniform(self.rng, 0.5, 0.7));
        let c = sofa.center + wall.normal * (sofa_depth * 0.5 + uniform(self.rng, 0.3, 0.45) + d * 0.5);
        let r = footprint(c, w, d, sofa.yaw);
        if !self.layout.floor_free(&r) {
            return None;
        }
        self.layout.add_obstacle(r);
        let h = uniform(self.rng, 0.38, 0.48);
        self.layout.interest.push(c.extend(h));
        self.b.place_on_floor(c, sofa.yaw);
        furniture::table(self.b, self.rng, self.pal, w, d, h);
        clutter::table_items(self.b, self.rng, self.pal, w, d, h, false);
        Some((c, w, sofa.yaw))
    }

    /// A table against a wall (credenza, console) with things on it, and optionally a
    /// chair beside it against the wall.
    fn wall_table(&mut self, walls: &[usize], w: f32, d: f32, h: f32, chair: bool) -> bool {
        let Some(slot) = self.layout.wall_slot(self.rng, walls, w, d, 0.01, h, 40) else {
            return false;
        };
        self.layout.take_wall_slot(&slot, w, d, h);
        self.b.place_on_floor(slot.center, slot.yaw);
        furniture::table(self.b, self.rng, self.pal, w, d, h);
        clutter::table_items(self.b, self.rng, self.pal, w, d, h, false);
        if chair {
            let style = ChairStyle::draw(self.rng, self.pal, false);
            let cs = style.size;
            for side in [1.0f32, -1.0] {
                let s = slot.s + side * (w * 0.5 + 0.1 + cs * 0.5);
                if let Some(cslot) = self.layout.wall_slot_at(slot.wall, s, cs, cs, 0.03, 1.0) {
                    self.layout.take_wall_slot(&cslot, cs, cs, 1.0);
                    self.b.place_on_floor(cslot.center, cslot.yaw);
                    furniture::chair(self.b, self.rng, &style);
                    break;
                }
            }
        }
        true
    }

    /// A table at `center` (local x along `yaw`) with chairs around it where they fit.
    fn table_with_chairs(&mut self, center: Vec2, w: f32, d: f32, yaw: f32, round: bool, ends: bool) -> bool {
        let r = footprint(center, w, d, yaw);
        let grown = Rect2::new(r.min - Vec2::splat(0.2), r.max + Vec2::splat(0.2));
        if !self.layout.floor_free(&r) || self.layout.obstacles.iter().any(|o| o.overlaps(&grown, 0.0)) {
            return false;
        }
        self.layout.add_obstacle(r);
        let h = table_height(self.rng);
        self.layout.interest.push(center.extend(h));
        self.b.place_on_floor(center, yaw);
        if round {
            furniture::round_table(self.b, self.rng, self.pal, w * 0.5, h);
        } else {
            furniture::table(self.b, self.rng, self.pal, w, d, h);
        }
        // Items on a round top stay inside its inscribed square.
        let (iw, id) = if round { (w * 0.7, d * 0.7) } else { (w, d) };
        clutter::table_items(self.b, self.rng, self.pal, iw, id, h, false);
        let swivel = self.rng.random_bool(0.5);
        let style = ChairStyle::draw(self.rng, self.pal, swivel);
        let cs = style.size;
        let gap = uniform(self.rng, 0.05, 0.2);
        let (dir, normal) = (Vec2::from_angle(yaw), Vec2::from_angle(yaw + FRAC_PI_2));
        let mut seats: Vec<(Vec2, f32)> = Vec::new();
        let per_side = (((w - 0.1) / (cs + 0.15)).floor() as usize).max(1);
        for side in [-1.0f32, 1.0] {
            for i in 0..per_side {
                let x = -w * 0.5 + (i as f32 + 0.5) * w / per_side as f32;
                let p = center + dir * x + normal * side * (d * 0.5 + gap + cs * 0.5);
                // Chair front (+y) faces the table.
                let chair_yaw = if side > 0.0 { yaw + PI } else { yaw };
                seats.push((p, chair_yaw));
            }
            if ends {
                let p = center + dir * side * (w * 0.5 + gap + cs * 0.5);
                seats.push((p, yaw + side * FRAC_PI_2));
            }
        }
        for (p, chair_yaw) in seats {
            let jitter = uniform(self.rng, -0.15, 0.15);
            self.chair_at(p, chair_yaw + jitter, &style);
        }
        true
    }

    /// A free-standing table somewhere in the room with chairs around it.
    fn free_table(&mut self, w: f32, d: f32, round: bool, clearance: f32, ends: bool) -> bool {
        let yaw = if round || self.rng.random_bool(0.5) { 0.0 } else { FRAC_PI_2 };
        let floor = self.layout.floor();
        let Some(c) = self.layout.free_slot(self.rng, floor, w, d, yaw, clearance, 60) else {
            return false;
        };
        self.table_with_chairs(c, w, d, yaw, round, ends)
    }

    /// Up to `n` boards on `walls`, `min_w..max_w` wide.
    fn boards(&mut self, walls: &[usize], n: usize, min_w: f32, max_w: f32) -> usize {
        let mut placed = 0;
        for _ in 0..n {
            let kind = pick(self.rng, &[BoardKind::White, BoardKind::White, BoardKind::Black, BoardKind::Cork]);
            let w = uniform(self.rng, min_w, max_w);
            let z0 = uniform(self.rng, 0.85, 1.0);
            let z1 = (z0 + uniform(self.rng, 0.6, 1.2)).min(2.15);
            if self.wall_piece(walls, w, z0, z1, 40, |f, s0, s1| {
                furniture::board(f.b, f.rng, f.pal, s0, s1, z0, z1, kind);
            }) {
                placed += 1;
            }
        }
        placed
    }

    /// Finds `width` of free wall between `z0` and `z1` on one of `walls` and builds there
    /// (in the wall frame) with `build(self, s0, s1)`.
    fn wall_piece(
        &mut self,
        walls: &[usize],
        width: f32,
        z0: f32,
        z1: f32,
        tries: usize,
        build: impl FnOnce(&mut Self, f32, f32),
    ) -> bool {
        for _ in 0..tries {
            let k = walls[self.rng.random_range(0..walls.len())];
            let len = self.layout.walls[k].length;
            let w = width.min(len - 0.4);
            if w < 0.3 {
                continue;
            }
            let s = uniform(self.rng, 0.2 + w * 0.5, len - 0.2 - w * 0.5);
            let (s0, s1) = (s - w * 0.5, s + w * 0.5);
            if self.layout.wall_free(k, s0, s1, z0 - 0.05, z1 + 0.05, 0.1) {
                self.build_on_wall(k, s, w, z0, z1, build);
                return true;
            }
        }
        false
    }

    /// Takes `width` of wall `k` centred at `s`, `z0..z1` high (checked free by the
    /// caller), and builds there with `build(self, s0, s1)` in the wall frame.
    fn build_on_wall(
        &mut self,
        k: usize,
        s: f32,
        width: f32,
        z0: f32,
        z1: f32,
        build: impl FnOnce(&mut Self, f32, f32),
    ) {
        let (s0, s1) = (s - width * 0.5, s + width * 0.5);
        self.layout.reserve_wall(k, s0, s1, z0 - 0.05, z1 + 0.05);
        let wall = self.layout.walls[k];
        self.layout.interest.push(wall.point(s, 0.05).extend((z0 + z1) * 0.5));
        self.b.place(wall.start.extend(0.0), wall.yaw);
        build(self, s0, s1);
    }

    fn wall_item(&mut self, walls: &[usize], kind: WallItem, w: f32, h: f32, zmin: f32, zmax: f32) -> bool {
        let zc = uniform(self.rng, zmin + h * 0.5, (zmax - h * 0.5).max(zmin + h * 0.5));
        self.wall_piece(walls, w, zc - h * 0.5, zc + h * 0.5, 30, |f, s0, s1| {
            clutter::wall_item(f.b, f.rng, f.pal, kind, (s0 + s1) * 0.5, zc, s1 - s0, h);
        })
    }

    fn wall_clutter(&mut self, n: usize, kinds: &[WallItem]) {
        for _ in 0..n {
            let kind = pick(self.rng, kinds);
            let (w, h) = match kind {
                WallItem::Clock => (0.3, 0.3),
                _ => (uniform(self.rng, 0.4, 1.0), uniform(self.rng, 0.3, 0.7)),
            };
            self.wall_item(&ALL_WALLS, kind, w, h, 1.2, 2.1);
        }
    }

    fn floor_clutter(&mut self, n: usize) {
        for _ in 0..n {
            let kind = pick(
                self.rng,
                &[
                    FloorItem::Boxes,
                    FloorItem::Bin,
                    FloorItem::Plant,
                    FloorItem::Cabinet,
                    FloorItem::Bin,
                    FloorItem::Boxes,
                ],
            );
            self.floor_item(kind);
        }
    }

    /// A floor clutter item, against a wall when possible, else anywhere free.
    fn floor_item(&mut self, kind: FloorItem) -> bool {
        let (w, d, h) = kind.size(self.rng);
        let z_top = if h > 0.0 { h } else { 1.2 };
        if let Some(slot) = self.layout.wall_slot(self.rng, &ALL_WALLS, w, d, 0.03, z_top, 30) {
            self.layout.take_wall_slot(&slot, w, d, z_top);
            self.b.place_on_floor(slot.center, slot.yaw);
            clutter::floor_item(self.b, self.rng, self.pal, kind, w, d, h);
            return true;
        }
        let floor = self.layout.floor();
        let yaw = uniform(self.rng, 0.0, PI);
        if let Some(c) = self.layout.free_slot(self.rng, floor, w, d, yaw, 0.3, 30) {
            self.layout.add_obstacle(footprint(c, w, d, yaw));
            self.layout.interest.push(c.extend(z_top * 0.5));
            self.b.place_on_floor(c, yaw);
            clutter::floor_item(self.b, self.rng, self.pal, kind, w, d, h);
            return true;
        }
        false
    }

    /// Last pass: whatever furniture class the recipe failed to place is added in a small
    /// size, against any wall or anywhere free.
    fn ensure_classes(&mut self) {
        for attempt in 0..4 {
            let shrink = 1.0 - 0.15 * attempt as f32;
            if !self.has(SemanticClass::Table) {
                let (w, d) = (0.9 * shrink, 0.5 * shrink);
                let h = table_height(self.rng);
                if !self.wall_table(&ALL_WALLS, w, d, h, false) {
                    self.free_table(w, d, false, 0.1, false);
                }
            }
            if !self.has(SemanticClass::Chair) {
                let style = ChairStyle::draw(self.rng, self.pal, false);
                let cs = style.size;
                if let Some(slot) = self.layout.wall_slot(self.rng, &ALL_WALLS, cs, cs, 0.03, 1.0, 60) {
                    self.layout.take_wall_slot(&slot, cs, cs, 1.0);
                    self.b.place_on_floor(slot.center, slot.yaw);
                    furniture::chair(self.b, self.rng, &style);
                }
                let floor = self.layout.floor();
                let yaw = uniform(self.rng, 0.0, std::f32::consts::TAU);
                if !self.has(SemanticClass::Chair) {
                    if let Some(c) = self.layout.free_slot(self.rng, floor, cs, cs, yaw, 0.3, 60) {
                        self.chair_at(c, yaw, &style);
                    }
                }
            }
            if !self.has(SemanticClass::Sofa) {
                let (w, d) = (0.85 * shrink.max(0.85), 0.8 * shrink.max(0.85));
                if let Some(slot) = self.layout.wall_slot(self.rng, &ALL_WALLS, w, d, 0.03, 0.9, 60) {
                    self.layout.take_wall_slot(&slot, w, d, 0.9);
                    self.b.place_on_floor(slot.center, slot.yaw);
                    furniture::sofa(self.b, self.rng, self.pal, w, d);
                }
                let floor = self.layout.floor();
                let yaw = f32::from(self.rng.random_range(0u8..4)) * FRAC_PI_2;
                if !self.has(SemanticClass::Sofa) {
                    if let Some(c) = self.layout.free_slot(self.rng, floor, w, d, yaw, 0.3, 60) {
                        self.free_sofa_at(c, w, d, yaw);
                    }
                }
            }
            if !self.has(SemanticClass::Bookcase) {
                self.bookcase(&ALL_WALLS, 0.8 * shrink, 0.3, 0.9 * shrink.max(0.8), 60);
                if !self.has(SemanticClass::Bookcase) {
                    // A free-standing low shelf.
                    let (w, d, h) = (0.8 * shrink, 0.35, 0.8);
                    let floor = self.layout.floor();
                    let yaw = f32::from(self.rng.random_range(0u8..4)) * FRAC_PI_2;
                    if let Some(c) = self.layout.free_slot(self.rng, floor, w, d, yaw, 0.3, 60) {
                        self.layout.add_obstacle(footprint(c, w, d, yaw));
                        self.layout.interest.push(c.extend(h * 0.5));
                        self.b.place_on_floor(c, yaw);
                        furniture::bookcase(self.b, self.rng, self.pal, w, d, h);
                    }
                }
            }
            if !self.has(SemanticClass::Board) {
                self.boards(&ALL_WALLS, 1, 0.6 * shrink, 0.9 * shrink);
            }
            if !self.has(SemanticClass::Clutter) {
                self.floor_item(FloorItem::Bin);
            }
        }
    }
}
