//! The planner's floor grid: clearance (distance to walls and obstacle footprints) on 5 cm
//! cells, shortest routes through cells with enough of it, smoothing of a closed route that
//! never gives the clearance up, and arc-length lookup along the result. Shared by the
//! single-room walk and the walk through the rooms of a flat (`walk`).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::{Vec2, Vec3};

use super::{RoomLayout, CELL};

/// Distance to walls and obstacle footprints on a floor grid.
pub(super) struct ClearanceGrid {
    pub(super) origin: Vec2,
    pub(super) nx: usize,
    ny: usize,
    clearance: Vec<f32>,
}

impl ClearanceGrid {
    pub(super) fn new(room: &RoomLayout) -> Self {
        let size = room.floor_max - room.floor_min;
        let nx = ((size.x / CELL).ceil() as usize).max(1);
        let ny = ((size.y / CELL).ceil() as usize).max(1);
        let mut clearance = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                let p = room.floor_min + Vec2::new((i as f32 + 0.5) * CELL, (j as f32 + 0.5) * CELL);
                clearance.push(clearance_at(room, p));
            }
        }
        Self { origin: room.floor_min, nx, ny, clearance }
    }

    /// The 8-connected neighbours of cell `c` inside the grid, each with whether the step
    /// to it is diagonal.
    fn neighbours(&self, c: usize) -> impl Iterator<Item = (usize, bool)> + '_ {
        let (ci, cj) = ((c % self.nx) as i64, (c / self.nx) as i64);
        [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)].into_iter().filter_map(
            move |(di, dj): (i64, i64)| {
                let (i, j) = (ci + di, cj + dj);
                let inside = i >= 0 && j >= 0 && i < self.nx as i64 && j < self.ny as i64;
                inside.then(|| (j as usize * self.nx + i as usize, di != 0 && dj != 0))
            },
        )
    }

    pub(super) fn centre(&self, c: usize) -> Vec2 {
        self.origin + Vec2::new(((c % self.nx) as f32 + 0.5) * CELL, ((c / self.nx) as f32 + 0.5) * CELL)
    }

    /// The cell nearest to `p` with at least `min_clearance`.
    pub(super) fn nearest_with(&self, p: Vec2, min_clearance: f32) -> Option<usize> {
        (0..self.clearance.len())
            .filter(|&c| self.clearance[c] >= min_clearance)
            .min_by(|&a, &b| self.centre(a).distance_squared(p).total_cmp(&self.centre(b).distance_squared(p)))
    }

    /// The largest 8-connected set of cells with at least `min_clearance`, as a mask: the
    /// floor a walk can reach everywhere in, leaving out pockets between furniture.
    pub(super) fn largest_component(&self, min_clearance: f32) -> Vec<bool> {
        let n = self.clearance.len();
        let mut label = vec![usize::MAX; n];
        let (mut best, mut best_size) = (usize::MAX, 0);
        let mut stack = Vec::new();
        for seed in 0..n {
            if label[seed] != usize::MAX || self.clearance[seed] < min_clearance {
                continue;
            }
            let mut size = 0;
            label[seed] = seed;
            stack.push(seed);
            while let Some(c) = stack.pop() {
                size += 1;
                for (nb, _) in self.neighbours(c) {
                    if label[nb] == usize::MAX && self.clearance[nb] >= min_clearance {
                        label[nb] = seed;
                        stack.push(nb);
                    }
                }
            }
            if size > best_size {
                (best, best_size) = (seed, size);
            }
        }
        label.iter().map(|&l| l == best && best != usize::MAX).collect()
    }

    /// The cell nearest to `p` with at least `min_clearance` among the cells of `mask`.
    pub(super) fn nearest_in(&self, p: Vec2, min_clearance: f32, mask: &[bool]) -> Option<usize> {
        (0..self.clearance.len())
            .filter(|&c| mask[c] && self.clearance[c] >= min_clearance)
            .min_by(|&a, &b| self.centre(a).distance_squared(p).total_cmp(&self.centre(b).distance_squared(p)))
    }

    /// Shortest 8-connected route between two cells through cells with at least
    /// `min_clearance`, preferring more clearance; `None` when unreachable.
    pub(super) fn route(&self, from: usize, to: usize, min_clearance: f32) -> Option<Vec<usize>> {
        let n = self.clearance.len();
        let mut cost = vec![f32::INFINITY; n];
        let mut prev = vec![usize::MAX; n];
        let mut heap = BinaryHeap::new();
        cost[from] = 0.0;
        heap.push(Reverse((0u64, from)));
        while let Some(Reverse((c_bits, c))) = heap.pop() {
            let c_cost = f32::from_bits(c_bits as u32);
            if c == to {
                break;
            }
            if c_cost > cost[c] {
                continue;
            }
            for (nb, diagonal) in self.neighbours(c) {
                if self.clearance[nb] < min_clearance {
                    continue;
                }
                let step = if diagonal { std::f32::consts::SQRT_2 } else { 1.0 };
                // Slightly cheaper far from obstacles, so routes keep to the middle.
                let new_cost = c_cost + step * (1.0 + 0.3 / (1.0 + self.clearance[nb]));
                if new_cost < cost[nb] {
                    cost[nb] = new_cost;
                    prev[nb] = c;
                    // Non-negative floats order like their bit patterns.
                    heap.push(Reverse((new_cost.to_bits() as u64, nb)));
                }
            }
        }
        if !cost[to].is_finite() {
            return None;
        }
        let mut route = vec![to];
        let mut c = to;
        while c != from {
            c = prev[c];
            route.push(c);
        }
        route.reverse();
        Some(route)
    }

    /// How far the camera at `eye` sees along `forward` (unit, z up) before it meets a wall
    /// or an obstacle footprint (treated as reaching the ceiling: the planner knows no
    /// heights), the floor at `floor_z` or the ceiling at `ceiling_z`, up to `max_range`
    /// metres. Marched on the floor grid in half-cell steps, so good to about 3 cm.
    pub(super) fn view_range(&self, eye: Vec3, forward: Vec3, floor_z: f32, ceiling_z: f32, max_range: f32) -> f32 {
        let mut range = max_range;
        if forward.z < -1e-6 {
            range = range.min((eye.z - floor_z) / -forward.z);
        } else if forward.z > 1e-6 {
            range = range.min((ceiling_z - eye.z) / forward.z);
        }
        let plan = forward.truncate();
        let plan_len = plan.length();
        if plan_len < 1e-6 {
            return range.max(0.0);
        }
        let dir = plan / plan_len;
        let end = self.origin + Vec2::new(self.nx as f32, self.ny as f32) * CELL;
        let step = 0.5 * CELL;
        let mut d = 0.0;
        // `d` is the distance in plan; the ray's own length is d / plan_len.
        while d / plan_len < range {
            let p = eye.truncate() + dir * d;
            if p.cmplt(self.origin).any() || p.cmpgt(end).any() || self.at(p) <= 0.0 {
                return (d / plan_len).min(range);
            }
            d += step;
        }
        range.max(0.0)
    }

    /// Clearance at `p`, from the nearest cell.
    pub(super) fn at(&self, p: Vec2) -> f32 {
        let q = (p - self.origin) / CELL;
        let i = (q.x.max(0.0) as usize).min(self.nx - 1);
        let j = (q.y.max(0.0) as usize).min(self.ny - 1);
        self.clearance[j * self.nx + i]
    }
}

