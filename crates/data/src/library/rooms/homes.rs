//! Recipes for the rooms people live in: the bedroom (beds with nightstands, a wardrobe, a
//! dresser), the living room (a sofa corner facing a TV, bookcases, sometimes a dining
//! table) and the studio, which has a bit of each and a kitchenette.

use std::f32::consts::FRAC_PI_2;

use glam::{Vec2, Vec3};
use rand::Rng;

use super::categories::{
    is_armchair, is_bed, is_coffee_table, is_dresser, is_nightstand, is_sofa, is_tv, is_tv_stand, is_wardrobe,
};
use super::pieces::{yaw_facing, Proc};
use super::placement::ALL_WALLS;
use super::{Home, ModelSource};
use crate::synth::palette::uniform;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    pub(super) fn bedroom(&mut self) {
        let (w, d) = (self.layout.width, self.layout.depth);
        let beds = if w.min(d) > 3.6 && self.rng.random_bool(0.2) { 2 } else { 1 };
        let shorter = w.min(d);
        for _ in 0..beds {
            let Some(bed) = self.piece(|m| is_bed(m) && m.size.y <= shorter - 0.9) else { break };
            let Some(pl) = self.wall_piece(&bed, &ALL_WALLS, 0.0, 0.0, 60) else { continue };
            let (k, s) = pl.wall.unwrap_or((0, 0.0));
            for side in [-1.0f32, 1.0] {
                if !self.rng.random_bool(0.8) {
                    continue;
                }
                let Some(ns) = self.piece(is_nightstand) else { break };
                let at = s + side * (pl.size.x * 0.5 + 0.04 + ns.size.x * 0.5);
                if let Some(n) = self.wall_piece_at(&ns, k, at, 1.0, 0.0, 0.0) {
                    self.on_top(&n, 1);
                }
            }
            if self.rng.random_bool(0.45) {
                let wall = self.layout.walls[k];
                let c = wall.point(s, pl.size.y * 0.6);
                self.rug(c, pl.yaw + FRAC_PI_2, Vec2::new(pl.size.y * 1.1, pl.size.x + 0.8));
            }
            // A picture above the bed.
            if self.rng.random_bool(0.6) {
                let z = pl.z + pl.size.z + uniform(&mut self.rng, 0.15, 0.35);
                let (pw, ph) = (uniform(&mut self.rng, 0.5, 1.2).min(pl.size.x), uniform(&mut self.rng, 0.3, 0.7));
                self.picture_at(k, s, z + ph * 0.5, pw, ph);
            }
        }
        if self.rng.random_bool(0.85) {
            if let Some(p) = self.piece(is_wardrobe) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.6, 50);
            }
        }
        if self.rng.random_bool(0.45) {
            if let Some(p) = self.piece(is_dresser) {
                if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 40) {
                    let n = self.rng.random_range(1..=3);
                    self.on_top(&pl, n);
                }
            }
        }
        if self.rng.random_bool(0.35) {
            self.desk_with_chair(&ALL_WALLS, false);
        }
        if self.rng.random_bool(0.25) {
            if let Some(p) = self.piece(is_armchair) {
                self.wall_piece(&p, &ALL_WALLS, 0.1, 0.0, 30);
            }
        }
        if self.rng.random_bool(0.3) {
            self.floor_lamp();
        }
        if self.rng.random_bool(0.35) {
            self.floor_plant(&ALL_WALLS);
        }
        if self.rng.random_bool(0.3) {
            self.bookcases(1, &ALL_WALLS, 0.45);
        }
        let n = self.rng.random_range(0..=2);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.pictures(n);
    }

    /// Sofa against a wall, coffee table in front, armchairs at its sides, TV opposite.
    fn sofa_corner(&mut self, big: bool) -> bool {
        let max_w = if big { 3.2 } else { 2.2 };
        let Some(sofa) = self.piece(|m| is_sofa(m) && m.size.x <= max_w).or_else(|| Some(self.proc_piece(Proc::Sofa)))
        else {
            return false;
        };
        let Some(pl) = self.wall_piece(&sofa, &ALL_WALLS, 0.05, 0.0, 60) else { return false };
        let (k, s) = pl.wall.unwrap_or((0, 0.0));
        let wall = self.layout.walls[k];
        let across = self.layout.walls[(k + 1) % 4].length;
        let mut ct_end = pl.size.y + 0.05;
        if let Some(ct) = self.piece(|m| is_coffee_table(m) && m.size.x <= pl.size.x + 0.2) {
            let dist = 0.05 + pl.size.y + uniform(&mut self.rng, 0.3, 0.5) + ct.size.y * 0.5;
            let c = wall.point(s, dist);
            if let Some(t) = self.free_piece_at(&ct, c, pl.yaw, 1.0, 0.0) {
                ct_end = dist + ct.size.y * 0.5;
                let n = self.rng.random_range(0..=3);
                self.on_top(&t, n);
                if self.rng.random_bool(0.6) {
                    self.rug(c, pl.yaw, Vec2::new(pl.size.x + 0.8, 2.0 * (dist - 0.05 - pl.size.y * 0.6) + ct.size.y));
                }
                // Armchairs at the ends of the coffee table, facing it.
                for side in [-1.0f32, 1.0] {
                    if !self.rng.random_bool(0.5) {
                        continue;
                    }
                    let Some(a) = self.piece(is_armchair) else { break };
                    let off = t.size.x * 0.5 + 0.3 + a.size.y * 0.5;
                    let ac = c + wall.dir * side * off;
                    let yaw = yaw_facing(-wall.dir * side) + uniform(&mut self.rng, -0.2, 0.2);
                    self.free_piece_at(&a, ac, yaw, 1.0, 0.0);
                }
            }
        }
        // TV on a stand against the opposite wall, if it is not too far.
        if across - ct_end > 1.4 && across < 6.5 && self.rng.random_bool(0.75) {
            let k2 = (k + 2) % 4;
            let s2 = self.layout.walls[k2].length - s;
            let stand = self.piece(is_tv_stand);
            let tv = self.piece(is_tv);
            match (stand, tv) {
                (Some(stand), Some(tv)) if tv.elevation < 0.5 => {
                    for ds in [0.0, 0.4, -0.4, 0.8, -0.8] {
                        if let Some(st) = self.wall_piece_at(&stand, k2, s2 + ds, 1.0, 0.0, 0.6) {
                            let scale = (st.size.x * 0.95 / tv.size.x).min(st.size.y / tv.size.y.max(0.05)).min(1.0);
                            if scale > 0.5 {
                                let back = self.layout.walls[k2].normal
                                    * ((st.size.y - tv.size.y * scale) * 0.5 - 0.02).max(0.0);
                                self.emit(&tv, st.center - back, st.top, st.yaw, Vec3::splat(scale));
                                self.layout.interest.push(st.center.extend(st.top + tv.size.z * 0.5));
                            }
                            break;
                        }
                    }
                }
                (_, Some(tv)) if tv.elevation >= 0.5 => {
                    self.wall_hang(&tv, &[k2], None, 20);
                }
                (Some(stand), _) => {
                    if let Some(st) = self.wall_piece(&stand, &[k2], 0.0, 0.6, 20) {
                        self.on_top(&st, 2);
                    }
                }
                _ => {}
            }
        }
        true
    }

    pub(super) fn living_room(&mut self) {
        self.sofa_corner(true);
        if self.rng.random_bool(0.35) {
            if let Some(p) = self.piece(|m| is_sofa(m) && m.size.x <= 2.4) {
                self.wall_piece(&p, &ALL_WALLS, 0.05, 0.0, 30);
            }
        }
        let n = self.rng.random_range(1..=2);
        self.bookcases(n, &ALL_WALLS, 0.6);
        if self.rng.random_bool(0.4) {
            if let Some(p) = self.piece(is_dresser) {
                if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 30) {
                    self.on_top(&pl, 3);
                }
            }
        }
        if self.layout.width * self.layout.depth > 22.0 && self.rng.random_bool(0.5) {
            let r = self.inner(0.3);
            self.dining_set(r, 6, false);
        }
        for _ in 0..self.rng.random_range(1..=3) {
            self.floor_plant(&ALL_WALLS);
        }
        if self.rng.random_bool(0.6) {
            self.floor_lamp();
        }
        let n = self.rng.random_range(0..=2);
        self.floor_clutter(n);
        let n = self.rng.random_range(1..=3);
        self.pictures(n);
    }

    pub(super) fn studio(&mut self) {
        // Sleeping corner.
        if let Some(bed) = self.piece(|m| is_bed(m) && m.size.x <= 1.7) {
            if let Some(pl) = self.wall_piece(&bed, &ALL_WALLS, 0.0, 0.0, 60) {
                if let Some((k, s)) = pl.wall {
                    if let Some(ns) = self.piece(is_nightstand) {
                        let side = if self.rng.random_bool(0.5) { 1.0 } else { -1.0 };
                        let at = s + side * (pl.size.x * 0.5 + 0.04 + ns.size.x * 0.5);
                        if let Some(n) = self.wall_piece_at(&ns, k, at, 1.0, 0.0, 0.0) {
                            self.on_top(&n, 1);
                        }
                    }
                }
            }
        }
        // Kitchenette.
        let k = self.freest_wall(&ALL_WALLS);
        let len = self.layout.walls[k].length;
        let run = uniform(&mut self.rng, 1.8, 3.0).min(len);
        let start = if self.rng.random_bool(0.5) { 0.0 } else { len - run };
        let fridge = self.rng.random_bool(0.5);
        self.kitchen_row(k, start, start + run, fridge);
        self.sofa_corner(false);
        if self.rng.random_bool(0.7) {
            let r = self.inner(0.3);
            self.dining_set(r, 4, false);
        }
        if self.rng.random_bool(0.6) {
            if let Some(p) = self.piece(is_wardrobe) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.6, 40);
            }
        }
        if self.rng.random_bool(0.3) {
            self.desk_with_chair(&ALL_WALLS, false);
        }
        if self.rng.random_bool(0.5) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(1..=2);
        self.pictures(n);
    }
}
