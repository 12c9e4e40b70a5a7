//! Things fixed to the walls and the ceiling: pictures and clocks, boards, radiators under
//! windows, curtains beside them, sockets and switches, wall lamps and a ceiling lamp. They
//! take wall space (nothing else hangs over them), and the lamps are light sources for the
//! baked shading.

use glam::{Vec2, Vec3};
use rand::Rng;

use super::categories::{is_ceiling_lamp, is_curtain, is_radiator, is_wall_lamp, is_wall_socket, is_whiteboard};
use super::pieces::yaw_facing;
use super::placement::ALL_WALLS;
use super::{Home, HomeRoomKind, HomeSpan, ModelSource};
use crate::class::UNLABELED;
use crate::home_class::HomeClass;
use crate::synth::clutter::{self, WallItem};
use crate::synth::furniture::{self, BoardKind};
use crate::synth::layout::footprint;
use crate::synth::palette::{pick, uniform};
use crate::synth::shell::{Opening, OpeningKind};

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// A procedural picture (or clock) centred at `s`, `zc` on wall `k`, if the wall is free.
    pub(super) fn picture_at(&mut self, k: usize, s: f32, zc: f32, w: f32, h: f32) -> bool {
        let (s0, s1, z0, z1) = (s - w * 0.5, s + w * 0.5, zc - h * 0.5, zc + h * 0.5);
        if s0 < 0.05
            || s1 > self.layout.walls[k].length - 0.05
            || z1 > self.layout.height - 0.1
            || !self.layout.wall_free(k, s0, s1, z0 - 0.02, z1 + 0.02, 0.05)
        {
            return false;
        }
        let wall = self.layout.walls[k];
        self.b.place(wall.start.extend(0.0), wall.yaw);
        let kind = if self.rng.random_bool(0.12) && w < 0.5 { WallItem::Clock } else { WallItem::Picture };
        let (w, h) = if kind == WallItem::Clock { (0.3, 0.3) } else { (w, h) };
        let start = self.b.mesh.positions.len() as u32;
        clutter::wall_item(&mut self.b, &mut self.rng, &self.pal, kind, s, zc, w, h);
        let label = if kind == WallItem::Picture { HomeClass::Picture.id() } else { UNLABELED };
        let end = self.b.mesh.positions.len() as u32;
        self.home_spans.push(HomeSpan { vertices: start..end, label, counter_top: false });
        self.layout.reserve_wall(k, s0, s1, z0, z1);
        self.layout.interest.push(wall.point(s, 0.0).extend(zc));
        true
    }

    pub(super) fn pictures(&mut self, n: usize) {
        for _ in 0..n {
            for _ in 0..20 {
                let k = self.rng.random_range(0..4);
                let len = self.layout.walls[k].length;
                let (w, h) = (uniform(&mut self.rng, 0.3, 1.2), uniform(&mut self.rng, 0.3, 0.9));
                if w > len - 0.4 {
                    continue;
                }
                let s = uniform(&mut self.rng, w * 0.5 + 0.1, len - w * 0.5 - 0.1);
                let zc = uniform(&mut self.rng, 1.3, 1.8);
                if self.picture_at(k, s, zc, w, h) {
                    break;
                }
            }
        }
    }

    /// Boards on walls: the catalogue's whiteboard on its stand by a wall sometimes, else
    /// procedural boards hung on the wall.
    pub(super) fn boards(&mut self, n: usize, walls: &[usize]) {
        for _ in 0..n {
            if self.rng.random_bool(0.3) {
                if let Some(p) = self.piece(is_whiteboard) {
                    if self.wall_piece(&p, walls, 0.02, 0.5, 20).is_some() {
                        continue;
                    }
                }
            }
            for _ in 0..30 {
                let k = walls[self.rng.random_range(0..walls.len())];
                let len = self.layout.walls[k].length;
                let bw = uniform(&mut self.rng, 1.0, 2.4).min(len - 0.6);
                if bw < 0.6 {
                    break;
                }
                let z0 = uniform(&mut self.rng, 0.8, 1.0);
                let z1 = (z0 + uniform(&mut self.rng, 0.9, 1.2)).min(self.layout.height - 0.2);
                let s = uniform(&mut self.rng, bw * 0.5 + 0.2, len - bw * 0.5 - 0.2);
                let (s0, s1) = (s - bw * 0.5, s + bw * 0.5);
                if !self.layout.wall_free(k, s0, s1, z0 - 0.1, z1 + 0.05, 0.1) {
                    continue;
                }
                // Nothing tall in front of it.
                let wall = self.layout.walls[k];
                let fp = footprint(wall.point(s, 0.3), bw, 0.6, wall.yaw);
                if !self.layout.floor_free(&fp) {
                    continue;
                }
                let kind =
                    pick(&mut self.rng, &[BoardKind::White, BoardKind::White, BoardKind::Black, BoardKind::Cork]);
                self.b.place(wall.start.extend(0.0), wall.yaw);
                furniture::board(&mut self.b, &mut self.rng, &self.pal, s0, s1, z0, z1, kind);
                self.layout.reserve_wall(k, s0, s1, z0 - 0.1, z1);
                self.layout.add_keepout(fp);
                self.layout.interest.push(wall.point(s, 0.0).extend((z0 + z1) * 0.5));
                break;
            }
        }
    }

    /// Radiators under some windows.
    pub(super) fn radiators(&mut self) {
        let windows: Vec<Opening> = self.openings.iter().filter(|o| o.kind == OpeningKind::Window).copied().collect();
        for o in windows {
            if o.z0 < 0.5 || !self.rng.random_bool(0.5) {
                continue;
            }
            let Some(p) = self.piece(|m| is_radiator(m) && m.size.x <= o.s1 - o.s0 + 0.3) else { return };
            let scale = ((o.z0 - 0.12) / (p.size.z + p.elevation.min(0.15))).min(1.0);
            if scale < 0.6 {
                continue;
            }
            let s = (o.s0 + o.s1) * 0.5;
            let wall = self.layout.walls[o.wall];
            let size = p.size * scale;
            let z = p.elevation.clamp(0.06, 0.15);
            let center = wall.point(s, size.y * 0.5 + 0.04);
            let fp = footprint(center, size.x, size.y, wall.yaw);
            if !self.layout.floor_free(&fp)
                || !self.layout.wall_free(o.wall, s - size.x * 0.5, s + size.x * 0.5, 0.0, z + size.z, 0.0)
            {
                continue;
            }
            if self.emit(&p, center, z, yaw_facing(wall.normal), Vec3::splat(scale)) {
                self.layout.add_obstacle(fp);
                self.layout.reserve_wall(o.wall, s - size.x * 0.5, s + size.x * 0.5, 0.0, z + size.z);
            }
        }
    }

    /// Curtains at the sides of some windows in homes.
    pub(super) fn curtains(&mut self) {
        if matches!(self.kind, HomeRoomKind::Bathroom | HomeRoomKind::Corridor | HomeRoomKind::Conference) {
            return;
        }
        let windows: Vec<Opening> = self.openings.iter().filter(|o| o.kind == OpeningKind::Window).copied().collect();
        for o in windows {
            if !self.rng.random_bool(0.5) {
                continue;
            }
            let Some(p) = self.piece(is_curtain) else { return };
            let wall = self.layout.walls[o.wall];
            let top = (o.z1 + uniform(&mut self.rng, 0.05, 0.2)).min(self.layout.height - 0.03);
            let to_floor = self.rng.random_bool(0.6);
            let bottom = if to_floor { 0.02 } else { (o.z0 - 0.1).max(0.02) };
            let pw = uniform(&mut self.rng, 0.3, 0.5);
            let sy = (0.12 / p.size.y).min(1.0);
            let scale = Vec3::new(pw / p.size.x, sy, (top - bottom) / p.size.z);
            let depth = p.size.y * sy;
            for s in [o.s0 - pw * 0.5 + 0.1, o.s1 + pw * 0.5 - 0.1] {
                let (a, b) = (s - pw * 0.5, s + pw * 0.5);
                if a < 0.02 || b > wall.length - 0.02 {
                    continue;
                }
                // The part beside the window must be free wall.
                let (fa, fb) = if s < o.s0 { (a, o.s0 - 0.1) } else { (o.s1 + 0.1, b) };
                if fb > fa && !self.layout.wall_free(o.wall, fa, fb, bottom, top, 0.0) {
                    continue;
                }
                let center = wall.point(s, 0.05 + depth * 0.5);
                let fp = footprint(center, pw, depth, wall.yaw);
                if to_floor && !self.layout.floor_free(&fp) {
                    continue;
                }
                if self.emit(&p, center, bottom, yaw_facing(wall.normal), scale) {
                    if to_floor {
                        self.layout.add_obstacle(fp);
                    }
                    self.layout.reserve_wall(o.wall, a, b, bottom, top);
                }
            }
        }
    }

    /// Sockets and switches on free wall, wall lamps sometimes.
    pub(super) fn wall_details(&mut self) {
        for _ in 0..self.rng.random_range(1..=4) {
            let Some(p) = self.piece(is_wall_socket) else { break };
            let z = if p.elevation > 0.1 { p.elevation } else { pick(&mut self.rng, &[0.25, 0.3, 1.05, 1.1]) };
            self.wall_hang(&p, &ALL_WALLS, Some(z), 20);
        }
        if !matches!(self.kind, HomeRoomKind::Conference | HomeRoomKind::Office) && self.rng.random_bool(0.3) {
            if let Some(p) = self.piece(is_wall_lamp) {
                if let Some(pl) = self.wall_hang(&p, &ALL_WALLS, None, 20) {
                    self.lights.push(pl.center.extend(pl.z + pl.size.z * 0.5));
                }
            }
        }
    }

    pub(super) fn ceiling_lamp(&mut self) {
        if !self.rng.random_bool(0.55) {
            return;
        }
        let h = self.layout.height;
        let Some(p) = self.piece(|m| is_ceiling_lamp(m) && m.size.z <= h - 2.05) else { return };
        let c = Vec2::new(self.layout.width, self.layout.depth) * 0.5;
        let fp = footprint(c, p.size.x, p.size.y, 0.0);
        if self.layout.floor().contains(&fp) && self.emit(&p, c, h - p.size.z, 0.0, Vec3::ONE) {
            self.lights.push(c.extend(h - p.size.z));
            self.layout.interest.push(c.extend(h - p.size.z * 0.5));
        }
    }
}
