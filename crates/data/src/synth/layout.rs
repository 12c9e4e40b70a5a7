//! Occupancy bookkeeping for placing things in a room without overlaps: the floor (2-D
//! footprints of furniture and columns, plus keep-out zones such as the swing of a door)
//! and the four walls (spans along a wall and a height range, taken by openings, columns,
//! boards and tall furniture). Placement is rejection sampling with a fixed number of tries
//! drawn from the room's RNG, so a seed always yields the same layout.
//!
//! Walls are numbered 0: y = 0, 1: x = width, 2: y = depth, 3: x = 0. Wall `k` has a frame
//! turned by `k` quarter turns: local x runs along the wall (s from 0 to its length), local
//! +y is the wall's inward normal, z is up; furniture modelled facing local +y therefore
//! stands against wall `k` when placed with the wall's yaw.

use glam::{Vec2, Vec3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::palette::uniform;

/// An axis-aligned rectangle on the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rect2 {
    pub(crate) min: Vec2,
    pub(crate) max: Vec2,
}

impl Rect2 {
    pub(crate) fn new(min: Vec2, max: Vec2) -> Self {
        Self { min, max }
    }

    /// Whether the two rectangles, each grown by `margin`, overlap with positive area.
    pub(crate) fn overlaps(&self, other: &Rect2, margin: f32) -> bool {
        self.min.x - margin < other.max.x
            && other.min.x < self.max.x + margin
            && self.min.y - margin < other.max.y
            && other.min.y < self.max.y + margin
    }

    /// Whether `other` lies inside `self` (to within a micrometre).
    pub(crate) fn contains(&self, other: &Rect2) -> bool {
        other.min.x >= self.min.x - 1e-6
            && other.min.y >= self.min.y - 1e-6
            && other.max.x <= self.max.x + 1e-6
            && other.max.y <= self.max.y + 1e-6
    }
}

/// Footprint of a `width` x `depth` object (local x by local y) centred at `center` and
/// turned by `yaw`: the bounding rectangle of the turned object.
pub(crate) fn footprint(center: Vec2, width: f32, depth: f32, yaw: f32) -> Rect2 {
    let (s, c) = yaw.sin_cos();
    let (s, c) = (snap(s), snap(c));
    let half =
        Vec2::new((c * width).abs() * 0.5 + (s * depth).abs() * 0.5, (s * width).abs() * 0.5 + (c * depth).abs() * 0.5);
    Rect2::new(center - half, center + half)
}

/// Rounds sines and cosines of quarter turns to exact 0 and ±1.
fn snap(x: f32) -> f32 {
    if x.abs() < 1e-6 {
        0.0
    } else if (x.abs() - 1.0).abs() < 1e-6 {
        x.signum()
    } else {
        x
    }
}

/// One wall of the room, in the frame described in the module documentation.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Wall {
    /// Corner where s = 0 (floor level).
    pub(crate) start: Vec2,
    /// Unit direction of increasing s.
    pub(crate) dir: Vec2,
    /// Unit inward normal.
    pub(crate) normal: Vec2,
    /// Yaw of the wall frame (quarter turns).
    pub(crate) yaw: f32,
    pub(crate) length: f32,
}

impl Wall {
    /// Floor point at `s` along the wall and `t` into the room.
    pub(crate) fn point(&self, s: f32, t: f32) -> Vec2 {
        self.start + self.dir * s + self.normal * t
    }
}

/// A piece of wall taken by something: `s0..s1` along it, `z0..z1` high.
#[derive(Debug, Clone, Copy)]
struct Span {
    s0: f32,
    s1: f32,
    z0: f32,
    z1: f32,
}

/// Where [`Layout::wall_slot`] found room: wall index, position along the wall, centre of
/// the footprint and yaw that makes local +y face into the room.
#[derive(Debug, Clone, Copy)]
pub(crate) struct WallSlot {
    pub(crate) wall: usize,
    pub(crate) s: f32,
    pub(crate) center: Vec2,
    pub(crate) yaw: f32,
}

