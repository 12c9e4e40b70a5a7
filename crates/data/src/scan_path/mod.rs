//! Generated handheld-like camera trajectories through a room, for rendering synthetic
//! RGB-D scans whose motion looks like a person scanning: walking a loop through free space
//! at 0.3-0.5 m/s, eye height with a slight bob, gaze drifting between walls and furniture
//! (sometimes down at tables and the floor, sometimes up), small smooth hand jitter, and
//! back to the start pose at the end so that loop closure can be tested. The gaze does not
//! face a wall or tall furniture from closer than 0.6 m (the sensor sees nothing within
//! 0.4 m): where it would, it turns to the nearest direction that sees further, across the
//! room rather than over the wall in front of it. Speeds stay within what frame-to-frame
//! tracking at 30 fps handles (below 40 degrees/s).
//!
//! The walk: a clearance grid of the floor (distance to walls and obstacle footprints,
//! `grid`), waypoints on an ellipse around the room centre snapped into free space, shortest
//! grid paths between them, then smoothing that never gives up the clearance (`walk`). A
//! scan through a flat ([`ScanPlan::rooms`]) walks such a loop in every room in turn and
//! passes from room to room through the doorways.

use std::f32::consts::{PI, TAU};

use glam::{Affine3A, Mat3, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::mesh::LabeledMesh;

mod grid;
mod walk;

#[cfg(test)]
use grid::clearance_at;
use grid::ClearanceGrid;

/// What a scan planner needs to know about a room (world frame, z up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RoomLayout {
    /// Floor rectangle corner with the smallest x and y, metres.
    pub floor_min: Vec2,
    /// Floor rectangle corner with the largest x and y, metres.
    pub floor_max: Vec2,
    /// Height of the floor (0 in generated rooms).
    pub floor_z: f32,
    /// Ceiling height above the floor, metres.
    pub ceiling_height: f32,
    /// Footprints of furniture the camera must walk around, as (min, max) corners.
    pub obstacles: Vec<(Vec2, Vec2)>,
    /// Points worth looking at (furniture, wall features); may be empty.
    pub interest_points: Vec<Vec3>,
    /// Footprints of what rises above the camera (walls between rooms; usually also among
    /// `obstacles`): what the gaze keeps [`ScanPlan::min_view_distance`] from, besides the
    /// floor rectangle's sides. Lower furniture is looked over, not dodged.
    #[serde(default)]
    pub tall_obstacles: Vec<(Vec2, Vec2)>,
}

/// Height above the floor from which a thing counts as tall for the gaze (see
/// [`RoomLayout::find_tall_obstacles`]), metres: a ray 20-50 degrees below the horizon from a
/// 1.45 m eye has come down to 1.0-1.25 m after 0.6 m, so what stays under 1 m is looked over.
pub const TALL_OBSTACLE_TOP: f32 = 1.0;

impl RoomLayout {
    /// Adds to [`Self::tall_obstacles`] every obstacle whose footprint (grown by a centimetre,
    /// so that a box's corners count) holds a vertex of `mesh` more than `min_top` above the
    /// floor, leaving out the room's shell (ceiling, floor, walls, beams, windows and boards,
    /// whose vertices may fall inside a footprint against a wall). A mesh without
    /// vertex labels counts every vertex.
    pub fn find_tall_obstacles(&mut self, mesh: &LabeledMesh, min_top: f32) {
        use crate::class::SemanticClass as C;
        // Doors count: a door standing open into the room is a leaf the height of a person.
        let shell = [C::Ceiling, C::Floor, C::Wall, C::Beam, C::Window, C::Board].map(|c| c.id());
        let labelled = mesh.vertex_labels.len() == mesh.positions.len();
        let grow = Vec2::splat(0.01);
        let mut tall = vec![false; self.obstacles.len()];
        for (v, p) in mesh.positions.iter().enumerate() {
            if p.z - self.floor_z <= min_top || (labelled && shell.contains(&mesh.vertex_labels[v])) {
                continue;
            }
            let q = p.truncate();
            for (k, (lo, hi)) in self.obstacles.iter().enumerate() {
                if !tall[k] && q.cmpge(*lo - grow).all() && q.cmple(*hi + grow).all() {
                    tall[k] = true;
                }
            }
        }
        self.tall_obstacles.extend(self.obstacles.iter().zip(tall).filter(|(_, t)| *t).map(|(o, _)| *o));
    }
}

