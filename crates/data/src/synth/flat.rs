//! Procedural flats: several rooms joined by open doorways, for scans that walk from room to
//! room (whole-home mapping, memory budgets, loop closure over a loop through two rooms).
//! A single generated room is a closed box; a flat places several of them side by side,
//! separated by interior walls of a real thickness, and cuts matching doorways through both
//! faces of a shared wall. Each room is built by the single-room code (`shell` for the
//! structure, `styles` for the furniture, the same palettes and shapes), in its own frame,
//! then moved to its place, so the flat is one [`LabeledMesh`] with the same classes, colours
//! and conventions as [`super::generate_room`]'s rooms, and rendering, evaluation and mesh
//! accuracy work on it unchanged.
//!
//! Two plans: [`FlatKind::Home`], five rooms (a hall along the middle, a living room and a
//! kitchen on one side, joined to each other as well, a bedroom and a study on the other;
//! 65-95 m^2 of floor, about 80 on average), and [`FlatKind::TwoRooms`], a living room and a
//! kitchen joined by one doorway (the loop of a loop-closure scan). Doorways stand open, the
//! leaf swung wide into a room; the hall has the closed front door; windows are only on
//! outside walls. Generation is deterministic in the seed.

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::layout::{footprint, Layout, Rect2};
use super::palette::{uniform, Palette};
use super::shapes::MeshBuilder;
use super::shell::{self, Leaf, Opening, OpeningKind};
use super::styles::Furnisher;
use super::{RoomStyle, PATCH};
use crate::error::DataError;
use crate::mesh::LabeledMesh;

/// Which flat to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FlatKind {
    /// Five rooms, about 80 m^2: hall, living room, kitchen, bedroom, study.
    Home,
    /// A living room and a kitchen joined by a doorway, about 40 m^2.
    TwoRooms,
}

/// What to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlatConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Plan of the flat.
    pub kind: FlatKind,
}

/// One room of a flat (world frame).
#[derive(Debug, Clone, PartialEq)]
pub struct FlatRoom {
    /// What the room is for (`hall`, `living room`, ...).
    pub name: &'static str,
    /// The single-room style it is furnished in.
    pub style: RoomStyle,
    /// Interior floor rectangle, lower corner.
    pub floor_min: Vec2,
    /// Interior floor rectangle, upper corner.
    pub floor_max: Vec2,
}

impl FlatRoom {
    /// Floor area, m^2.
    pub fn area(&self) -> f32 {
        let size = self.floor_max - self.floor_min;
        size.x * size.y
    }

    /// Whether `p` is on this room's floor, grown by `margin`.
    pub fn contains(&self, p: Vec2, margin: f32) -> bool {
        p.cmpge(self.floor_min - Vec2::splat(margin)).all() && p.cmple(self.floor_max + Vec2::splat(margin)).all()
    }
}

/// An open doorway: the floor of the hole through the wall between two rooms.
#[derive(Debug, Clone, PartialEq)]
pub struct Doorway {
    /// The rooms it joins (indices into [`SyntheticFlat::rooms`]).
    pub rooms: [usize; 2],
    /// Lower corner of the passage's floor (through the wall's thickness).
    pub min: Vec2,
    /// Upper corner of the passage's floor.
    pub max: Vec2,
    /// Clear width of the opening, metres.
    pub width: f32,
}

impl Doorway {
    /// Centre of the passage's floor.
    pub fn centre(&self) -> Vec2 {
        (self.min + self.max) * 0.5
    }
}

/// A generated flat.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticFlat {
    /// Plan it follows.
    pub kind: FlatKind,
    /// The labelled mesh of every room: class per triangle and per vertex, colour and
    /// normal per vertex (as [`super::SyntheticRoom::mesh`]).
    pub mesh: LabeledMesh,
    /// The rooms, in the order a walk through the flat visits them.
    pub rooms: Vec<FlatRoom>,
    /// The doorways between rooms.
    pub doorways: Vec<Doorway>,
    /// Bounding rectangle of the whole floor plan (rooms and walls), lower corner (the origin).
    pub floor_min: Vec2,
    /// Bounding rectangle, upper corner.
    pub floor_max: Vec2,
    /// Ceiling height of every room, metres.
    pub ceiling_height: f32,
    /// Thickness of the interior walls, metres.
    pub wall_thickness: f32,
    /// Floor footprints `(min, max)` of everything standing on the floor (furniture,
    /// columns, open door leaves), inside the rooms.
    pub obstacles: Vec<(Vec2, Vec2)>,
    /// Centres of furniture, wall objects, windows and doors: places worth looking at.
    pub interest_points: Vec<Vec3>,
}

