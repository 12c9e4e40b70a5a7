//! Arrangements the room recipes share: small things on top of a table, counter or shelf,
//! chairs around a table, a dining set, a desk with its chair, bookcases, a rug, a floor
//! plant, a floor lamp, clutter by the walls. Each places what fits and leaves out what
//! does not.

use std::f32::consts::FRAC_PI_2;

use glam::{Vec2, Vec3};
use rand::Rng;

use super::categories::{
    is_bookcase, is_chair, is_desk, is_floor_clutter, is_floor_lamp, is_floor_plant, is_office_chair, is_rug, is_small,
    is_table,
};
use super::pieces::{rot, yaw_facing, Piece, Placed, Proc};
use super::placement::ALL_WALLS;
use super::{Home, ModelSource, MAX_TRIANGLES};
use crate::synth::layout::{footprint, Rect2};
use crate::synth::palette::uniform;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// Small things on the top of `support`: up to `n`, side by side across its width.
    pub(super) fn on_top(&mut self, support: &Placed, n: usize) {
        if n == 0 || support.size.x < 0.25 || support.size.y < 0.2 {
            return;
        }
        let kind = self.kind;
        let (w, d) = (support.size.x * 0.9, support.size.y * 0.85);
        let cell = w / n as f32;
        for i in 0..n {
            if self.b.mesh.triangles.len() > MAX_TRIANGLES * 9 / 10 || self.rng.random_bool(0.2) {
                continue;
            }
            let Some(p) = self.piece(|m| is_small(m, kind)) else { return };
            let ext = p.size.x.max(p.size.y);
            let room = (cell * 0.85).min(d * 0.9);
            let scale = (room / ext).min(1.0).min((self.layout.height - support.top - 0.3) / p.size.z);
            if scale < 0.35 {
                continue;
            }
            let spin = uniform(&mut self.rng, -0.4, 0.4);
            let half = footprint(Vec2::ZERO, p.size.x * scale, p.size.y * scale, spin).max;
            let x = -w * 0.5 + cell * (i as f32 + 0.5);
            let slack_x = (cell * 0.5 - half.x).max(0.0);
            let slack_y = (d * 0.5 - half.y).max(0.0);
            if half.x > cell * 0.5 + 1e-3 || half.y > d * 0.5 + 1e-3 {
                continue;
            }
            let local =
                Vec2::new(x + uniform(&mut self.rng, -slack_x, slack_x), uniform(&mut self.rng, -slack_y, slack_y));
            let c = support.center + rot(local, support.yaw);
            let yaw = support.yaw + spin;
            if self.emit(&p, c, support.top + 0.001, yaw, Vec3::splat(scale)) {
                self.layout.interest.push(c.extend(support.top + p.size.z * scale * 0.5));
            }
        }
    }

    /// Chairs around a table, facing it: along its front (local -y) and, unless the table
    /// stands against a wall (`back` false), its back; at the ends when `ends`.
    pub(super) fn chairs_around(&mut self, table: &Placed, chair: &Piece, ends: bool, back: bool, max: usize) -> usize {
        let (tw, td) = (table.size.x, table.size.y);
        let cs = chair.size;
        let mut seats: Vec<(Vec2, Vec2)> = Vec::new(); // (local position, outward normal)
        let gap = uniform(&mut self.rng, 0.05, 0.2);
        let per_side = ((tw - 0.1) / (cs.x + 0.15)).floor().max(1.0) as usize;
        for side in [-1.0f32, 1.0] {
            if side > 0.0 && !back {
                continue;
            }
            for i in 0..per_side {
                let x = -tw * 0.5 + tw * (i as f32 + 0.5) / per_side as f32;
                seats.push((Vec2::new(x, side * (td * 0.5 + gap + cs.y * 0.5)), Vec2::new(0.0, side)));
            }
        }
        if ends {
            for side in [-1.0f32, 1.0] {
                seats.push((Vec2::new(side * (tw * 0.5 + gap + cs.y * 0.5), 0.0), Vec2::new(side, 0.0)));
            }
        }
        let mut placed = 0;
        for (pos, n) in seats {
            if placed >= max {
                break;
            }
            if self.rng.random_bool(0.1) {
                continue;
            }
            let c = table.center + rot(pos, table.yaw);
            let inward = -rot(n, table.yaw);
            let yaw = yaw_facing(inward) + uniform(&mut self.rng, -0.15, 0.15);
            if self.free_piece_at(chair, c, yaw, 1.0, 0.0).is_some() {
                placed += 1;
            }
        }
        placed
    }

    /// A table free-standing in the room with chairs around it.
    pub(super) fn dining_set(&mut self, region: Rect2, max_chairs: usize, ends: bool) -> Option<Placed> {
        let region_size = region.max - region.min;
        let limit = region_size.min_element() - 1.4;
        let table = self
            .piece(|m| is_table(m) && m.size.y <= limit && m.size.x <= region_size.max_element() - 1.4)
            .unwrap_or_else(|| self.proc_piece(Proc::Table));
        let yaw = if region_size.x >= region_size.y { 0.0 } else { FRAC_PI_2 };
        let yaw = if self.rng.random_bool(0.2) { yaw + FRAC_PI_2 } else { yaw };
        let t = self.free_piece(&table, region, yaw, 0.75, 40)?;
        let chair = match self.piece(is_chair) {
            Some(c) => c,
            None => {
                let s = self.chair_style(false);
                self.proc_piece(s)
            }
        };
        self.chairs_around(&t, &chair, ends, true, max_chairs);
        let n = self.rng.random_range(0..=3);
        self.on_top(&t, n);
        Some(t)
    }

    /// A desk against a wall with a chair in front of it and things on top.
    pub(super) fn desk_with_chair(&mut self, walls: &[usize], office: bool) -> Option<Placed> {
        let desk = self.piece(is_desk).unwrap_or_else(|| self.proc_piece(Proc::Desk));
        let placed = self.wall_piece(&desk, walls, 0.01, 0.0, 40)?;
        let chair =
            if office { self.piece(is_office_chair).or_else(|| self.piece(is_chair)) } else { self.piece(is_chair) };
        let chair = match chair {
            Some(c) => c,
            None => {
                let s = self.chair_style(office);
                self.proc_piece(s)
            }
        };
        let (k, _) = placed.wall.unwrap_or((0, 0.0));
        let wall = self.layout.walls[k];
        let c = placed.center
            + wall.normal * (placed.size.y * 0.5 + uniform(&mut self.rng, 0.05, 0.25) + chair.size.y * 0.5)
            + wall.dir * uniform(&mut self.rng, -0.15, 0.15) * placed.size.x;
        let yaw = yaw_facing(-wall.normal) + uniform(&mut self.rng, -0.35, 0.35);
        self.free_piece_at(&chair, c, yaw, 1.0, 0.0);
        let n = self.rng.random_range(1..=3);
        self.on_top(&placed, n);
        Some(placed)
    }

    pub(super) fn rug(&mut self, center: Vec2, yaw: f32, max: Vec2) {
        let Some(p) = self.piece(is_rug) else { return };
        let scale = (max.x / p.size.x).min(max.y / p.size.y).min(1.1);
        if scale < 0.5 {
            return;
        }
        let fp = footprint(center, p.size.x * scale, p.size.y * scale, yaw);
        if !self.layout.floor().contains(&fp) {
            return;
        }
        self.emit(&p, center, 0.0, yaw, Vec3::new(scale, scale, 1.0));
    }

    pub(super) fn floor_plant(&mut self, walls: &[usize]) {
        let p = self.piece(is_floor_plant).unwrap_or_else(|| self.proc_piece(Proc::Plant));
        self.wall_piece(&p, walls, 0.05, 0.0, 30);
    }

    pub(super) fn floor_lamp(&mut self) {
        let p = self.piece(is_floor_lamp).unwrap_or_else(|| self.proc_piece(Proc::Lamp));
        if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.05, 0.0, 30) {
            self.lights.push(pl.center.extend(pl.z + pl.size.z));
        }
    }

    pub(super) fn bookcases(&mut self, n: usize, walls: &[usize], max_depth: f32) {
        for _ in 0..n {
            let p = self
                .piece(|m| is_bookcase(m) && m.size.y <= max_depth)
                .unwrap_or_else(|| self.proc_piece(Proc::Bookcase));
            if let Some(pl) = self.wall_piece(&p, walls, 0.0, 0.5, 40) {
                if pl.top < 1.5 {
                    let n = self.rng.random_range(1..=3);
                    self.on_top(&pl, n);
                }
            }
        }
    }

    pub(super) fn floor_clutter(&mut self, n: usize) {
        for _ in 0..n {
            let kind = self.kind;
            if let Some(p) = self.piece(|m| is_floor_clutter(m, kind)) {
                self.wall_piece(&p, &ALL_WALLS, 0.03, 0.0, 20);
            }
        }
    }
}