/// Parameters of a generated scan; [`ScanPlan::poses`] makes the trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanPlan {
    /// The room to walk through.
    pub room: RoomLayout,
    /// Seed of every random choice (gaze targets, jitter).
    pub seed: u64,
    /// Frames per second of the trajectory.
    pub frame_rate: f32,
    /// Top walking speed, m/s.
    pub walking_speed: f32,
    /// Camera height above the floor, metres (bobs by about a centimetre while walking).
    pub eye_height: f32,
    /// Smallest distance kept from walls and obstacle footprints, metres.
    pub clearance: f32,
    /// Top turning speed of the gaze, degrees per second (hand jitter adds a little).
    pub max_turn_rate_deg: f32,
    /// Scale of the hand jitter (1 = a steady hand, 0 = none).
    pub jitter: f32,
    /// Amplitude of a slow nod added to the gaze's pitch, degrees (0 = none): the camera
    /// tilts up by this much and down by half of it about every 8 s, as someone mapping a
    /// room sweeps the walls from floor to ceiling. Casual scans (the default) look level or down and rarely
    /// see the top third of a wall, where doors and boards end.
    pub vertical_sweep_deg: f32,
    /// Rooms to walk through, in this order, as floor rectangles `(min, max)`; empty for a
    /// single room. With rooms, [`Self::room`] describes the whole floor plan (its
    /// rectangle bounds every room; walls between rooms are among its obstacles), the walk
    /// goes round each room in turn and from room to room through the doorways the free
    /// space leaves, then back to its start, and the gaze picks points in the room the
    /// camera is in (see the `walk` module).
    #[serde(default)]
    pub rooms: Vec<(Vec2, Vec2)>,
    /// Nearest a surface may come along the camera's optical axis, metres (0 = no limit):
    /// where the gaze would face a wall or tall furniture closer than this, now or a second
    /// later, it turns to the nearest direction that sees further (see [`Self::view_ranges`]).
    /// A walk with little clearance (a flat's doorways and corridors) otherwise stares at a
    /// wall from inside the depth sensor's minimum range, and a scan with no depth for
    /// seconds is not what a person scanning a room records.
    #[serde(default)]
    pub min_view_distance: f32,
}

/// Steepest gaze below the horizon, radians (50 degrees).
const MAX_PITCH_DOWN: f32 = 50.0 * std::f32::consts::PI / 180.0;
/// Steepest gaze above the horizon, radians (20 degrees).
const MAX_PITCH_UP: f32 = 20.0 * std::f32::consts::PI / 180.0;

/// Steepest gaze above the horizon with a vertical sweep, radians (55 degrees).
const MAX_SWEPT_PITCH_UP: f32 = 55.0 * std::f32::consts::PI / 180.0;

/// [`ScanPlan::min_view_distance`] of a new plan, metres: half again the sensor model's
/// 0.4 m minimum range, so that the centre of the image has depth with room to spare.
pub const DEFAULT_MIN_VIEW_DISTANCE: f32 = 0.6;

/// Fastest the gaze turns away from a surface it faces too closely, as a multiple of
/// [`ScanPlan::max_turn_rate_deg`] (22 -> 35 degrees/s by default, still below the 40
/// degrees/s frame-to-frame tracking handles).
const DODGE_TURN_FACTOR: f32 = 1.6;

/// Floor grid resolution of the planner, metres.
const CELL: f32 = 0.05;

impl ScanPlan {
    /// A plan with the defaults: 30 fps, 0.4 m/s, eye at 1.45 m, 0.4 m clearance, gaze
    /// turning at most 22 degrees/s, steady hand.
    pub fn new(room: RoomLayout, seed: u64) -> Self {
        Self {
            room,
            seed,
            frame_rate: 30.0,
            walking_speed: 0.4,
            eye_height: 1.45,
            clearance: 0.4,
            max_turn_rate_deg: 22.0,
            jitter: 1.0,
            vertical_sweep_deg: 0.0,
            rooms: Vec::new(),
            min_view_distance: DEFAULT_MIN_VIEW_DISTANCE,
        }
    }

    /// A plan for an arbitrary mesh with z up: the floor is the bounding box's footprint at
    /// its lowest z, without obstacles; the walk is an ellipse around the centre, looking
    /// outward at points on the bounding box's sides.
    pub fn from_mesh_bounds(mesh: &LabeledMesh, seed: u64) -> crate::Result<Self> {
        let (lo, hi) = mesh
            .bounds()
            .ok_or_else(|| crate::DataError::InvalidArgument("cannot plan a scan of an empty mesh".into()))?;
        let centre = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        let height = hi.z - lo.z;
        let look_z = lo.z + (1.1f32).min(height * 0.5);
        let interest_points = (0..12)
            .map(|i| {
                let a = i as f32 / 12.0 * TAU;
                let dir = Vec2::new(a.cos(), a.sin());
                // Where the ray from the centre leaves the footprint.
                let t = (half.x / dir.x.abs().max(1e-6)).min(half.y / dir.y.abs().max(1e-6));
                Vec3::new(centre.x + dir.x * t, centre.y + dir.y * t, look_z)
            })
            .collect();
        let mut plan = Self::new(
            RoomLayout {
                floor_min: lo.truncate(),
                floor_max: hi.truncate(),
                floor_z: lo.z,
                ceiling_height: height,
                obstacles: Vec::new(),
                interest_points,
                tall_obstacles: Vec::new(),
            },
            seed,
        );
        plan.clearance = plan.clearance.min(0.25 * half.x.min(half.y));
        Ok(plan)
    }