impl SyntheticFlat {
    /// Floor area of the rooms (without walls and doorways), m^2.
    pub fn floor_area(&self) -> f32 {
        self.rooms.iter().map(FlatRoom::area).sum()
    }

    /// The room whose floor (grown by `margin`) holds `p`, the first one if several do.
    pub fn room_at(&self, p: Vec2, margin: f32) -> Option<usize> {
        self.rooms.iter().position(|r| r.contains(p, margin))
    }

    /// Whether `p` is on a floor one can walk on: in a room or in a doorway.
    pub fn is_walkable(&self, p: Vec2) -> bool {
        self.room_at(p, 0.0).is_some() || self.doorways.iter().any(|d| p.cmpge(d.min).all() && p.cmple(d.max).all())
    }

    /// The parts of the bounding rectangle one cannot walk on (walls between rooms, minus
    /// the doorways), as `(min, max)` rectangles: with [`Self::obstacles`], everything a
    /// walk must keep clear of.
    pub fn walls(&self) -> Vec<(Vec2, Vec2)> {
        // Cut the bounding rectangle along every room and doorway edge; each cell of the
        // cut is wholly free or wholly blocked.
        let mut xs = vec![self.floor_min.x, self.floor_max.x];
        let mut ys = vec![self.floor_min.y, self.floor_max.y];
        let free: Vec<(Vec2, Vec2)> = self
            .rooms
            .iter()
            .map(|r| (r.floor_min, r.floor_max))
            .chain(self.doorways.iter().map(|d| (d.min, d.max)))
            .collect();
        for (lo, hi) in &free {
            xs.extend([lo.x, hi.x]);
            ys.extend([lo.y, hi.y]);
        }
        for v in [&mut xs, &mut ys] {
            v.sort_by(f32::total_cmp);
            v.dedup_by(|a, b| (*a - *b).abs() < 1e-5);
        }
        let mut blocked = Vec::new();
        for row in ys.windows(2) {
            // Runs of blocked cells along the row become one rectangle.
            let mut run: Option<f32> = None;
            for (i, col) in xs.windows(2).enumerate() {
                let c = Vec2::new((col[0] + col[1]) * 0.5, (row[0] + row[1]) * 0.5);
                let is_free = free.iter().any(|(lo, hi)| c.cmpge(*lo).all() && c.cmple(*hi).all());
                match (is_free, run) {
                    (false, None) => run = Some(col[0]),
                    (true, Some(x0)) => {
                        blocked.push((Vec2::new(x0, row[0]), Vec2::new(col[0], row[1])));
                        run = None;
                    }
                    _ => {}
                }
                if i + 2 == xs.len() {
                    if let Some(x0) = run.take() {
                        blocked.push((Vec2::new(x0, row[0]), Vec2::new(col[1], row[1])));
                    }
                }
            }
        }
        blocked
    }
}

/// Thickness of interior walls, metres.
const WALL: f32 = 0.12;

/// Width of the ways kept free of furniture from doorways to the middle of each room (and
/// along a hall), metres: wide enough for a walk keeping 0.25 m from everything.
const WALKWAY: f32 = 1.0;

/// A room of the plan (world frame), with the walls that have daylight behind them.
struct RoomPlan {
    name: &'static str,
    style: RoomStyle,
    min: Vec2,
    size: Vec2,
    outside: Vec<usize>,
}

