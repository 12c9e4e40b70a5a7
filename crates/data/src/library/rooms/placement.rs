//! Where a piece may go, and putting it there: against a wall (its back to the wall, facing
//! into the room, optionally with free floor kept in front of it), free-standing, or hung
//! on a wall, with the floor and wall occupancy of the
//! [`Layout`](crate::synth::layout::Layout) updated. Every placement
//! on the floor is checked on a walk grid so that the room keeps one connected area where a
//! scanning camera can move, [`WALK_CLEARANCE`] from walls and obstacles.

use glam::{Vec2, Vec3};
use rand::Rng;

use super::pieces::{yaw_facing, Piece, Placed};
use super::{Home, ModelSource};
use crate::synth::layout::{footprint, Rect2};
use crate::synth::palette::uniform;

/// Clearance a scan path keeps from walls and obstacles (see `scan_path`): every room keeps
/// a connected walkable area at this distance.
const WALK_CLEARANCE: f32 = 0.4;

/// Every wall of the room, by its index in the layout's `walls`.
pub(super) const ALL_WALLS: [usize; 4] = [0, 1, 2, 3];

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// Whether the floor keeps a connected area where a camera can walk (at
    /// [`WALK_CLEARANCE`] from walls and obstacles) once `extra` is taken too.
    fn walkable_with(&self, extra: &Rect2) -> bool {
        const CELL: f32 = 0.1;
        let (w, d) = (self.layout.width, self.layout.depth);
        let (nx, ny) = ((w / CELL) as usize, (d / CELL) as usize);
        let mut free = vec![false; nx * ny];
        let mut initial = 0usize;
        let c = WALK_CLEARANCE;
        for j in 0..ny {
            for i in 0..nx {
                let p = Vec2::new((i as f32 + 0.5) * CELL, (j as f32 + 0.5) * CELL);
                if p.x >= c && p.x <= w - c && p.y >= c && p.y <= d - c {
                    free[j * nx + i] = true;
                    initial += 1;
                }
            }
        }
        if initial == 0 {
            return true;
        }
        for r in self.layout.obstacles.iter().chain(std::iter::once(extra)) {
            let (lo, hi) = (r.min - Vec2::splat(c), r.max + Vec2::splat(c));
            let i0 = ((lo.x / CELL - 0.5).ceil().max(0.0)) as usize;
            let j0 = ((lo.y / CELL - 0.5).ceil().max(0.0)) as usize;
            let i1 = ((hi.x / CELL - 0.5).floor()).min(nx as f32 - 1.0);
            let j1 = ((hi.y / CELL - 0.5).floor()).min(ny as f32 - 1.0);
            if i1 < 0.0 || j1 < 0.0 {
                continue;
            }
            for j in j0..=j1 as usize {
                for i in i0..=i1 as usize {
                    free[j * nx + i] = false;
                }
            }
        }
        // Largest 4-connected free area.
        let mut seen = vec![false; nx * ny];
        let mut largest = 0usize;
        let mut stack = Vec::new();
        for start in 0..nx * ny {
            if !free[start] || seen[start] {
                continue;
            }
            let mut count = 0;
            seen[start] = true;
            stack.push(start);
            while let Some(k) = stack.pop() {
                count += 1;
                let (i, j) = (k % nx, k / nx);
                let mut visit = |k2: usize| {
                    if free[k2] && !seen[k2] {
                        seen[k2] = true;
                        stack.push(k2);
                    }
                };
                if i > 0 {
                    visit(k - 1);
                }
                if i + 1 < nx {
                    visit(k + 1);
                }
                if j > 0 {
                    visit(k - nx);
                }
                if j + 1 < ny {
                    visit(k + nx);
                }
            }
            largest = largest.max(count);
        }
        largest * 5 >= initial && largest >= initial.min(25)
    }

    /// Vertical extent `(z0, z1)` a piece takes on the wall at scale `s`.
    fn z_range(&self, p: &Piece, s: f32) -> (f32, f32) {
        let h = p.size.z * s;
        let z0 = if p.elevation > 0.05 { p.elevation.min(self.layout.height - 0.03 - h).max(0.0) } else { 0.0 };
        (z0, z0 + h)
    }

    /// Whether a piece of scaled `size` fits against wall `k` at `s`, `gap` off the wall,
    /// `access` of floor kept free in front of it.
    #[allow(clippy::too_many_arguments)]
    fn wall_fits(&self, k: usize, s: f32, size: Vec3, gap: f32, z0: f32, z1: f32, access: f32) -> bool {
        let wall = self.layout.walls[k];
        if s - size.x * 0.5 < 0.0 || s + size.x * 0.5 > wall.length || z1 > self.layout.height - 0.01 {
            return false;
        }
        if !self.layout.wall_free(k, s - size.x * 0.5, s + size.x * 0.5, z0, z1, 0.02) {
            return false;
        }
        if z0 >= 1.2 {
            return true;
        }
        let fp = footprint(wall.point(s, gap + size.y * 0.5), size.x, size.y, wall.yaw);
        if !self.layout.floor_free(&fp) {
            return false;
        }
        if access > 0.0 {
            let front = footprint(wall.point(s, gap + size.y + access * 0.5), size.x, access, wall.yaw);
            if !self.layout.floor_free(&front) {
                return false;
            }
        }
        self.walkable_with(&fp)
    }

    /// Puts `p` against wall `k` at `s` if it fits; takes the wall and floor.
    pub(super) fn wall_piece_at(
        &mut self,
        p: &Piece,
        k: usize,
        s: f32,
        scale: f32,
        gap: f32,
        access: f32,
    ) -> Option<Placed> {
        let size = p.size * scale;
        let (z0, z1) = self.z_range(p, scale);
        if !self.wall_fits(k, s, size, gap, z0, z1, access) {
            return None;
        }
        let wall = self.layout.walls[k];
        let center = wall.point(s, gap + size.y * 0.5);
        let yaw = yaw_facing(wall.normal);
        if !self.emit(p, center, z0, yaw, Vec3::splat(scale)) {
            return None;
        }
        self.layout.reserve_wall(k, s - size.x * 0.5, s + size.x * 0.5, z0, z1);
        if z0 < 1.2 {
            self.layout.add_obstacle(footprint(center, size.x, size.y, wall.yaw));
            if access > 0.0 {
                self.layout.add_keepout(footprint(
                    wall.point(s, gap + size.y + access * 0.5),
                    size.x,
                    access,
                    wall.yaw,
                ));
            }
        }
        self.layout.interest.push(center.extend((z0 + z1) * 0.5));
        Some(Placed { center, yaw, size, z: z0, top: z0 + p.top * scale, wall: Some((k, s)) })
    }

    /// Puts `p` against one of `walls` at a random free position.
    pub(super) fn wall_piece(
        &mut self,
        p: &Piece,
        walls: &[usize],
        gap: f32,
        access: f32,
        tries: usize,
    ) -> Option<Placed> {
        let scale = self.scale_for(p);
        for attempt in 0..tries {
            let s_scale = if attempt * 2 < tries { scale } else { scale.min(1.0) };
            let k = walls[self.rng.random_range(0..walls.len())];
            let len = self.layout.walls[k].length;
            let w = p.size.x * s_scale;
            if w > len {
                continue;
            }
            // Corners are popular: half of the tries start at one.
            let s = match self.rng.random_range(0..4) {
                0 => w * 0.5 + 0.01,
                1 => len - w * 0.5 - 0.01,
                _ => uniform(&mut self.rng, w * 0.5, len - w * 0.5),
            };
            if let Some(pl) = self.wall_piece_at(p, k, s, s_scale, gap, access) {
                return Some(pl);
            }
        }
        None
    }

    /// Puts `p` free-standing at `center` turned by `yaw` if the floor is free (with
    /// `clearance` to other obstacles) and the room stays walkable.
    pub(super) fn free_piece_at(
        &mut self,
        p: &Piece,
        center: Vec2,
        yaw: f32,
        scale: f32,
        clearance: f32,
    ) -> Option<Placed> {
        let size = p.size * scale;
        let fp = footprint(center, size.x, size.y, yaw);
        let grown = Rect2::new(fp.min - Vec2::splat(clearance), fp.max + Vec2::splat(clearance));
        // With a clearance (tables that get chairs around), the grown footprint must be free
        // floor (keep-out zones included) and leave the room walkable.
        let free = if clearance > 0.0 {
            self.layout.floor_free(&grown) && self.walkable_with(&grown)
        } else {
            self.layout.floor_free(&fp) && self.walkable_with(&fp)
        };
        if !free {
            return None;
        }
        let (z0, z1) = (0.0, size.z);
        if !self.emit(p, center, z0, yaw, Vec3::splat(scale)) {
            return None;
        }
        self.layout.add_obstacle(fp);
        self.layout.interest.push(center.extend((z0 + z1) * 0.5));
        Some(Placed { center, yaw, size, z: z0, top: z0 + p.top * scale, wall: None })
    }

    /// Puts `p` free-standing somewhere in `region`.
    pub(super) fn free_piece(
        &mut self,
        p: &Piece,
        region: Rect2,
        yaw: f32,
        clearance: f32,
        tries: usize,
    ) -> Option<Placed> {
        let scale = self.scale_for(p);
        let half = footprint(Vec2::ZERO, p.size.x * scale, p.size.y * scale, yaw).max;
        for _ in 0..tries {
            let lo = region.min + half + Vec2::splat(clearance);
            let hi = region.max - half - Vec2::splat(clearance);
            if lo.x > hi.x || lo.y > hi.y {
                return None;
            }
            let c = Vec2::new(uniform(&mut self.rng, lo.x, hi.x), uniform(&mut self.rng, lo.y, hi.y));
            if let Some(pl) = self.free_piece_at(p, c, yaw, scale, clearance) {
                return Some(pl);
            }
        }
        None
    }

    /// Hangs `p` on one of `walls` with its bottom at `z0` (or its catalogue elevation),
    /// flush with the wall; nothing on the floor.
    pub(super) fn wall_hang(&mut self, p: &Piece, walls: &[usize], z0: Option<f32>, tries: usize) -> Option<Placed> {
        let h = self.layout.height;
        for _ in 0..tries {
            let k = walls[self.rng.random_range(0..walls.len())];
            let len = self.layout.walls[k].length;
            let size = p.size;
            if size.x > len - 0.2 {
                continue;
            }
            let z = z0.unwrap_or(if p.elevation > 0.2 {
                p.elevation
            } else {
                uniform(&mut self.rng, 1.2, 1.6) - size.z * 0.5
            });
            let z = z.min(h - 0.05 - size.z).max(0.05);
            let s = uniform(&mut self.rng, size.x * 0.5 + 0.1, len - size.x * 0.5 - 0.1);
            if !self.layout.wall_free(k, s - size.x * 0.5, s + size.x * 0.5, z - 0.02, z + size.z + 0.02, 0.05) {
                continue;
            }
            let wall = self.layout.walls[k];
            let center = wall.point(s, size.y * 0.5 + 0.003);
            if z < 1.2 {
                let fp = footprint(center, size.x, size.y, wall.yaw);
                // Low wall things hang over free floor or over furniture lower than them.
                if !self.layout.floor().contains(&fp) {
                    continue;
                }
            }
            let yaw = yaw_facing(wall.normal);
            if !self.emit(p, center, z, yaw, Vec3::ONE) {
                return None;
            }
            self.layout.reserve_wall(k, s - size.x * 0.5, s + size.x * 0.5, z, z + size.z);
            self.layout.interest.push(center.extend(z + size.z * 0.5));
            return Some(Placed { center, yaw, size, z, top: z + p.top, wall: Some((k, s)) });
        }
        None
    }

    pub(super) fn long_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [0, 2]
        } else {
            [1, 3]
        }
    }

    pub(super) fn short_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [1, 3]
        } else {
            [0, 2]
        }
    }

    pub(super) fn inner(&self, margin: f32) -> Rect2 {
        Rect2::new(Vec2::splat(margin), Vec2::new(self.layout.width, self.layout.depth) - Vec2::splat(margin))
    }

    /// The wall with the most free length, among `walls`.
    pub(super) fn freest_wall(&self, walls: &[usize]) -> usize {
        let mut best = (walls[0], -1.0f32);
        for &k in walls {
            let len = self.layout.walls[k].length;
            let mut free = 0.0;
            let mut s = 0.05;
            while s < len - 0.05 {
                if self.layout.wall_free(k, s - 0.05, s + 0.05, 0.0, 0.9, 0.0) {
                    free += 0.1;
                }
                s += 0.1;
            }
            if free > best.1 {
                best = (k, free);
            }
        }
        best.0
    }
}