    /// How far each `world_from_camera` pose sees along its optical axis in the planner's
    /// model of the room (the floor rectangle's sides and the tall obstacles' footprints as
    /// full-height boxes, the floor and the ceiling), up to `max_range` metres: what
    /// [`Self::min_view_distance`] bounds from below.
    pub fn view_ranges(&self, poses: &[Affine3A], max_range: f32) -> Vec<f32> {
        let grid = self.view_grid();
        let (floor, ceiling) = (self.room.floor_z, self.room.floor_z + self.room.ceiling_height);
        poses
            .iter()
            .map(|p| grid.view_range(p.translation.into(), p.matrix3.z_axis.into(), floor, ceiling, max_range))
            .collect()
    }

    /// `n` `world_from_camera` poses (camera x right, y down, z forward) at
    /// `frame_rate`; the last equals the first.
    pub fn poses(&self, n: usize) -> crate::Result<Vec<Affine3A>> {
        let room = &self.room;
        let bad = |m: String| Err(crate::DataError::InvalidArgument(m));
        let size = room.floor_max - room.floor_min;
        if !(size.x > 0.0 && size.y > 0.0 && size.is_finite()) {
            return bad(format!("floor rectangle {:?}..{:?} is empty", room.floor_min, room.floor_max));
        }
        if !(self.frame_rate > 0.0 && self.walking_speed > 0.0 && self.max_turn_rate_deg > 0.0) {
            return bad("frame rate, walking speed and turn rate must be positive".into());
        }
        if !(self.min_view_distance >= 0.0 && self.min_view_distance <= 5.0) {
            return bad(format!("minimum view distance {} m is outside 0..=5", self.min_view_distance));
        }
        if !(0.0..=60.0).contains(&self.vertical_sweep_deg) {
            return bad(format!("vertical sweep {} degrees is outside 0..=60", self.vertical_sweep_deg));
        }
        if n == 0 {
            return Ok(Vec::new());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let grid = ClearanceGrid::new(room);
        let path = self.walk(&grid)?;
        let view_grid = self.view_grid();
        let duration = n as f32 / self.frame_rate;
        let dt = 1.0 / self.frame_rate;
        let times: Vec<f32> = (0..n).map(|i| if n > 1 { i as f32 / (n - 1) as f32 } else { 0.0 }).collect();

        // Distance along the path per frame: once round the loop with gentle start and
        // stop when the time allows it, otherwise out along the loop and back.
        let length = path.length();
        let ramp = (2.0 / duration).min(0.2);
        let once_speed = length / duration / (1.0 - ramp);
        let distance: Vec<f32> = if once_speed <= self.walking_speed {
            // Long scans go round several times rather than crawl.
            let laps = if once_speed > 0.0 { (0.8 * self.walking_speed / once_speed).floor().max(1.0) } else { 1.0 };
            let profile: Vec<f32> = times.iter().map(|&u| speed_profile(u, ramp)).collect();
            cumulative(&profile, length * laps)
        } else {
            let reach = self.walking_speed * duration / PI;
            times.iter().map(|&u| reach * (1.0 - (TAU * u).cos()) * 0.5).collect()
        };
        let floor = room.floor_z;
        let eye_z = floor + self.eye_height.min(room.ceiling_height - 0.25).max(0.5f32.min(room.ceiling_height * 0.5));
        let positions: Vec<Vec3> = distance
            .iter()
            .map(|&s| {
                let on_loop = if length > 0.0 { s % length } else { 0.0 };
                // The end of the last lap is the start, whatever the rounding.
                let on_loop = if length - on_loop < 1e-4 { 0.0 } else { on_loop };
                path.at(on_loop).extend(eye_z)
            })
            .collect();

        // Walking direction (for choosing what to look at), and bobbing with the steps.
        let heading: Vec<Vec2> = (0..n)
            .map(|i| {
                let a = positions[i.saturating_sub(3)].truncate();
                let b = positions[(i + 3).min(n - 1)].truncate();
                (b - a).try_normalize().unwrap_or(Vec2::X)
            })
            .collect();
        let speeds: Vec<f32> = (0..n)
            .map(|i| {
                let a = distance[i.saturating_sub(1)];
                let b = distance[(i + 1).min(n - 1)];
                (b - a).abs() / (dt * ((i + 1).min(n - 1) - i.saturating_sub(1)).max(1) as f32)
            })
            .collect();
        let mut step_phase = 0.0f32;
        let mut eye: Vec<Vec3> = Vec::with_capacity(n);
        for i in 0..n {
            // About 1.8 steps/s at full speed; the bob fades as the walk slows down.
            let rel = (speeds[i] / self.walking_speed).min(1.0);
            step_phase += TAU * 1.8 * rel * dt;
            eye.push(positions[i] + Vec3::Z * (0.012 * rel * step_phase.sin()));
        }

        // Gaze: a target point moving smoothly between chosen points of interest.
        let targets = self.gaze_targets(&mut rng, &eye, &heading, duration);
        let mut yaw_pitch: Vec<Vec2> = Vec::with_capacity(n);
        let max_step = self.max_turn_rate_deg.to_radians() * dt;
        let nod_height = self.vertical_sweep_deg.to_radians();
        let nod_periods = (duration / 8.0).round().max(1.0);
        for i in 0..n {
            let t = i as f32 * dt;
            let dir = (gaze_target_at(&targets, t) - eye[i]).try_normalize().unwrap_or(heading[i].extend(0.0));
            // Level or down far more than up, as people scan (see `gaze_targets`), also while
            // walking up to a high target.
            let mut want =
                Vec2::new(dir.y.atan2(dir.x), dir.z.clamp(-1.0, 1.0).asin().clamp(-MAX_PITCH_DOWN, MAX_PITCH_UP));
            // The nod: whole sine periods over the scan, so it starts and ends on the gaze and
            // the loop stays closed; added before the turn-rate limit, which bounds both.
            if nod_height > 0.0 {
                let u = if n > 1 { times[i] } else { 0.0 };
                let wave = (TAU * nod_periods * u).sin();
                // Half as far down: the casual gaze already looks down a lot, and views of
                // bare floor alone leave tracking little to hold on to.
                let nod = nod_height * if wave > 0.0 { wave } else { 0.5 * wave };
                want.y = (want.y + nod).clamp(-MAX_PITCH_DOWN, MAX_SWEPT_PITCH_UP);
            }
            let ahead = eye[(i + self.frame_rate as usize).min(n - 1)];
            let prev = yaw_pitch.last().copied();
            if self.min_view_distance > 0.0 {
                want = self.clear_gaze(&view_grid, [eye[i], ahead], want, prev.unwrap_or(want));
            }
            let next = match prev {
                None => want,
                Some(prev) => {
                    // Turn away faster from a surface the camera faces too closely.
                    let blocked =
                        self.min_view_distance > 0.0 && self.sees(&view_grid, eye[i], prev) < self.min_view_distance;
                    let max_step = if blocked { max_step * DODGE_TURN_FACTOR } else { max_step };
                    let mut delta = Vec2::new(wrap_angle(want.x - prev.x), want.y - prev.y);
                    if self.min_view_distance > 0.0 {
                        delta.x = self.clear_turn(&view_grid, eye[i], prev, delta);
                    }
                    let len = delta.length();
                    prev + if len > max_step { delta * (max_step / len) } else { delta }
                }
            };
            yaw_pitch.push(next);
        }
        // Close the loop exactly: spread what is left of the way back to the first gaze
        // over the last seconds.
        let error = Vec2::new(wrap_angle(yaw_pitch[n - 1].x - yaw_pitch[0].x), yaw_pitch[n - 1].y - yaw_pitch[0].y);
        // At most about 5 degrees/s on top of the gaze's own turning.
        let fix_seconds = (error.length().to_degrees() / 5.0).max(3.0);
        let fix_frames = ((fix_seconds * self.frame_rate) as usize).clamp(1, n);
        for (j, yp) in yaw_pitch[n - fix_frames..].iter_mut().enumerate() {
            let u = (j + 1) as f32 / fix_frames as f32;
            *yp -= error * smoothstep(u);
        }
        // Hand jitter: sums of sinusoids with a whole number of periods over the scan, so
        // the jitter ends where it started.
        let jitter_t = PeriodicNoise::new(&mut rng, duration, 0.004 * self.jitter);
        let jitter_r = PeriodicNoise::new(&mut rng, duration, 0.4f32.to_radians() * self.jitter);
        Ok((0..n)
            .map(|i| {
                let t = i as f32 * dt;
                let u = if n > 1 { times[i] * duration } else { t };
                let [yaw, pitch] = yaw_pitch[i].to_array();
                let forward = Vec3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin());
                let right = forward.cross(Vec3::Z).normalize();
                let down = forward.cross(right);
                let r = jitter_r.at(u);
                let shake = Mat3::from_rotation_z(r.z) * Mat3::from_rotation_x(r.x) * Mat3::from_rotation_y(r.y);
                let rotation = Mat3::from_cols(right, down, forward) * shake;
                Affine3A::from_mat3_translation(rotation, eye[i] + jitter_t.at(u))
            })
            .collect())
    }

