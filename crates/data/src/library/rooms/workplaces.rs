//! Recipes for the rooms of an office building: the office (desks with chairs along the
//! walls, a block of facing desks in a big one, bookcases, cabinets, boards), the
//! conference room (tables end to end with chairs all around, a board and a screen at the
//! ends) and the corridor (narrow cabinets and benches along its sides, pictures).

use std::f32::consts::{FRAC_PI_2, PI};

use glam::Vec2;
use rand::Rng;

use super::categories::{
    is_bench, is_bookcase, is_chair, is_desk, is_dresser, is_floor_cabinet, is_office_chair, is_sofa, is_table, is_tv,
};
use super::pieces::{rot, yaw_facing, Proc};
use super::placement::ALL_WALLS;
use super::{Home, ModelSource};
use crate::synth::palette::uniform;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    pub(super) fn office(&mut self) {
        let (w, d) = (self.layout.width, self.layout.depth);
        let n = ((w + d) / 3.0) as usize + self.rng.random_range(0..=1);
        for _ in 0..n {
            self.desk_with_chair(&ALL_WALLS, true);
        }
        // A block of two desks face to face in the middle of a big office.
        if w.min(d) >= 5.0 && self.rng.random_bool(0.6) {
            if let Some(desk) = self.piece(|m| is_desk(m) && m.size.z <= 0.9) {
                let yaw = if w >= d { 0.0 } else { FRAC_PI_2 };
                let c = Vec2::new(w, d) * 0.5
                    + Vec2::new(uniform(&mut self.rng, -0.5, 0.5), uniform(&mut self.rng, -0.5, 0.5));
                let off = rot(Vec2::new(0.0, desk.size.y * 0.5 + 0.01), yaw);
                let chair = self.piece(is_office_chair).or_else(|| self.piece(is_chair));
                for (sign, y) in [(1.0f32, yaw + PI), (-1.0, yaw)] {
                    // Each desk's back towards the other.
                    if let Some(pl) = self.free_piece_at(&desk, c + off * sign, y, 1.0, 0.0) {
                        let n = self.rng.random_range(1..=3);
                        self.on_top(&pl, n);
                        if let Some(ch) = &chair {
                            let front = rot(Vec2::new(0.0, -1.0), y);
                            let cc = pl.center + front * (pl.size.y * 0.5 + 0.15 + ch.size.y * 0.5);
                            let cy = yaw_facing(-front) + uniform(&mut self.rng, -0.3, 0.3);
                            self.free_piece_at(ch, cc, cy, 1.0, 0.0);
                        }
                    }
                }
            }
        }
        let n = self.rng.random_range(1..=3);
        self.bookcases(n, &ALL_WALLS, 0.5);
        for _ in 0..self.rng.random_range(0..=2) {
            let p = self.piece(is_floor_cabinet).unwrap_or_else(|| self.proc_piece(Proc::Cabinet));
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.4, 30) {
                if pl.top < 1.3 {
                    self.on_top(&pl, 2);
                }
            }
        }
        let n = self.rng.random_range(1..=2);
        self.boards(n, &ALL_WALLS);
        if self.rng.random_bool(0.4) {
            if let Some(p) = self.piece(is_sofa) {
                self.wall_piece(&p, &ALL_WALLS, 0.05, 0.0, 30);
            }
        }
        for _ in 0..self.rng.random_range(1..=3) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=2);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.pictures(n);
    }

    pub(super) fn conference(&mut self) {
        let (w, d) = (self.layout.width, self.layout.depth);
        let along_x = w >= d;
        let (long, short) = (w.max(d), w.min(d));
        let yaw = if along_x { 0.0 } else { FRAC_PI_2 };
        let c = Vec2::new(w, d) * 0.5 + Vec2::new(uniform(&mut self.rng, -0.2, 0.2), uniform(&mut self.rng, -0.2, 0.2));
        let table = self
            .piece(|m| is_table(m) && m.size.x >= 1.2 && m.size.y <= short - 2.4 && m.size.x <= long - 2.6)
            .unwrap_or_else(|| self.proc_piece(Proc::Table));
        // Tables end to end make the long table.
        let n = ((long - 2.8) / table.size.x).round().clamp(1.0, 3.0) as usize;
        let chair = match self.piece(is_chair) {
            Some(c) => c,
            None => {
                let swivel = self.rng.random_bool(0.5);
                let s = self.chair_style(swivel);
                self.proc_piece(s)
            }
        };
        let dir = rot(Vec2::X, yaw);
        let mut tables = Vec::new();
        for i in 0..n {
            let off = (i as f32 - (n as f32 - 1.0) * 0.5) * (table.size.x + 0.005);
            if let Some(t) = self.free_piece_at(&table, c + dir * off, yaw, 1.0, 0.0) {
                tables.push(t);
            }
        }
        let count = tables.len();
        for t in &tables {
            let ends = count == 1 && self.rng.random_bool(0.7);
            self.chairs_around(t, &chair, ends, true, 8);
            let n = self.rng.random_range(0..=3);
            self.on_top(t, n);
        }
        let ends = self.short_walls();
        self.boards(1, &ends);
        if self.rng.random_bool(0.4) {
            if let Some(tv) = self.piece(|m| is_tv(m) && m.elevation >= 0.5) {
                self.wall_hang(&tv, &ends, None, 20);
            }
        }
        let sides = self.long_walls();
        for _ in 0..self.rng.random_range(1..=2) {
            let p = self
                .piece(|m| is_floor_cabinet(m) && m.size.y <= 0.6)
                .unwrap_or_else(|| self.proc_piece(Proc::Cabinet));
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30) {
                if pl.top < 1.3 {
                    self.on_top(&pl, 2);
                }
            }
        }
        if self.rng.random_bool(0.4) {
            self.bookcases(1, &sides, 0.45);
        }
        for _ in 0..self.rng.random_range(0..=2) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=2);
        self.pictures(n);
    }

    pub(super) fn corridor(&mut self) {
        let sides = self.long_walls();
        let width = self.layout.width.min(self.layout.depth);
        let max_d = (width - 1.0).min(0.5);
        for _ in 0..self.rng.random_range(1..=3) {
            let p = self.piece(|m| (is_floor_cabinet(m) || is_dresser(m) || is_bookcase(m)) && m.size.y <= max_d);
            if let Some(p) = p {
                if let Some(pl) = self.wall_piece(&p, &sides, 0.0, 0.0, 30) {
                    if pl.top < 1.3 {
                        self.on_top(&pl, 2);
                    }
                }
            }
        }
        if self.rng.random_bool(0.6) {
            if let Some(p) = self.piece(|m| is_bench(m) && m.size.y <= max_d) {
                self.wall_piece(&p, &sides, 0.02, 0.0, 30);
            }
        }
        if self.rng.random_bool(0.5) {
            let ends = self.short_walls();
            self.floor_plant(&ends);
        }
        if self.rng.random_bool(0.4) {
            self.boards(1, &sides);
        }
        let n = self.rng.random_range(1..=3);
        self.pictures(n);
    }
}
