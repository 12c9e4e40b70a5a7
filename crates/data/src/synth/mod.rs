//! Procedural labelled indoor rooms: training and test data for the whole pipeline without
//! a scanner. A seed (and optionally a style) gives a closed room — floor, ceiling, walls
//! with real window and door openings, beams, columns — furnished with tables, chairs,
//! sofas, bookcases full of books, boards and clutter, as one [`LabeledMesh`] with an
//! S3DIS class per triangle (and per vertex) and a colour per vertex. Every room of every
//! style contains all 13 classes. Four styles are for training; a fifth, the classroom, is
//! held out (never drawn from a seed) to test on rooms unlike any seen in training.
//!
//! World frame: metres, z up, floor at z = 0; the interior floor is the rectangle
//! `floor_min..floor_max` (from the origin). Triangles are counter-clockwise seen from the
//! side a camera inside the room sees. Generation is deterministic: the same
//! [`RoomConfig`] gives the same bits.
//!
//! Inside: `shapes` (mesh builders), `shell` (the room's structure), `furniture`,
//! `clutter`, `layout` (occupancy of floor and walls), `styles` (per-style recipes),
//! `palette` (colours); [`flat`] puts several rooms together into a flat joined by doorways.

pub(crate) mod clutter;
pub mod flat;
pub(crate) mod furniture;
pub(crate) mod layout;
pub(crate) mod palette;
pub(crate) mod shapes;
pub(crate) mod shell;
mod styles;

pub use flat::{generate_flat, FlatConfig, FlatKind, SyntheticFlat};

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::DataError;
use crate::mesh::LabeledMesh;

/// Kind of room to generate.
///
/// [`RoomStyle::ALL`] holds the four styles training draws from; `classroom`
/// ([`RoomStyle::HELD_OUT`]) is held out from training by design: a seed never draws it, so
/// it is generated only when named (`--style classroom`, `synth:A..B:classroom`), and the
/// rooms it gives test how the network does on a kind of room it has never seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RoomStyle {
    /// Desks with swivel chairs and monitors along the walls, bookcases, a sofa corner.
    Office,
    /// A long table with chairs all around, a board on an end wall.
    Conference,
    /// Sofas and armchairs around a coffee table, bookcases, a dining table, lamps, plants.
    Lounge,
    /// A long narrow corridor with doors, benches, shelves and notice boards.
    Hallway,
    /// Rows of student tables with chairs facing a board on the front wall, a teacher's
    /// desk, bookcases at the back, windows along one long wall, a reading corner. Held out
    /// from training: not in [`RoomStyle::ALL`].
    Classroom,
}

impl RoomStyle {
    /// The styles training uses, and the only ones a seed draws. Changing this list
    /// changes the room of every seed (the style is the seed's first draw).
    pub const ALL: [RoomStyle; 4] = [Self::Office, Self::Conference, Self::Lounge, Self::Hallway];

    /// Styles never used in training, generated only when named: held-out test rooms.
    pub const HELD_OUT: [RoomStyle; 1] = [Self::Classroom];

    /// Lower-case name (`office`, `conference`, `lounge`, `hallway`, `classroom`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Office => "office",
            Self::Conference => "conference",
            Self::Lounge => "lounge",
            Self::Hallway => "hallway",
            Self::Classroom => "classroom",
        }
    }

    /// Whether training never sees this style (it is in [`RoomStyle::HELD_OUT`]).
    pub fn is_held_out(self) -> bool {
        Self::HELD_OUT.contains(&self)
    }
}

impl std::fmt::Display for RoomStyle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for RoomStyle {
    type Err = DataError;

    /// Parses a style name, case-insensitive: the trained styles and the held-out ones.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase();
        Self::ALL.into_iter().chain(Self::HELD_OUT).find(|st| st.name() == lower).ok_or_else(|| {
            DataError::InvalidArgument(format!(
                "unknown room style {s:?} (expected one of office, conference, lounge, hallway, classroom)"
            ))
        })
    }
}

/// What to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RoomConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Style of the room; `None` draws it from the seed (among [`RoomStyle::ALL`], never a
    /// held-out style).
    pub style: Option<RoomStyle>,
}