    /// The floor grid of what the camera cannot see over: the floor rectangle's sides and
    /// the tall obstacles.
    fn view_grid(&self) -> ClearanceGrid {
        ClearanceGrid::new(&RoomLayout { obstacles: self.room.tall_obstacles.clone(), ..self.room.clone() })
    }

    /// How far the camera at `eye` sees with the gaze `yaw_pitch` (radians), in the
    /// planner's model of the room.
    fn sees(&self, grid: &ClearanceGrid, eye: Vec3, yaw_pitch: Vec2) -> f32 {
        let [yaw, pitch] = yaw_pitch.to_array();
        let forward = Vec3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin());
        let floor = self.room.floor_z;
        grid.view_range(eye, forward, floor, floor + self.room.ceiling_height, 2.0 * self.min_view_distance)
    }

    /// `want` if it sees at least [`Self::min_view_distance`] from every one of `eyes`,
    /// otherwise the yaw nearest to it (in 10 degree steps, ties going to the side the gaze
    /// `prev` is on, so that the dodge does not flicker) that does; where none does (a
    /// narrow passage), the yaw that sees furthest.
    fn clear_gaze(&self, grid: &ClearanceGrid, eyes: [Vec3; 2], want: Vec2, prev: Vec2) -> Vec2 {
        let range = |yp: Vec2| eyes.iter().map(|&e| self.sees(grid, e, yp)).fold(f32::INFINITY, f32::min);
        if range(want) >= self.min_view_distance {
            return want;
        }
        let step = 10f32.to_radians();
        let mut best_clear: Option<(f32, Vec2)> = None;
        let mut furthest = (range(want), want);
        for k in 1..=18 {
            for side in [1.0f32, -1.0] {
                let candidate = Vec2::new(wrap_angle(want.x + side * k as f32 * step), want.y);
                let r = range(candidate);
                if r >= self.min_view_distance {
                    let cost = k as f32 * step + 0.5 * wrap_angle(candidate.x - prev.x).abs();
                    if best_clear.is_none_or(|(c, _)| cost < c) {
                        best_clear = Some((cost, candidate));
                    }
                } else if r > furthest.0 {
                    furthest = (r, candidate);
                }
            }
        }
        best_clear.map_or(furthest.1, |(_, c)| c)
    }

    /// The yaw turn from the gaze `prev` by `delta` (yaw within +-pi, pitch) the short way
    /// round, or the long way where that faces fewer surfaces closer than
    /// [`Self::min_view_distance`] on the way: someone walking along a wall who turns from
    /// one side to the other looks across the room, not over the wall in front of their nose.
    fn clear_turn(&self, grid: &ClearanceGrid, eye: Vec3, prev: Vec2, delta: Vec2) -> f32 {
        let step = 10f32.to_radians();
        // Cost of a way: its length in 10 degree steps, and three more for each step that
        // faces a near surface.
        let cost = |yaw_turn: f32, stop_at_first: bool| -> (f32, usize) {
            let steps = (yaw_turn.abs() / step).ceil().max(1.0) as usize;
            let mut blocked = 0;
            for k in 1..=steps {
                let u = k as f32 / steps as f32;
                if self.sees(grid, eye, prev + Vec2::new(yaw_turn, delta.y) * u) < self.min_view_distance {
                    blocked += 1;
                    if stop_at_first {
                        break;
                    }
                }
            }
            (steps as f32 + 3.0 * blocked as f32, blocked)
        };
        if delta.x.abs() < step || cost(delta.x, true).1 == 0 {
            return delta.x;
        }
        let long = delta.x - TAU.copysign(delta.x);
        if cost(long, false).0 < cost(delta.x, false).0 {
            long
        } else {
            delta.x
        }
    }

    /// Gaze targets: (start time, point), each held for a few seconds; the last is the
    /// first again so that the scan ends looking where it began.
    fn gaze_targets(&self, rng: &mut ChaCha8Rng, eye: &[Vec3], heading: &[Vec2], duration: f32) -> Vec<(f32, Vec3)> {
        let room = &self.room;
        let floor = room.floor_z;
        let centre = ((room.floor_min + room.floor_max) * 0.5).extend(floor + 0.8);
        let mut points = room.interest_points.clone();
        if points.is_empty() {
            // Wall middles and room corners at table height.
            let (a, b) = (room.floor_min, room.floor_max);
            let m = (a + b) * 0.5;
            for p in [
                Vec2::new(a.x, m.y),
                Vec2::new(b.x, m.y),
                Vec2::new(m.x, a.y),
                Vec2::new(m.x, b.y),
                a,
                b,
                Vec2::new(a.x, b.y),
                Vec2::new(b.x, a.y),
            ] {
                points.push(p.extend(floor + 1.0));
            }
        }
        let at = |t: f32| ((t * self.frame_rate) as usize).min(eye.len() - 1);
        // In a flat, only the room the camera is in can be seen (the doorway aside): the room
        // holding the eye (its floor grown so that a camera in a doorway still counts), and
        // the points on that room's floor or walls.
        let room_of = |p: Vec2, margin: f32| {
            self.rooms.iter().position(|(lo, hi)| {
                p.cmpge(*lo - Vec2::splat(margin)).all() && p.cmple(*hi + Vec2::splat(margin)).all()
            })
        };
        let choose = |rng: &mut ChaCha8Rng, t: f32| -> Vec3 {
            let e = eye[at(t)];
            let h = heading[at(t)];
            let here = room_of(e.truncate(), 0.35);
            let visible = |p: &Vec3| match here {
                Some(r) => {
                    let (lo, hi) = self.rooms[r];
                    p.truncate().cmpge(lo - Vec2::splat(0.06)).all() && p.truncate().cmple(hi + Vec2::splat(0.06)).all()
                }
                None => true,
            };
            let centre = match here {
                Some(r) => ((self.rooms[r].0 + self.rooms[r].1) * 0.5).extend(floor + 0.8),
                None => centre,
            };
            let roll: f32 = rng.random();
            if roll < 0.15 {
                // Down at a table or the floor ahead.
                let z = if rng.random::<bool>() { floor + 0.75 } else { floor };
                return (e.truncate() + h * 1.2).extend(z);
            }
            if roll < 0.25 {
                // Up at the top of a wall ahead.
                return (e.truncate() + h * 2.0).extend(floor + room.ceiling_height - 0.1);
            }
            // Prefer points ahead, not too close.
            let mut best = centre;
            let mut best_score = f32::NEG_INFINITY;
            for p in points.iter().filter(|p| visible(p)) {
                let d = (*p - e).truncate();
                let dist = d.length();
                if dist < 0.5 {
                    continue;
                }
                let ahead = d.dot(h) / dist;
                let score = ahead + 0.8 * rng.random::<f32>() - 0.05 * dist;
                if score > best_score {
                    best_score = score;
                    best = *p;
                }
            }
            best
        };
        // People scanning a room look level or down far more than up: keep every gaze point
        // between 50 degrees below and 20 degrees above the horizon (beams and wall tops
        // seen from close would otherwise tilt the camera steeply at the ceiling).
        let choose = |rng: &mut ChaCha8Rng, t: f32| -> Vec3 {
            let p = choose(rng, t);
            let e = eye[at(t)];
            let reach = (p - e).truncate().length();
            let z = p.z.clamp(e.z - reach * MAX_PITCH_DOWN.tan(), e.z + reach * MAX_PITCH_UP.tan());
            p.truncate().extend(z)
        };
        // Walking into another room, look round it at once rather than at the last room's
        // point, now behind a wall.
        let mut entries = Vec::new();
        if !self.rooms.is_empty() {
            let mut current = room_of(eye[0].truncate(), 0.0);
            for (i, e) in eye.iter().enumerate() {
                let r = room_of(e.truncate(), 0.0);
                if r.is_some() && r != current {
                    current = r;
                    // Once a little way in, so that the choice sees this room.
                    entries.push(i as f32 / self.frame_rate + 0.3);
                }
            }
        }
        let mut entries = entries.into_iter().peekable();
        let first = choose(rng, 0.0);
        let mut targets = vec![(0.0, first)];
        let mut t = rng.random_range(3.0..5.0);
        while t < duration {
            while let Some(e) = entries.next_if(|&e| e < t) {
                targets.push((e, choose(rng, e)));
            }
            targets.push((t, choose(rng, t)));
            t += rng.random_range(3.0..5.0);
        }
        // Time to turn back (up to 180 degrees at the turn rate) before the end.
        let back = (180.0 / self.max_turn_rate_deg + 2.0).min(duration * 0.3);
        targets.retain(|&(t, _)| t == 0.0 || t < duration - back - 2.0);
        targets.push((duration - back, first));
        targets
    }
}

