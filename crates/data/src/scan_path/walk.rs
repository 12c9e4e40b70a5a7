//! The walking route of a scan, a closed loop through free space: in one room, once round
//! an ellipse about the middle of the floor; through a flat ([`ScanPlan::rooms`]), round a
//! smaller ellipse in each room in turn, from room to room along the shortest way with the
//! clearance (through doorways: walls are obstacles of the floor grid, so a route can only
//! pass where a doorway leaves the clearance), and back to the start in the first room.
//! Waypoints are snapped into free space, joined by shortest grid routes, and the loop is
//! smoothed without giving up the clearance.

use std::f32::consts::TAU;

use glam::Vec2;

use super::grid::{smooth_loop, ClearanceGrid, Polyline};
use super::{ScanPlan, CELL};

impl ScanPlan {
    /// The closed walking loop through free space.
    pub(super) fn walk(&self, grid: &ClearanceGrid) -> crate::Result<Polyline> {
        let room = &self.room;
        // Planned with a margin, so that smoothing has room to cut corners.
        let want = self.clearance + 2.0 * CELL;
        let no_space = || {
            crate::DataError::InvalidArgument(format!(
                "no floor space {} m away from walls and obstacles in {:?}..{:?}",
                self.clearance, room.floor_min, room.floor_max
            ))
        };
        if self.rooms.is_empty() {
            let waypoints = self.ring(grid, room.floor_min, room.floor_max, want, None, None);
            let &start = waypoints.first().ok_or_else(no_space)?;
            let (cells, _) = self.route_through(grid, start, &waypoints[1..]);
            return Ok(self.smoothed(grid, &cells));
        }
        // Round each room in turn, each ring starting where the last one ended, on the floor
        // that is all one piece (not in a pocket between furniture, which a route could
        // not reach).
        let reachable = grid.largest_component(self.clearance);
        let mut rings: Vec<Vec<usize>> = Vec::with_capacity(self.rooms.len());
        let mut last = None;
        for (i, &(lo, hi)) in self.rooms.iter().enumerate() {
            if !(lo.cmplt(hi).all() && lo.is_finite() && hi.is_finite()) {
                return Err(crate::DataError::InvalidArgument(format!("room {i} of the walk, {lo}..{hi}, is empty")));
            }
            let ring = self.ring(grid, lo, hi, want, last, Some(&reachable));
            if ring.is_empty() {
                return Err(crate::DataError::InvalidArgument(format!(
                    "room {i} of the walk ({lo}..{hi}) has no floor {} m away from walls and obstacles",
                    self.clearance
                )));
            }
            last = ring.last().map(|&c| grid.centre(c));
            rings.push(ring);
        }
        let all: Vec<usize> = rings.iter().flatten().copied().collect();
        let start = all[0];
        let (cells, reached) = self.route_through(grid, start, &all[1..]);
        // Every room must be reached: a doorway narrower than twice the clearance, or a room
        // cut off by furniture, would otherwise quietly drop out of the scan.
        let mut offset = 0;
        for (i, ring) in rings.iter().enumerate() {
            let here = offset..offset + ring.len();
            offset += ring.len();
            if !here.clone().any(|k| k == 0 || reached[k - 1]) {
                return Err(crate::DataError::InvalidArgument(format!(
                    "room {i} of the walk cannot be reached from the first with {} m of clearance",
                    self.clearance
                )));
            }
        }
        Ok(self.smoothed(grid, &cells))
    }

    /// Twelve waypoints on an ellipse about the middle of the floor rectangle `lo..hi`
    /// (half its size, less near walls), snapped to the nearest cells with `want` clearance
    /// (or at least the plan's), among the cells of `mask` if given; when `start_near` is
    /// given, the ring begins at the waypoint nearest to it.
    fn ring(
        &self,
        grid: &ClearanceGrid,
        lo: Vec2,
        hi: Vec2,
        want: f32,
        start_near: Option<Vec2>,
        mask: Option<&[bool]>,
    ) -> Vec<usize> {
        let centre = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        let semi = (half * 0.5).min(half - Vec2::splat(want)).max(Vec2::ZERO);
        let mut waypoints: Vec<usize> = Vec::new();
        for i in 0..12 {
            let a = i as f32 / 12.0 * TAU;
            let p = centre + semi * Vec2::new(a.cos(), a.sin());
            let snapped = match mask {
                None => grid.nearest_with(p, want).or_else(|| grid.nearest_with(p, self.clearance)),
                // Only on this room's floor: the nearest reachable cell may be next door.
                Some(mask) => {
                    let inside: Vec<bool> = (0..mask.len())
                        .map(|c| mask[c] && grid.centre(c).cmpge(lo).all() && grid.centre(c).cmple(hi).all())
                        .collect();
                    grid.nearest_in(p, want, &inside).or_else(|| grid.nearest_in(p, self.clearance, &inside))
                }
            };
            if let Some(cell) = snapped {
                if waypoints.last() != Some(&cell) {
                    waypoints.push(cell);
                }
            }
        }
        if let Some(p) = start_near {
            let first = (0..waypoints.len())
                .min_by(|&a, &b| {
                    let (da, db) = (grid.centre(waypoints[a]).distance(p), grid.centre(waypoints[b]).distance(p));
                    da.total_cmp(&db)
                })
                .unwrap_or(0);
            waypoints.rotate_left(first);
        }
        waypoints
    }

    /// Cells of the route from `start` through `waypoints` and back to `start`; a waypoint
    /// that cannot be reached is left out. Also says which waypoints were reached.
    fn route_through(&self, grid: &ClearanceGrid, start: usize, waypoints: &[usize]) -> (Vec<usize>, Vec<bool>) {
        let mut cells = vec![start];
        let mut reached = Vec::with_capacity(waypoints.len());
        let mut from = start;
        for &to in waypoints.iter().chain(std::iter::once(&start)) {
            let route = grid.route(from, to, self.clearance);
            reached.push(route.is_some());
            if let Some(route) = route {
                cells.extend(route.into_iter().skip(1));
                from = to;
            }
        }
        reached.pop();
        (cells, reached)
    }

    fn smoothed(&self, grid: &ClearanceGrid, cells: &[usize]) -> Polyline {
        let raw: Vec<Vec2> = cells.iter().map(|&c| grid.centre(c)).collect();
        Polyline::closed(smooth_loop(&raw, grid, self.clearance))
    }
}