/// A doorway of the plan: the two rooms, the wall of each it goes through, where along the
/// wall (world coordinate: x for walls 0 and 2, y for walls 1 and 3), how wide and high, and
/// which of the two rooms (0 or 1) the leaf swings into, if any.
struct DoorPlan {
    rooms: [usize; 2],
    walls: [usize; 2],
    at: f32,
    width: f32,
    height: f32,
    leaf_in: Option<usize>,
}

/// Generates the flat described by `config`.
pub fn generate_flat(config: &FlatConfig) -> Result<SyntheticFlat, DataError> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let height = uniform(&mut rng, 2.55, 2.85);
    let door_height = uniform(&mut rng, 2.03, 2.2);
    let (plans, doors, front) = match config.kind {
        FlatKind::Home => plan_home(&mut rng, door_height),
        FlatKind::TwoRooms => plan_two_rooms(&mut rng, door_height),
    };
    let mut mesh = LabeledMesh::default();
    let mut obstacles = Vec::new();
    let mut interest_points = Vec::new();
    for (i, plan) in plans.iter().enumerate() {
        // Each room draws from its own stream, so that one room's draws do not shift the
        // next room's.
        let mut room_rng = ChaCha8Rng::seed_from_u64(rng.random());
        let front_here = front.filter(|f| f.0 == i).map(|f| f.1);
        let built = build_room(plan, i, &doors, front_here, height, door_height, &mut room_rng)?;
        let offset = plan.min;
        let mut part = built.mesh;
        for p in &mut part.positions {
            *p += offset.extend(0.0);
        }
        mesh.append(&part);
        obstacles.extend(built.obstacles.iter().map(|r| (r.min + offset, r.max + offset)));
        interest_points.extend(built.interest.iter().map(|p| *p + offset.extend(0.0)));
    }
    let rooms: Vec<FlatRoom> = plans
        .iter()
        .map(|p| FlatRoom { name: p.name, style: p.style, floor_min: p.min, floor_max: p.min + p.size })
        .collect();
    let doorways = doors.iter().map(|d| doorway_floor(&plans, d)).collect();
    let floor_max = plans.iter().fold(Vec2::ZERO, |acc, p| acc.max(p.min + p.size));
    Ok(SyntheticFlat {
        kind: config.kind,
        mesh,
        rooms,
        doorways,
        floor_min: Vec2::ZERO,
        floor_max,
        ceiling_height: height,
        wall_thickness: WALL,
        obstacles,
        interest_points,
    })
}

/// A doorway's position along a side room's span `lo..hi`, away from the corners.
fn door_at(rng: &mut ChaCha8Rng, lo: f32, hi: f32, width: f32) -> f32 {
    let (a, b) = (lo + 0.6 + width * 0.5, hi - 0.6 - width * 0.5);
    if a < b {
        uniform(rng, a, b)
    } else {
        (lo + hi) * 0.5
    }
}