/// Gaze point at time `t`: each target is reached from the previous one over 1.5 s.
fn gaze_target_at(targets: &[(f32, Vec3)], t: f32) -> Vec3 {
    let mut point = targets.first().map(|p| p.1).unwrap_or(Vec3::ZERO);
    for &(start, p) in targets.iter().skip(1) {
        if t <= start {
            break;
        }
        point = point.lerp(p, smoothstep(((t - start) / 1.5).min(1.0)));
    }
    point
}

/// Relative walking speed at normalised time `u`: smooth ramps of length `ramp` at both
/// ends, 1 in between.
fn speed_profile(u: f32, ramp: f32) -> f32 {
    smoothstep((u / ramp).min(1.0)).min(smoothstep(((1.0 - u) / ramp).min(1.0)))
}

/// Running sum of `rates`, scaled so that it goes from 0 to `total`.
fn cumulative(rates: &[f32], total: f32) -> Vec<f32> {
    let mut acc = 0.0f64;
    let mut out = Vec::with_capacity(rates.len());
    for (i, &r) in rates.iter().enumerate() {
        if i > 0 {
            acc += 0.5 * (r + rates[i - 1]) as f64;
        }
        out.push(acc);
    }
    let scale = if acc > 0.0 { total as f64 / acc } else { 0.0 };
    out.into_iter().map(|s| (s * scale) as f32).collect()
}

