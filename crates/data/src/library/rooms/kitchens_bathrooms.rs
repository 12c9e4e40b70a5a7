//! Recipes for the rooms built along their plumbing: the kitchen (a row of modules with the
//! fridge, the stove and the sink along one or two walls, upper cabinets and a hood above
//! it, a table with chairs) and the bathroom (toilet, washbasin with a mirror, bathtub or
//! shower, towels). The kitchen row also makes the studio's kitchenette.

use std::f32::consts::FRAC_PI_2;

use glam::{Vec2, Vec3};
use rand::Rng;

use super::categories::{
    is, is_bathtub, is_chair, is_floor_cabinet, is_fridge, is_kitchen_lower, is_kitchen_upper, is_shower, is_table,
    is_toilet, is_towel_rack, is_washbasin, on_floor,
};
use super::pieces::{yaw_facing, Placed, Proc, Src};
use super::placement::ALL_WALLS;
use super::{Home, ModelSource};
use crate::class::SemanticClass;
use crate::synth::layout::footprint;
use crate::synth::palette::{jitter, uniform};
use crate::synth::shapes::SKIP_NEG_Y;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// A row of kitchen modules along wall `k` from `s0` to `s1`, with a fridge at the
    /// start sometimes, upper cabinets above sometimes, things on the counter.
    pub(super) fn kitchen_row(&mut self, k: usize, s0: f32, s1: f32, fridge: bool) -> usize {
        let mut s = s0;
        let mut modules: Vec<Placed> = Vec::new();
        let mut stoves: Vec<Placed> = Vec::new();
        let mut first = true;
        let mut sink = false;
        let mut misses = 0;
        while s < s1 - 0.3 && misses < 12 {
            let room = s1 - s;
            let p = if first && fridge {
                self.piece(|m| is_fridge(m) && m.size.x <= room)
            } else if !sink && self.rng.random_bool(0.35) {
                sink = true;
                self.piece(|m| is_kitchen_lower(m) && is(m, &["sink"]) && m.size.x <= room)
            } else {
                self.piece(|m| is_kitchen_lower(m) && m.size.x <= room)
            };
            first = false;
            let Some(p) = p else {
                misses += 1;
                continue;
            };
            match self.wall_piece_at(&p, k, s + p.size.x * 0.5 + 0.002, 1.0, 0.0, 0.0) {
                Some(pl) => {
                    s += p.size.x + 0.004;
                    if matches!(&p.src, Src::Model { model, .. } if model.fine == "oven") {
                        stoves.push(pl);
                    }
                    if pl.size.z < 1.2 {
                        modules.push(pl);
                    }
                }
                None => {
                    s += 0.1;
                    misses += 1;
                }
            }
        }
        if modules.is_empty() {
            return 0;
        }
        // Keep the floor in front of the row free.
        let wall = self.layout.walls[k];
        let (a, b) = (modules.first().map_or(s0, |m| m.wall.map_or(s0, |w| w.1 - m.size.x * 0.5)), s);
        let depth = modules.iter().map(|m| m.size.y).fold(0.0, f32::max);
        self.layout.add_keepout(footprint(wall.point((a + b) * 0.5, depth + 0.35), (b - a).max(0.1), 0.7, wall.yaw));
        // A hood above the first stove.
        if let Some(st) = stoves.first().copied() {
            if let (Some(hood), Some((_, hs))) = (self.piece(|m| is(m, &["range_hood"]) && m.size.y <= 0.6), st.wall) {
                let z = if hood.elevation >= 1.4 { hood.elevation } else { st.top + 0.65 };
                let z = z.min(self.layout.height - 0.02 - hood.size.z);
                let half = hood.size.x * 0.5;
                if z > st.top + 0.4
                    && hs - half >= 0.0
                    && hs + half <= wall.length
                    && self.layout.wall_free(k, hs - half, hs + half, z, z + hood.size.z, 0.0)
                {
                    let center = wall.point(hs, hood.size.y * 0.5);
                    if self.emit(&hood, center, z, yaw_facing(wall.normal), Vec3::ONE) {
                        self.layout.reserve_wall(k, hs - half, hs + half, z, z + hood.size.z);
                        self.layout.interest.push(center.extend(z + hood.size.z * 0.5));
                    }
                }
            }
        }
        // Upper cabinets.
        if self.rng.random_bool(0.6) {
            let mut t = a;
            let mut misses = 0;
            while t < b - 0.3 && misses < 8 {
                let room = b - t;
                let Some(p) = self.piece(|m| is_kitchen_upper(m) && m.size.x <= room) else { break };
                let z = p.elevation.min(self.layout.height - 0.05 - p.size.z);
                let sc = t + p.size.x * 0.5 + 0.002;
                if z > 1.3 && self.layout.wall_free(k, sc - p.size.x * 0.5, sc + p.size.x * 0.5, z, z + p.size.z, 0.0) {
                    let center = wall.point(sc, p.size.y * 0.5);
                    if self.emit(&p, center, z, yaw_facing(wall.normal), Vec3::ONE) {
                        self.layout.reserve_wall(k, sc - p.size.x * 0.5, sc + p.size.x * 0.5, z, z + p.size.z);
                        self.layout.interest.push(center.extend(z + p.size.z * 0.5));
                    }
                    t += p.size.x + 0.004;
                } else {
                    t += 0.2;
                    misses += 1;
                }
            }
        }
        for m in &modules {
            let n = if self.rng.random_bool(0.5) { 1 } else { 0 };
            self.on_top(m, n);
        }
        modules.len()
    }

    pub(super) fn kitchen(&mut self) {
        let k = self.freest_wall(&ALL_WALLS);
        let len = self.layout.walls[k].length;
        let fridge = self.rng.random_bool(0.75);
        let n = self.kitchen_row(k, 0.0, len, fridge);
        if n == 0 {
            // No kitchen models: cabinets and a counter table.
            for _ in 0..3 {
                let p = self.proc_piece(Proc::Cabinet);
                self.wall_piece(&p, &[k], 0.0, 0.0, 20);
            }
        }
        if self.rng.random_bool(0.5) {
            let k2 = if self.rng.random_bool(0.5) { (k + 1) % 4 } else { (k + 3) % 4 };
            let len2 = self.layout.walls[k2].length;
            self.kitchen_row(k2, 0.0, len2, false);
        }
        let r = self.inner(0.2);
        if self.dining_set(r, 4, false).is_none() && self.rng.random_bool(0.7) {
            // A small table against a wall with two chairs.
            if let Some(t) = self.piece(|m| is_table(m) && m.size.x <= 1.4) {
                if let Some(pl) = self.wall_piece(&t, &ALL_WALLS, 0.0, 0.0, 30) {
                    if let Some(c) = self.piece(is_chair) {
                        self.chairs_around(&pl, &c, true, false, 2);
                    }
                }
            }
        }
        if self.rng.random_bool(0.3) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=1);
        self.pictures(n);
    }

    pub(super) fn bathroom(&mut self) {
        if let Some(p) = self.piece(is_toilet) {
            self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 60);
        }
        if let Some(p) = self.piece(is_washbasin) {
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 60) {
                let n = self.rng.random_range(0..=2);
                self.on_top(&pl, n);
                // A mirror above: a flat procedural panel, labelled clutter like S3DIS does.
                if let Some((k, s)) = pl.wall {
                    let z0 = (pl.z + pl.size.z + 0.15).max(1.1);
                    let (mw, mh) = (pl.size.x.clamp(0.4, 1.2), uniform(&mut self.rng, 0.5, 0.8));
                    if z0 + mh < self.layout.height - 0.1
                        && self.layout.wall_free(k, s - mw * 0.5, s + mw * 0.5, z0, z0 + mh, 0.0)
                    {
                        let wall = self.layout.walls[k];
                        self.b.place(wall.start.extend(0.0), wall.yaw);
                        let glass = jitter(&mut self.rng, [0.62, 0.66, 0.68], 0.08);
                        self.b.cuboid(
                            Vec3::new(s - mw * 0.5, 0.0, z0),
                            Vec3::new(s + mw * 0.5, 0.02, z0 + mh),
                            SKIP_NEG_Y,
                            SemanticClass::Clutter,
                            glass,
                        );
                        self.layout.reserve_wall(k, s - mw * 0.5, s + mw * 0.5, z0, z0 + mh);
                    }
                }
            }
        }
        if self.rng.random_bool(0.6) {
            if let Some(p) = self.piece(is_bathtub) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 60);
            }
        } else if let Some(p) = self.piece(is_shower) {
            self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 60);
        }
        if self.rng.random_bool(0.4) {
            if let Some(p) = self.piece(|m| is_floor_cabinet(m) && m.size.y <= 0.5) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30);
            }
        }
        if self.rng.random_bool(0.25) {
            if let Some(p) = self.piece(|m| is(m, &["washing_machine"]) && on_floor(m)) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30);
            }
        }
        for _ in 0..self.rng.random_range(1..=2) {
            if let Some(p) = self.piece(is_towel_rack) {
                let z = if p.elevation > 0.3 { None } else { Some(uniform(&mut self.rng, 0.9, 1.3)) };
                self.wall_hang(&p, &ALL_WALLS, z, 20);
            }
        }
        if self.rng.random_bool(0.5) {
            let c = Vec2::new(self.layout.width, self.layout.depth) * 0.5;
            let yaw = if self.rng.random_bool(0.5) { 0.0 } else { FRAC_PI_2 };
            self.rug(c, yaw, Vec2::new(0.9, 0.6));
        }
    }
}