/// The five-room plan: the hall along x in the middle, living room and kitchen below it
/// (smaller y), bedroom and study above; the walk visits hall, living room, kitchen, study,
/// bedroom. Returns rooms, doorways and the front door (room, wall).
fn plan_home(rng: &mut ChaCha8Rng, door_height: f32) -> (Vec<RoomPlan>, Vec<DoorPlan>, Option<(usize, usize)>) {
    let length = uniform(rng, 8.0, 9.5);
    let (south, hall, north) = (uniform(rng, 3.6, 4.4), uniform(rng, 1.6, 2.0), uniform(rng, 3.0, 3.6));
    let living = length * uniform(rng, 0.52, 0.62);
    let bedroom = length * uniform(rng, 0.5, 0.6);
    let (y_hall, y_north) = (south + WALL, south + 2.0 * WALL + hall);
    let plans = vec![
        RoomPlan {
            name: "hall",
            style: RoomStyle::Hallway,
            min: Vec2::new(0.0, y_hall),
            size: Vec2::new(length, hall),
            outside: vec![1, 3],
        },
        RoomPlan {
            name: "living room",
            style: RoomStyle::Lounge,
            min: Vec2::ZERO,
            size: Vec2::new(living, south),
            outside: vec![0, 3],
        },
        RoomPlan {
            name: "kitchen",
            style: RoomStyle::Conference,
            min: Vec2::new(living + WALL, 0.0),
            size: Vec2::new(length - living - WALL, south),
            outside: vec![0, 1],
        },
        RoomPlan {
            name: "study",
            style: RoomStyle::Office,
            min: Vec2::new(bedroom + WALL, y_north),
            size: Vec2::new(length - bedroom - WALL, north),
            outside: vec![1, 2],
        },
        RoomPlan {
            name: "bedroom",
            style: RoomStyle::Lounge,
            min: Vec2::new(0.0, y_north),
            size: Vec2::new(bedroom, north),
            outside: vec![2, 3],
        },
    ];
    let mut doors = Vec::new();
    // Hall to each side room: the hall's wall 0 (below) or 2 (above), the room's wall 2 or 0;
    // leaves swing into the rooms, the hall being narrow.
    for (room, hall_wall, room_wall) in [(1, 0, 2), (2, 0, 2), (3, 2, 0), (4, 2, 0)] {
        let width = uniform(rng, 0.9, 1.0);
        let p = &plans[room];
        doors.push(DoorPlan {
            rooms: [0, room],
            walls: [hall_wall, room_wall],
            at: door_at(rng, p.min.x, p.min.x + p.size.x, width),
            width,
            height: door_height,
            leaf_in: Some(1),
        });
    }
    // Living room to kitchen: a wide opening without a leaf, or a door; with the hall this
    // makes a loop through three rooms.
    let width = if rng.random_bool(0.5) { uniform(rng, 1.2, 1.6) } else { uniform(rng, 0.9, 1.0) };
    doors.push(DoorPlan {
        rooms: [1, 2],
        walls: [1, 3],
        at: door_at(rng, 0.0, south, width),
        width,
        height: door_height,
        leaf_in: (width < 1.1).then_some(1),
    });
    let front_wall = if rng.random_bool(0.5) { 1 } else { 3 };
    (plans, doors, Some((0, front_wall)))
}

/// The two-room plan: living room (0) and kitchen (1) side by side along x, one doorway.
fn plan_two_rooms(rng: &mut ChaCha8Rng, door_height: f32) -> (Vec<RoomPlan>, Vec<DoorPlan>, Option<(usize, usize)>) {
    let depth = uniform(rng, 4.0, 5.0);
    let (wa, wb) = (uniform(rng, 4.5, 6.0), uniform(rng, 3.5, 4.5));
    let plans = vec![
        RoomPlan {
            name: "living room",
            style: RoomStyle::Lounge,
            min: Vec2::ZERO,
            size: Vec2::new(wa, depth),
            outside: vec![0, 3],
        },
        RoomPlan {
            name: "kitchen",
            style: RoomStyle::Conference,
            min: Vec2::new(wa + WALL, 0.0),
            size: Vec2::new(wb, depth),
            outside: vec![0, 1, 2],
        },
    ];
    let width = uniform(rng, 0.9, 1.0);
    let doors = vec![DoorPlan {
        rooms: [0, 1],
        walls: [1, 3],
        at: door_at(rng, 0.0, depth, width),
        width,
        height: door_height,
        leaf_in: Some(1),
    }];
    (plans, doors, Some((0, 2)))
}

/// Position along wall `k` of a room (the wall frame's s, see `layout`) of the world
/// coordinate `at` (x for walls 0 and 2, y for walls 1 and 3).
fn wall_s(plan: &RoomPlan, k: usize, at: f32) -> f32 {
    match k {
        0 => at - plan.min.x,
        1 => at - plan.min.y,
        2 => plan.min.x + plan.size.x - at,
        _ => plan.min.y + plan.size.y - at,
    }
}