fn smoothstep(u: f32) -> f32 {
    let u = u.clamp(0.0, 1.0);
    u * u * (3.0 - 2.0 * u)
}

fn wrap_angle(a: f32) -> f32 {
    (a + PI).rem_euclid(TAU) - PI
}

/// Smooth, periodic 3-D noise: per axis, three sinusoids at 0.2-1.6 Hz with whole periods
/// over `duration`.
struct PeriodicNoise {
    waves: Vec<(Vec3, Vec3, Vec3)>, // (amplitude, angular frequency, phase) per wave
}

impl PeriodicNoise {
    fn new(rng: &mut ChaCha8Rng, duration: f32, amplitude: f32) -> Self {
        let waves = [0.25f32, 0.6, 1.3]
            .iter()
            .map(|&hz| {
                let mut v = || {
                    let cycles = (hz * duration * rng.random_range(0.8..1.25)).round().max(1.0);
                    (amplitude * rng.random_range(0.3..0.6), TAU * cycles / duration, rng.random_range(0.0..TAU))
                };
                let (a, b, c) = (v(), v(), v());
                (Vec3::new(a.0, b.0, c.0), Vec3::new(a.1, b.1, c.1), Vec3::new(a.2, b.2, c.2))
            })
            .collect();
        Self { waves }
    }