/// A generated room.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticRoom {
    /// Style of the room.
    pub style: RoomStyle,
    /// The labelled mesh: class per triangle and per vertex, colour and normal per vertex.
    pub mesh: LabeledMesh,
    /// Interior floor rectangle, lower corner (always the origin).
    pub floor_min: Vec2,
    /// Interior floor rectangle, upper corner (width, depth).
    pub floor_max: Vec2,
    /// Ceiling height (metres).
    pub ceiling_height: f32,
    /// Floor footprints `(min, max)` of everything standing on the floor (furniture,
    /// columns, floor clutter): inside the floor rectangle and pairwise disjoint.
    pub obstacles: Vec<(Vec2, Vec2)>,
    /// Centres of furniture, wall objects, windows and doors: places worth looking at.
    pub interest_points: Vec<Vec3>,
}

/// Largest edge of a tessellation patch (metres).
const PATCH: f32 = 0.2;

/// Generates the room described by `config`.
pub fn generate_room(config: &RoomConfig) -> SyntheticRoom {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    // Always draw the style so that the rest of the room does not depend on whether the
    // style was given. Only trained styles are drawn, so adding a held-out style leaves
    // every seed's room as it was.
    let drawn = RoomStyle::ALL[rng.random_range(0..RoomStyle::ALL.len())];
    let style = config.style.unwrap_or(drawn);
    let u = palette::uniform;
    let (width, depth, height) = match style {
        RoomStyle::Office => (u(&mut rng, 5.0, 9.0), u(&mut rng, 4.0, 7.0), u(&mut rng, 2.7, 3.2)),
        RoomStyle::Conference => (u(&mut rng, 6.0, 10.0), u(&mut rng, 4.6, 7.0), u(&mut rng, 2.8, 3.5)),
        RoomStyle::Lounge => (u(&mut rng, 5.5, 9.0), u(&mut rng, 5.0, 8.0), u(&mut rng, 2.7, 3.4)),
        RoomStyle::Hallway => (u(&mut rng, 9.0, 18.0), u(&mut rng, 2.0, 2.8), u(&mut rng, 2.6, 3.0)),
        RoomStyle::Classroom => (u(&mut rng, 7.0, 10.0), u(&mut rng, 5.8, 8.0), u(&mut rng, 2.8, 3.4)),
    };
    // Rooms are not always longer along x.
    let (width, depth) = if rng.random_bool(0.5) { (width, depth) } else { (depth, width) };
    let pal = palette::Palette::draw(&mut rng);
    let mut builder = shapes::MeshBuilder::new(PATCH, rng.random());
    let mut layout = layout::Layout::new(width, depth, height);

    shell::add_structure(&mut builder, &mut layout, &mut rng, &pal, style);
    let openings = shell::plan_openings(&mut layout, &mut rng, style);
    shell::build_shell(&mut builder, &layout, &openings, &mut rng, &pal);
    styles::Furnisher { b: &mut builder, layout: &mut layout, rng: &mut rng, pal: &pal, desk_chairs: None }
        .furnish(style, &openings);

    SyntheticRoom {
        style,
        mesh: builder.finish(),
        floor_min: Vec2::ZERO,
        floor_max: Vec2::new(width, depth),
        ceiling_height: height,
        obstacles: layout.obstacles.iter().map(|r| (r.min, r.max)).collect(),
        interest_points: layout.interest,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn style_names_round_trip() {
        for s in RoomStyle::ALL.into_iter().chain(RoomStyle::HELD_OUT) {
            assert_eq!(s.name().parse::<RoomStyle>().ok(), Some(s));
            assert_eq!(s.is_held_out(), !RoomStyle::ALL.contains(&s));
        }
        assert_eq!("CLASSROOM".parse::<RoomStyle>().ok(), Some(RoomStyle::Classroom));
        assert_eq!(" Hallway ".parse::<RoomStyle>().ok(), Some(RoomStyle::Hallway));
        assert!("kitchen".parse::<RoomStyle>().is_err());
    }

    #[test]
    fn given_style_keeps_the_rest_of_the_drawn_room() {
        let drawn = generate_room(&RoomConfig { seed: 5, style: None });
        let given = generate_room(&RoomConfig { seed: 5, style: Some(drawn.style) });
        assert_eq!(drawn, given);
    }

    #[test]
    fn seeds_never_draw_a_held_out_style() {
        for seed in 0..200 {
            let style = generate_room(&RoomConfig { seed, style: None }).style;
            assert!(!style.is_held_out(), "seed {seed} drew {style}");
        }
    }
}