/// Distance from `p` to the walls and the nearest obstacle footprint (0 inside one).
pub(super) fn clearance_at(room: &RoomLayout, p: Vec2) -> f32 {
    let wall = (p - room.floor_min).min(room.floor_max - p).min_element();
    room.obstacles.iter().fold(wall, |acc, (lo, hi)| {
        let d = (*lo - p).max(p - *hi).max(Vec2::ZERO);
        acc.min(d.length())
    })
}

/// Smooths a closed polyline by repeated circular averaging over about half a metre, then
/// pulls back towards the unsmoothed route wherever the clearance would drop below
/// `min_clearance` - one cell (the grid's resolution).
pub(super) fn smooth_loop(raw: &[Vec2], grid: &ClearanceGrid, min_clearance: f32) -> Vec<Vec2> {
    let n = raw.len();
    if n < 3 {
        return raw.to_vec();
    }
    let half_window = 5usize.min((n - 1) / 2);
    let mut pts = raw.to_vec();
    for _ in 0..3 {
        pts = (0..n)
            .map(|i| {
                let sum = (0..=2 * half_window).fold(Vec2::ZERO, |acc, k| acc + pts[(i + n + k - half_window) % n]);
                sum / (2 * half_window + 1) as f32
            })
            .collect();
    }
    let limit = min_clearance - CELL;
    for (p, &r) in pts.iter_mut().zip(raw) {
        let mut t = 1.0;
        while t > 0.0 && grid.at(r.lerp(*p, t)) < limit {
            t -= 0.25;
        }
        *p = r.lerp(*p, t.max(0.0));
    }
    pts
}

/// A closed polyline with arc-length lookup.
pub(super) struct Polyline {
    points: Vec<Vec2>,
    /// Distance from the start to each point; the last entry closes the loop.
    arc: Vec<f32>,
}

impl Polyline {
    pub(super) fn closed(mut points: Vec<Vec2>) -> Self {
        points.dedup_by(|a, b| a.distance(*b) < 1e-4);
        if let Some(&first) = points.first() {
            points.push(first);
        }
        let mut arc = vec![0.0];
        for w in points.windows(2) {
            arc.push(arc.last().copied().unwrap_or(0.0) + w[0].distance(w[1]));
        }
        Self { points, arc }
    }

    pub(super) fn length(&self) -> f32 {
        self.arc.last().copied().unwrap_or(0.0)
    }

    pub(super) fn at(&self, s: f32) -> Vec2 {
        if self.points.len() < 2 {
            return self.points.first().copied().unwrap_or(Vec2::ZERO);
        }
        let s = s.clamp(0.0, self.length());
        let i = self.arc.partition_point(|&a| a <= s).clamp(1, self.points.len() - 1);
        let (a, b) = (self.arc[i - 1], self.arc[i]);
        let t = if b > a { (s - a) / (b - a) } else { 0.0 };
        self.points[i - 1].lerp(self.points[i], t)
    }
}