    fn at(&self, t: f32) -> Vec3 {
        self.waves.iter().fold(Vec3::ZERO, |acc, (a, w, p)| {
            let phase = *w * t + *p;
            acc + *a * Vec3::new(phase.x.sin(), phase.y.sin(), phase.z.sin())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::SQRT_2;

    fn office() -> RoomLayout {
        RoomLayout {
            floor_min: Vec2::new(0.0, 0.0),
            floor_max: Vec2::new(6.0, 5.0),
            floor_z: 0.0,
            ceiling_height: 2.7,
            obstacles: vec![(Vec2::new(2.4, 2.0), Vec2::new(3.8, 3.0)), (Vec2::new(0.0, 3.8), Vec2::new(2.0, 5.0))],
            interest_points: vec![
                Vec3::new(3.1, 2.5, 0.75),
                Vec3::new(1.0, 4.4, 0.5),
                Vec3::new(6.0, 1.0, 1.5),
                Vec3::new(0.0, 1.0, 1.2),
            ],
            tall_obstacles: Vec::new(),
        }
    }

    fn angle_between(a: &Affine3A, b: &Affine3A) -> f32 {
        let r = Mat3::from(a.matrix3).transpose() * Mat3::from(b.matrix3);
        ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) * 0.5).clamp(-1.0, 1.0).acos()
    }

    fn check_plausible(plan: &ScanPlan, poses: &[Affine3A]) {
        let dt = 1.0 / plan.frame_rate;
        for p in poses {
            assert!(p.is_finite());
            let m = Mat3::from(p.matrix3);
            assert!((m.transpose() * m).abs_diff_eq(Mat3::IDENTITY, 1e-4), "not a rotation");
            assert!((m.determinant() - 1.0).abs() < 1e-4);
        }
        for w in poses.windows(2) {
            let v = (w[1].translation - w[0].translation).length() / dt;
            let omega = angle_between(&w[0], &w[1]).to_degrees() / dt;
            assert!(v < 0.6, "speed {v} m/s");
            assert!(omega < 40.0, "turning at {omega} deg/s");
        }
        let (first, last) = (poses[0], poses[poses.len() - 1]);
        assert!((first.translation - last.translation).length() < 0.01, "loop not closed");
        assert!(angle_between(&first, &last).to_degrees() < 1.0, "loop not closed in rotation");
    }

    #[test]
    fn walks_a_closed_loop_through_free_space_at_handheld_speeds() {
        let plan = ScanPlan::new(office(), 1);
        let poses = plan.poses(1800).expect("plan");
        assert_eq!(poses.len(), 1800);
        check_plausible(&plan, &poses);
        let room = &plan.room;
        let mut travelled = 0.0;
        for w in poses.windows(2) {
            travelled += (w[1].translation - w[0].translation).length();
        }
        assert!(travelled > 5.0, "walked only {travelled} m");
        for p in &poses {
            let xy = p.translation.truncate();
            assert!((1.3..1.6).contains(&p.translation.z), "eye at {}", p.translation.z);
            assert!(clearance_at(room, xy) > 0.3, "at {xy} too close to a wall or obstacle");
        }
        // Looks down sometimes, and mostly at things rather than the ceiling.
        let pitches: Vec<f32> = poses.iter().map(|p| p.matrix3.z_axis.z.asin().to_degrees()).collect();
        assert!(pitches.iter().any(|&p| p < -20.0));
        assert!(pitches.iter().all(|&p| p < 45.0));
        assert_eq!(poses, plan.poses(1800).expect("plan"), "not deterministic");
        assert_ne!(poses, ScanPlan::new(office(), 2).poses(1800).expect("plan"));
    }

    #[test]
    fn a_vertical_sweep_nods_up_within_handheld_speeds_and_keeps_the_loop_closed() {
        let pitch = |p: &Affine3A| p.matrix3.z_axis.z.asin().to_degrees();
        for frames in [300, 1800] {
            let casual = ScanPlan::new(office(), 1);
            let mut mapping = casual.clone();
            mapping.vertical_sweep_deg = 30.0;
            let (a, b) = (casual.poses(frames).expect("plan"), mapping.poses(frames).expect("plan"));
            check_plausible(&mapping, &b);
            // Same walk, the gaze tilted by at most 30 degrees, the same at both ends.
            for (p, q) in a.iter().zip(&b) {
                assert!((p.translation - q.translation).length() < 1e-5);
                let lift = pitch(q) - pitch(p);
                assert!((-35.0..=35.0).contains(&lift), "lift {lift}");
                assert!((-51.0..56.0).contains(&pitch(q)));
            }
            // The nod reaches well up and well down of the casual gaze.
            let lifts: Vec<f32> = a.iter().zip(&b).map(|(p, q)| pitch(q) - pitch(p)).collect();
            assert!(lifts.iter().any(|&l| l > 20.0) && lifts.iter().any(|&l| l < -5.0));
        }
        let mut bad = ScanPlan::new(office(), 1);
        bad.vertical_sweep_deg = f32::NAN;
        assert!(bad.poses(10).is_err());
    }

    #[test]
    fn short_scans_go_out_and_back() {
        let plan = ScanPlan::new(office(), 3);
        let poses = plan.poses(90).expect("plan");
        check_plausible(&plan, &poses);
    }

    #[test]
    fn mesh_bounds_fallback_stays_inside_the_bounds() {
        let mesh = LabeledMesh {
            positions: vec![Vec3::new(-2.0, -1.0, 0.2), Vec3::new(3.0, 2.5, 3.0)],
            colors: vec![[0; 3]; 2],
            ..Default::default()
        };
        let plan = ScanPlan::from_mesh_bounds(&mesh, 0).expect("plan");
        let poses = plan.poses(600).expect("plan");
        check_plausible(&plan, &poses);
        for p in &poses {
            let t = p.translation;
            assert!(t.x > -1.6 && t.x < 2.6 && t.y > -0.6 && t.y < 2.1 && t.z > 1.4 && t.z < 1.8, "{t}");
        }
        assert!(ScanPlan::from_mesh_bounds(&LabeledMesh::default(), 0).is_err());
    }

    #[test]
    fn a_tiny_room_gives_a_camera_standing_and_looking_around() {
        let room = RoomLayout {
            floor_min: Vec2::ZERO,
            floor_max: Vec2::new(1.0, 1.0),
            floor_z: 0.0,
            ceiling_height: 2.5,
            obstacles: Vec::new(),
            interest_points: Vec::new(),
            tall_obstacles: Vec::new(),
        };
        let plan = ScanPlan::new(room, 4);
        let poses = plan.poses(300).expect("plan");
        check_plausible(&plan, &poses);
    }

    #[test]
    fn view_ranges_meet_walls_tall_obstacles_floor_and_ceiling() {
        let mut room = office();
        room.tall_obstacles = vec![(Vec2::new(3.0, 0.0), Vec2::new(3.1, 1.0))];
        let plan = ScanPlan::new(room, 0);
        let look = |eye: Vec3, forward: Vec3| {
            let forward = forward.normalize();
            let right = forward.cross(Vec3::Z).normalize();
            Affine3A::from_mat3_translation(Mat3::from_cols(right, forward.cross(right), forward), eye)
        };
        let eye = Vec3::new(1.0, 0.5, 1.5);
        let poses = [
            // Level at the x = 0 wall, 1 m away.
            look(eye, Vec3::NEG_X),
            // Level at the tall obstacle, 2 m away (the low obstacles are looked over).
            look(eye, Vec3::X),
            // 45 degrees down along +y: the floor 1.5 / sin(45) away, before the far wall.
            look(eye, Vec3::new(0.0, 1.0, -1.0)),
            // 45 degrees up: the ceiling (2.7 m) 1.2 / sin(45) away.
            look(eye, Vec3::new(0.0, 1.0, 1.0)),
            // Straight along +y to the far wall (y = 5), cut at the range asked for.
            look(eye, Vec3::Y),
        ];
        let got = plan.view_ranges(&poses, 4.0);
        let want = [1.0, 2.0, 1.5 * SQRT_2, 1.2 * SQRT_2, 4.0];
        for (g, w) in got.iter().zip(want) {
            // Half-cell steps on a 5 cm grid, read from the nearest cell.
            assert!((g - w).abs() < 0.06, "got {got:?}, want {want:?}");
        }
    }

    #[test]
    fn a_room_without_free_space_is_an_error() {
        let mut room = office();
        room.obstacles = vec![(Vec2::new(0.0, 0.0), Vec2::new(6.0, 5.0))];
        assert!(ScanPlan::new(room, 0).poses(10).is_err());
    }
}