/// The occupancy of a room being furnished.
pub(crate) struct Layout {
    pub(crate) width: f32,
    pub(crate) depth: f32,
    pub(crate) height: f32,
    pub(crate) walls: [Wall; 4],
    spans: [Vec<Span>; 4],
    /// Footprints of furniture, columns and other things standing on the floor.
    pub(crate) obstacles: Vec<Rect2>,
    keepouts: Vec<Rect2>,
    /// Centres of things worth looking at.
    pub(crate) interest: Vec<Vec3>,
}

/// Gap kept between footprints so that they never touch (and a camera path can tell them
/// apart).
pub(crate) const FLOOR_MARGIN: f32 = 0.04;

impl Layout {
    pub(crate) fn new(width: f32, depth: f32, height: f32) -> Self {
        use std::f32::consts::FRAC_PI_2;
        let walls = [
            Wall { start: Vec2::ZERO, dir: Vec2::X, normal: Vec2::Y, yaw: 0.0, length: width },
            Wall { start: Vec2::new(width, 0.0), dir: Vec2::Y, normal: -Vec2::X, yaw: FRAC_PI_2, length: depth },
            Wall {
                start: Vec2::new(width, depth),
                dir: -Vec2::X,
                normal: -Vec2::Y,
                yaw: 2.0 * FRAC_PI_2,
                length: width,
            },
            Wall { start: Vec2::new(0.0, depth), dir: -Vec2::Y, normal: Vec2::X, yaw: 3.0 * FRAC_PI_2, length: depth },
        ];
        Self {
            width,
            depth,
            height,
            walls,
            spans: Default::default(),
            obstacles: Vec::new(),
            keepouts: Vec::new(),
            interest: Vec::new(),
        }
    }

    pub(crate) fn floor(&self) -> Rect2 {
        Rect2::new(Vec2::ZERO, Vec2::new(self.width, self.depth))
    }

    /// Whether `s0..s1` x `z0..z1` on wall `k` is inside the wall and clear of every span
    /// (grown by `margin` along the wall).
    pub(crate) fn wall_free(&self, k: usize, s0: f32, s1: f32, z0: f32, z1: f32, margin: f32) -> bool {
        s0 >= 0.0
            && s1 <= self.walls[k].length
            && self.spans[k].iter().all(|sp| s1 + margin <= sp.s0 || s0 - margin >= sp.s1 || z1 <= sp.z0 || z0 >= sp.z1)
    }

    pub(crate) fn reserve_wall(&mut self, k: usize, s0: f32, s1: f32, z0: f32, z1: f32) {
        self.spans[k].push(Span { s0, s1, z0, z1 });
    }

    /// Whether footprint `r` is inside the floor and clear of obstacles and keep-out zones.
    pub(crate) fn floor_free(&self, r: &Rect2) -> bool {
        self.floor().contains(r)
            && self.obstacles.iter().all(|o| !o.overlaps(r, FLOOR_MARGIN))
            && self.keepouts.iter().all(|o| !o.overlaps(r, 0.0))
    }

    pub(crate) fn add_obstacle(&mut self, r: Rect2) {
        self.obstacles.push(r);
    }

    pub(crate) fn add_keepout(&mut self, r: Rect2) {
        self.keepouts.push(r);
    }