/// The floor of a doorway's hole: its span along the walls by the gap between the rooms.
fn doorway_floor(plans: &[RoomPlan], d: &DoorPlan) -> Doorway {
    let (a, b) = (&plans[d.rooms[0]], &plans[d.rooms[1]]);
    let (lo, hi) = (d.at - d.width * 0.5, d.at + d.width * 0.5);
    let (min, max) = if d.walls[0].is_multiple_of(2) {
        // Walls along x: the gap is in y, between the two rooms' facing walls.
        let (y0, y1) = if a.min.y < b.min.y { (a.min.y + a.size.y, b.min.y) } else { (b.min.y + b.size.y, a.min.y) };
        (Vec2::new(lo, y0), Vec2::new(hi, y1))
    } else {
        let (x0, x1) = if a.min.x < b.min.x { (a.min.x + a.size.x, b.min.x) } else { (b.min.x + b.size.x, a.min.x) };
        (Vec2::new(x0, lo), Vec2::new(x1, hi))
    };
    Doorway { rooms: d.rooms, min, max, width: d.width }
}

/// A room built in its own frame (floor corner at the origin).
struct BuiltRoom {
    mesh: LabeledMesh,
    obstacles: Vec<Rect2>,
    interest: Vec<Vec3>,
}

/// Builds room `index` of the plan: its doorways and front door first (so that nothing is
/// placed in front of them), then the structure, windows on outside walls, the shell, the
/// passages and the furniture, all by the single-room code.
fn build_room(
    plan: &RoomPlan,
    index: usize,
    doors: &[DoorPlan],
    front_wall: Option<usize>,
    height: f32,
    door_height: f32,
    rng: &mut ChaCha8Rng,
) -> Result<BuiltRoom, DataError> {
    let pal = Palette::draw(rng);
    let mut b = MeshBuilder::new(PATCH, rng.random());
    let mut layout = Layout::new(plan.size.x, plan.size.y, height);
    let mut openings: Vec<Opening> = Vec::new();
    // (opening index, draws the reveals, leaf) for each doorway of this room.
    let mut passages: Vec<(usize, bool, Option<Leaf>)> = Vec::new();
    let mut keepouts = Vec::new();
    let fail = |what: &str| {
        DataError::InvalidArgument(format!("flat plan: no room for {what} in the {} ({:?})", plan.name, plan.size))
    };
    if let Some(k) = front_wall {
        let len = layout.walls[k].length;
        let width = uniform(rng, 0.9, 1.0).min(len - 0.6);
        if !shell::try_add_opening(
            &mut layout,
            &mut openings,
            k,
            len * 0.5,
            width,
            0.0,
            door_height,
            OpeningKind::Door,
            0.05,
        ) {
            return Err(fail("the front door"));
        }
        let wall = layout.walls[k];
        keepouts.push(footprint(wall.point(len * 0.5, 0.5), width + 0.2, 1.0, wall.yaw));
    }
    for d in doors {
        let Some(side) = d.rooms.iter().position(|&r| r == index) else { continue };
        let k = d.walls[side];
        let s = wall_s(plan, k, d.at);
        if !shell::try_add_opening(&mut layout, &mut openings, k, s, d.width, 0.0, d.height, OpeningKind::Door, WALL) {
            return Err(fail("a doorway"));
        }
        // Wide open, so that the leaf stands clear of the way through.
        let leaf = (d.leaf_in == Some(side))
            .then(|| Leaf { at_start: rng.random_bool(0.5), angle: uniform(rng, 88.0, 95.0).to_radians() });
        // The floor in front stays free: the leaf's swing, or the way in. Kept out only once
        // every doorway is placed, so that doorways facing each other across a narrow hall
        // may share it.
        let reach = if leaf.is_some() { 1.0 } else { 0.7 };
        let wall = layout.walls[k];
        keepouts.push(footprint(wall.point(s, reach * 0.5), d.width + 0.2, reach, wall.yaw));
        // And a way in, from the doorway to the middle of the room: furnished rooms this size
        // leave no other way through that is sure to be wide enough.
        let middle = if k.is_multiple_of(2) { plan.size.y * 0.5 } else { plan.size.x * 0.5 };
        keepouts.push(footprint(wall.point(s, middle * 0.5), WALKWAY, middle, wall.yaw));
        passages.push((openings.len() - 1, side == 0, leaf));
    }
    // A narrow room (the hall) keeps a way along its middle, from end to end.
    if plan.size.min_element() < 2.5 {
        let (len, centre) = (plan.size.max_element() - 0.6, plan.size * 0.5);
        let yaw = if plan.size.x >= plan.size.y { 0.0 } else { std::f32::consts::FRAC_PI_2 };
        keepouts.push(footprint(centre, len, WALKWAY, yaw));
    }
    for r in keepouts {
        layout.add_keepout(r);
    }
    shell::add_structure(&mut b, &mut layout, rng, &pal, plan.style);
    shell::add_windows(&mut layout, &mut openings, rng, &plan.outside, false, false);
    shell::build_surfaces(&mut b, &layout, &openings, rng, &pal);
    for (i, o) in openings.iter().enumerate() {
        let wall = layout.walls[o.wall];
        b.place(wall.start.extend(0.0), wall.yaw);
        match (passages.iter().find(|p| p.0 == i), o.kind) {
            (Some(&(_, reveals, leaf)), _) => {
                if let Some(r) = shell::passage(&mut b, o, rng, &pal, WALL, reveals, leaf) {
                    // From the wall frame (along, into the room) to the room's frame.
                    let (a, c) = (wall.point(r.min.x, r.min.y), wall.point(r.max.x, r.max.y));
                    layout.add_obstacle(Rect2::new(a.min(c), a.max(c)));
                }
            }
            (None, OpeningKind::Window) => shell::window(&mut b, o, rng, &pal),
            (None, OpeningKind::Door) => shell::door(&mut b, o, rng, &pal),
        }
    }
    b.set_noise(0.06);
    Furnisher { b: &mut b, layout: &mut layout, rng, pal: &pal, desk_chairs: None }.furnish(plan.style, &openings);
    Ok(BuiltRoom { mesh: b.finish(), obstacles: layout.obstacles, interest: layout.interest })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::class::SemanticClass;

    fn flat(seed: u64, kind: FlatKind) -> SyntheticFlat {
        generate_flat(&FlatConfig { seed, kind }).expect("flat")
    }

    /// Whether the doorways join every room to the first.
    fn connected(f: &SyntheticFlat) -> bool {
        let mut reached = vec![false; f.rooms.len()];
        reached[0] = true;
        for _ in 0..f.rooms.len() {
            for d in &f.doorways {
                if reached[d.rooms[0]] || reached[d.rooms[1]] {
                    reached[d.rooms[0]] = true;
                    reached[d.rooms[1]] = true;
                }
            }
        }
        reached.iter().all(|&r| r)
    }

    #[test]
    fn a_home_has_five_connected_rooms_of_about_80_square_metres() {
        for seed in 0..8 {
            let f = flat(seed, FlatKind::Home);
            assert_eq!(f.rooms.len(), 5);
            let area = f.floor_area();
            assert!((65.0..95.0).contains(&area), "seed {seed}: {area} m^2");
            assert!(connected(&f), "seed {seed}: rooms not connected");
            assert_eq!(f.doorways.len(), 5, "seed {seed}");
            // Rooms do not overlap, and walls stand between them.
            for (i, a) in f.rooms.iter().enumerate() {
                for b in &f.rooms[i + 1..] {
                    let gap = (a.floor_min - b.floor_max).max(b.floor_min - a.floor_max);
                    assert!(gap.max_element() >= WALL - 1e-4, "seed {seed}: {} and {} overlap", a.name, b.name);
                }
            }
            f.mesh.validate().expect("valid mesh");
            // Every obstacle stands on a room's floor.
            for (lo, hi) in &f.obstacles {
                let c = (*lo + *hi) * 0.5;
                assert!(f.room_at(c, 0.01).is_some(), "seed {seed}: obstacle at {c} outside the rooms");
            }
        }
    }

    #[test]
    fn doorways_are_passable_holes_through_the_walls() {
        for seed in 0..8 {
            for kind in [FlatKind::Home, FlatKind::TwoRooms] {
                let f = flat(seed, kind);
                let walls = f.walls();
                for d in &f.doorways {
                    assert!(d.width >= 0.85, "seed {seed}: doorway {} m wide", d.width);
                    let depth = (d.max - d.min).min_element();
                    assert!((depth - WALL).abs() < 1e-4, "seed {seed}: doorway through {depth} m of wall");
                    // The middle of the doorway is walkable and joins the two rooms' floors.
                    let c = d.centre();
                    assert!(f.is_walkable(c));
                    assert!(walls.iter().all(|(lo, hi)| !(c.cmpgt(*lo).all() && c.cmplt(*hi).all())));
                    let across = if d.max.x - d.min.x < d.max.y - d.min.y { Vec2::X } else { Vec2::Y };
                    let sides = [c - across * 0.2, c + across * 0.2].map(|p| f.room_at(p, 0.0));
                    let mut got = [sides[0], sides[1]].map(|s| s.unwrap_or(usize::MAX));
                    got.sort();
                    let mut want = d.rooms;
                    want.sort();
                    assert_eq!(got, want, "seed {seed}: doorway at {c} does not join its rooms");
                    // No mesh inside the passage at walking height except the door casing:
                    // every triangle vertex in it belongs to a door or the floor.
                    for (p, &l) in f.mesh.positions.iter().zip(&f.mesh.vertex_labels) {
                        let inner = p.truncate().cmpgt(d.min + Vec2::splat(0.1)).all()
                            && p.truncate().cmplt(d.max - Vec2::splat(0.1)).all();
                        if inner && p.z > 0.05 && p.z < 1.9 {
                            panic!("seed {seed}: class {l} at {p} blocks the doorway");
                        }
                    }
                }
                // Walls and rooms tile the bounding rectangle.
                let walls_area: f32 = walls.iter().map(|(lo, hi)| (*hi - *lo).x * (*hi - *lo).y).sum();
                let doors_area: f32 = f.doorways.iter().map(|d| (d.max - d.min).x * (d.max - d.min).y).sum();
                let total = (f.floor_max - f.floor_min).x * (f.floor_max - f.floor_min).y;
                assert!((walls_area + doors_area + f.floor_area() - total).abs() < 1e-2, "seed {seed}");
            }
        }
    }

    #[test]
    fn every_room_has_walls_floor_ceiling_and_doors_labelled() {
        let f = flat(3, FlatKind::Home);
        for room in &f.rooms {
            let mut seen = [false; 13];
            for (t, &l) in f.mesh.triangles.iter().zip(&f.mesh.triangle_labels) {
                let c = t.iter().fold(Vec3::ZERO, |acc, &i| acc + f.mesh.positions[i as usize]) / 3.0;
                if room.contains(c.truncate(), 0.02) && (l as usize) < 13 {
                    seen[l as usize] = true;
                }
            }
            for class in [SemanticClass::Wall, SemanticClass::Floor, SemanticClass::Ceiling, SemanticClass::Door] {
                assert!(seen[class.id() as usize], "{} has no {class:?}", room.name);
            }
        }
        // Floor triangles lie at z = 0, ceiling ones at the ceiling height or a light panel.
        for (t, &l) in f.mesh.triangles.iter().zip(&f.mesh.triangle_labels) {
            let z = t.iter().map(|&i| f.mesh.positions[i as usize].z).fold(f32::NEG_INFINITY, f32::max);
            if l == SemanticClass::Ceiling.id() {
                assert!(z > f.ceiling_height - 0.6, "ceiling triangle at {z}");
            }
        }
    }

    #[test]
    fn two_rooms_are_joined_by_one_doorway() {
        for seed in 0..8 {
            let f = flat(seed, FlatKind::TwoRooms);
            assert_eq!(f.rooms.len(), 2);
            assert_eq!(f.doorways.len(), 1);
            assert!(connected(&f));
            assert!((30.0..55.0).contains(&f.floor_area()), "seed {seed}: {}", f.floor_area());
        }
    }

    #[test]
    fn flats_are_deterministic_in_the_seed() {
        let a = flat(11, FlatKind::Home);
        assert_eq!(a, flat(11, FlatKind::Home));
        assert_ne!(a.mesh, flat(12, FlatKind::Home).mesh);
    }
}