    /// Searches `walls` for room for a `width` x `depth` object standing `gap` off the wall,
    /// taking the wall from the floor to `z_top`; `tries` random positions. Does not reserve.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn wall_slot(
        &self,
        rng: &mut ChaCha8Rng,
        walls: &[usize],
        width: f32,
        depth: f32,
        gap: f32,
        z_top: f32,
        tries: usize,
    ) -> Option<WallSlot> {
        if walls.is_empty() {
            return None;
        }
        for _ in 0..tries {
            let k = walls[rng.random_range(0..walls.len())];
            let wall = self.walls[k];
            if wall.length < width {
                continue;
            }
            let s = uniform(rng, width * 0.5, wall.length - width * 0.5);
            if let Some(slot) = self.wall_slot_at(k, s, width, depth, gap, z_top) {
                return Some(slot);
            }
        }
        None
    }

    /// [`wall_slot`](Self::wall_slot) at one given position.
    pub(crate) fn wall_slot_at(
        &self,
        k: usize,
        s: f32,
        width: f32,
        depth: f32,
        gap: f32,
        z_top: f32,
    ) -> Option<WallSlot> {
        let wall = self.walls[k];
        let center = wall.point(s, gap + depth * 0.5);
        let r = footprint(center, width, depth, wall.yaw);
        (self.wall_free(k, s - width * 0.5, s + width * 0.5, 0.0, z_top, 0.02) && self.floor_free(&r))
            .then_some(WallSlot { wall: k, s, center, yaw: wall.yaw })
    }

    /// Takes a wall slot: the wall span up to `z_top` and the footprint.
    pub(crate) fn take_wall_slot(&mut self, slot: &WallSlot, width: f32, depth: f32, z_top: f32) {
        self.reserve_wall(slot.wall, slot.s - width * 0.5, slot.s + width * 0.5, 0.0, z_top);
        self.add_obstacle(footprint(slot.center, width, depth, slot.yaw));
        self.interest.push(slot.center.extend(z_top * 0.5));
    }

    /// Searches `region` for a free spot for a `width` x `depth` object turned by `yaw`,
    /// keeping `clearance` around it; `tries` random positions. Does not reserve.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn free_slot(
        &self,
        rng: &mut ChaCha8Rng,
        region: Rect2,
        width: f32,
        depth: f32,
        yaw: f32,
        clearance: f32,
        tries: usize,
    ) -> Option<Vec2> {
        let half = footprint(Vec2::ZERO, width, depth, yaw).max;
        for _ in 0..tries {
            let lo = region.min + half + Vec2::splat(clearance);
            let hi = region.max - half - Vec2::splat(clearance);
            if lo.x > hi.x || lo.y > hi.y {
                return None;
            }
            let c = Vec2::new(uniform(rng, lo.x, hi.x), uniform(rng, lo.y, hi.y));
            let r = footprint(c, width + 2.0 * clearance, depth + 2.0 * clearance, yaw);
            if self.floor_free(&footprint(c, width, depth, yaw)) && self.obstacles.iter().all(|o| !o.overlaps(&r, 0.0))
            {
                return Some(c);
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walls_face_into_the_room() {
        let l = Layout::new(6.0, 4.0, 3.0);
        let c = Vec2::new(3.0, 2.0);
        for w in &l.walls {
            let mid = w.point(w.length * 0.5, 0.0);
            assert!((c - mid).dot(w.normal) > 0.0);
            let frame = super::super::shapes::world_from_object(w.start.extend(0.0), w.yaw);
            let x = frame.transform_vector3(Vec3::X);
            let y = frame.transform_vector3(Vec3::Y);
            assert!((x.truncate() - w.dir).length() < 1e-6);
            assert!((y.truncate() - w.normal).length() < 1e-6);
            let end = w.point(w.length, 0.0);
            assert!(end.x.abs() < 1e-6 || (end.x - 6.0).abs() < 1e-6);
            assert!(end.y.abs() < 1e-6 || (end.y - 4.0).abs() < 1e-6);
        }
    }

    #[test]
    fn footprints_turn_with_the_object() {
        let r = footprint(Vec2::new(1.0, 1.0), 2.0, 0.5, std::f32::consts::FRAC_PI_2);
        assert_eq!(r, Rect2::new(Vec2::new(0.75, 0.0), Vec2::new(1.25, 2.0)));
    }
}
