//! Rooms as people live in them, furnished from the furniture catalogues: bedrooms, living
//! rooms, kitchens, bathrooms, studios, offices, conference rooms and corridors, each with
//! the furniture such a room has (a bed with nightstands and a wardrobe, a sofa facing a
//! coffee table and a TV, a row of kitchen cabinets with the fridge and the stove, a toilet
//! and a washbasin, desks with chairs, a long table with chairs all around), things on the
//! tables, counters and shelves, things on the walls, and a shell with real materials
//! (planks, tiles, carpet, paint) and baked-in light.
//!
//! The generator takes its models from any [`ModelSource`] (the installed catalogues,
//! [`FurnitureLibrary`], or a fake one in tests). Every model's mesh is copied in as it is
//! (turned, moved, scaled by at most ±10 %, its labels kept), with its colours varied a
//! little, and, for upholstered furniture, sometimes recoloured. Where the catalogues lack a
//! kind of furniture (in rooms of held-out models, mostly), the procedural furniture of
//! [`crate::synth`] stands in.
//!
//! World frame as in [`crate::synth`]: metres, z up, floor at z = 0, floor rectangle
//! `[0, W] x [0, D]`. Generation is deterministic: the same config and the same models give
//! the same bits.
//!
//! Inside, one concept a file: `categories` (which catalogue models count as a bed, a chair,
//! a kitchen cabinet...), `pieces` (a model or a procedural stand-in, copied into the mesh
//! and recoloured), `placement` (against a wall, free-standing or hung; the walk grid),
//! `arrangements` (groups the recipes share: a dining set, a desk with its chair, things on
//! top), the recipes by room kind (`homes`, `kitchens_bathrooms`, `workplaces`), `fixtures`
//! (pictures, boards, radiators, curtains, sockets, lamps), `openings` (doors and windows)
//! and `materials` (floor, walls and ceiling, and the baked light).
#![warn(missing_docs)]

mod arrangements;
mod categories;
mod fixtures;
mod homes;
mod kitchens_bathrooms;
mod materials;
mod openings;
mod pieces;
mod placement;
#[cfg(test)]
mod tests;
mod wall_finish;
mod workplaces;

use std::collections::BTreeSet;
use std::sync::Arc;

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use self::pieces::Piece;
use super::{FurnitureLibrary, LibraryModel, Split};
use crate::class::SemanticClass;
use crate::error::{DataError, Result};
use crate::home_class::HomeClass;
use crate::mesh::LabeledMesh;
use crate::synth::layout::Layout;
use crate::synth::palette::{uniform, Palette};
use crate::synth::shapes::MeshBuilder;
use crate::synth::shell::{self, Opening};
use crate::synth::{RoomStyle, SyntheticRoom};

/// Where a room's models come from: a list of models and their meshes.
pub trait ModelSource {
    /// Every model that may be placed (the generator keeps those of the room's split).
    fn models(&self) -> &[LibraryModel];
    /// The model's mesh in its local frame: x in `[0, size.x]`, y in `[0, size.y]` (front
    /// towards -y), z in `[0, size.z]`, labelled, with per-vertex colours.
    fn mesh(&self, model: &LibraryModel) -> Result<Arc<LabeledMesh>>;
}

impl ModelSource for FurnitureLibrary {
    fn models(&self) -> &[LibraryModel] {
        &self.models
    }

    fn mesh(&self, model: &LibraryModel) -> Result<Arc<LabeledMesh>> {
        self.load_mesh(model)
    }
}

/// Kind of room to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomeRoomKind {
    /// A bed (sometimes two) with nightstands, a wardrobe, a dresser or a desk, a rug.
    Bedroom,
    /// Sofas and armchairs around a coffee table facing a TV, bookcases, plants, sometimes
    /// a dining table with chairs.
    LivingRoom,
    /// Kitchen cabinets, fridge, stove and sink in a row along one or two walls, a table
    /// with chairs.
    Kitchen,
    /// Toilet, washbasin, bathtub or shower, a cabinet, towels.
    Bathroom,
    /// One room to live in: bed, sofa corner, kitchenette, small dining table.
    Studio,
    /// Desks with chairs and computers, bookcases, cabinets, a board.
    Office,
    /// A long table with chairs all around, a board, cabinets.
    Conference,
    /// Long and narrow, doors along it, cabinets, benches, pictures.
    Corridor,
}

impl HomeRoomKind {
    /// Every kind; a seed draws among these (changing the list changes every seed's room).
    pub const ALL: [HomeRoomKind; 8] = [
        Self::Bedroom,
        Self::LivingRoom,
        Self::Kitchen,
        Self::Bathroom,
        Self::Studio,
        Self::Office,
        Self::Conference,
        Self::Corridor,
    ];

    /// Lower-case name (`bedroom`, `living_room`, `kitchen`, `bathroom`, `studio`, `office`,
    /// `conference`, `corridor`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Bedroom => "bedroom",
            Self::LivingRoom => "living_room",
            Self::Kitchen => "kitchen",
            Self::Bathroom => "bathroom",
            Self::Studio => "studio",
            Self::Office => "office",
            Self::Conference => "conference",
            Self::Corridor => "corridor",
        }
    }

    /// The procedural style closest to this kind, reported in [`SyntheticRoom::style`]:
    /// office, conference and hallway for those kinds, lounge for the homes.
    pub fn synth_style(self) -> RoomStyle {
        match self {
            Self::Office => RoomStyle::Office,
            Self::Conference => RoomStyle::Conference,
            Self::Corridor => RoomStyle::Hallway,
            _ => RoomStyle::Lounge,
        }
    }
}

impl std::fmt::Display for HomeRoomKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for HomeRoomKind {
    type Err = DataError;

    /// Parses a kind name, case-insensitive; `-` and a space are taken for `_`
    /// (`living-room`, `Living Room`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase().replace(['-', ' '], "_");
        Self::ALL.into_iter().find(|k| k.name() == lower).ok_or_else(|| {
            DataError::InvalidArgument(format!(
                "unknown room kind {s:?} (expected one of bedroom, living_room, kitchen, bathroom, studio, office, \
                 conference, corridor)"
            ))
        })
    }
}

/// What to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LibraryRoomConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Kind of room; `None` draws it from the seed (uniformly among [`HomeRoomKind::ALL`]).
    pub kind: Option<HomeRoomKind>,
    /// Which models may be used: a `Train` room uses only `Train` models, a `HeldOut` room
    /// only `HeldOut` models (furniture that training never saw).
    pub split: Split,
}

impl LibraryRoomConfig {
    /// A training room of a kind drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        Self { seed, kind: None, split: Split::Train }
    }
}

/// A generated room with what went into it.
#[derive(Debug, Clone, PartialEq)]
pub struct LibraryRoom {
    /// The room (its `style` is [`HomeRoomKind::synth_style`]).
    pub room: SyntheticRoom,
    /// Kind of the room.
    pub kind: HomeRoomKind,
    /// Ids of the catalogue models placed in the room, sorted, each once.
    pub model_ids: Vec<String>,
    /// Per vertex of `room.mesh`, its class in the home label set
    /// ([`crate::home_class::HomeClass`] ids, [`crate::class::UNLABELED`] where ScanNet
    /// scores nothing), from each model's fine category.
    pub home_labels: Vec<u8>,
}

/// The vertices one placed piece added to the room's mesh, with its home class.
#[derive(Debug, Clone)]
struct HomeSpan {
    vertices: std::ops::Range<u32>,
    /// Home class id, or `UNLABELED`.
    label: u8,
    /// A kitchen cabinet: its top faces are the counter (ScanNet labels a kitchen row's
    /// worktop `counter` and the doors below it `cabinet`).
    counter_top: bool,
}

/// Height within which an upward face of a kitchen cabinet counts as its worktop (metres).
const COUNTER_TOP_BAND: f32 = 0.04;

/// Highest worktop (metres above the floor): the tops of wall cabinets above it are not.
const COUNTER_TOP_MAX: f32 = 1.25;

/// The home class of every vertex: the shell's from its S3DIS class, each piece's from its
/// span (its own shell-class vertices, such as a door model's frame labelled wall, kept), and
/// a kitchen cabinet's worktop (upward faces at its top) counter.
fn home_vertex_labels(mesh: &LabeledMesh, spans: &[HomeSpan]) -> Vec<u8> {
    let from_s3dis = |l: u8| {
        SemanticClass::from_id(l).and_then(HomeClass::from_s3dis).map_or(crate::class::UNLABELED, HomeClass::id)
    };
    let is_shell = |l: u8| {
        matches!(
            SemanticClass::from_id(l),
            Some(
                SemanticClass::Ceiling
                    | SemanticClass::Floor
                    | SemanticClass::Wall
                    | SemanticClass::Beam
                    | SemanticClass::Column
            )
        )
    };
    let mut labels: Vec<u8> = mesh.vertex_labels.iter().map(|&l| from_s3dis(l)).collect();
    let mut tops = Vec::with_capacity(spans.len());
    for span in spans {
        let range = span.vertices.start as usize..(span.vertices.end as usize).min(labels.len());
        tops.push(range.clone().map(|v| mesh.positions[v].z).fold(f32::NEG_INFINITY, f32::max));
        for v in range {
            if !is_shell(mesh.vertex_labels[v]) {
                labels[v] = span.label;
            }
        }
    }
    // Worktops by face: library meshes share vertices between a top and its sides, so a
    // vertex normal does not say which way a face looks.
    let mut counter = Vec::new();
    for t in &mesh.triangles {
        let first = t[0];
        let s = spans.partition_point(|s| s.vertices.end <= first);
        if !spans.get(s).is_some_and(|s| s.counter_top && s.vertices.contains(&first)) {
            continue;
        }
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let up = (b - a).cross(c - a).normalize_or_zero().z > 0.9;
        // Upper cabinets' tops are not worktops.
        if up && tops[s] <= COUNTER_TOP_MAX && a.z.min(b.z).min(c.z) >= tops[s] - COUNTER_TOP_BAND {
            counter.extend(t.iter().copied());
        }
    }
    for v in counter {
        if !is_shell(mesh.vertex_labels[v as usize]) {
            labels[v as usize] = HomeClass::Counter.id();
        }
    }
    labels
}

/// Most triangles a room gets: decoration that would go over is left out.
pub const MAX_TRIANGLES: usize = 1_500_000;

/// Largest edge of a tessellation patch of the shell and procedural parts (metres).
const PATCH: f32 = 0.12;

/// Generates the room described by `config` from the models of `lib`.
pub fn generate_library_room(config: &LibraryRoomConfig, lib: &(impl ModelSource + ?Sized)) -> Result<SyntheticRoom> {
    Ok(generate_library_room_detailed(config, lib)?.room)
}

/// [`generate_library_room`], also returning the kind and the ids of the models used.
pub fn generate_library_room_detailed(
    config: &LibraryRoomConfig,
    lib: &(impl ModelSource + ?Sized),
) -> Result<LibraryRoom> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0x4C49_4252_4152_5931);
    // Always drawn, so that the rest of the room does not depend on whether it was given.
    let drawn = HomeRoomKind::ALL[rng.random_range(0..HomeRoomKind::ALL.len())];
    let kind = config.kind.unwrap_or(drawn);
    let pool: Vec<&LibraryModel> = lib
        .models()
        .iter()
        .filter(|m| m.split == config.split && m.size.is_finite() && m.size.min_element() > 0.002)
        .collect();
    let u = uniform;
    let (w, d, h) = match kind {
        HomeRoomKind::Bathroom => (u(&mut rng, 1.8, 3.0), u(&mut rng, 2.0, 3.5), u(&mut rng, 2.4, 2.8)),
        HomeRoomKind::Bedroom => (u(&mut rng, 3.0, 5.0), u(&mut rng, 3.0, 5.0), u(&mut rng, 2.4, 3.0)),
        HomeRoomKind::LivingRoom => (u(&mut rng, 4.0, 7.0), u(&mut rng, 4.0, 6.0), u(&mut rng, 2.4, 3.2)),
        HomeRoomKind::Kitchen => (u(&mut rng, 2.5, 5.0), u(&mut rng, 3.0, 5.0), u(&mut rng, 2.4, 3.0)),
        HomeRoomKind::Studio => (u(&mut rng, 5.0, 8.0), u(&mut rng, 4.0, 6.0), u(&mut rng, 2.4, 3.0)),
        HomeRoomKind::Office => (u(&mut rng, 4.0, 9.0), u(&mut rng, 4.0, 7.0), u(&mut rng, 2.6, 3.2)),
        HomeRoomKind::Conference => (u(&mut rng, 5.0, 10.0), u(&mut rng, 4.0, 7.0), u(&mut rng, 2.6, 3.2)),
        HomeRoomKind::Corridor => (u(&mut rng, 1.3, 2.2), u(&mut rng, 5.0, 12.0), u(&mut rng, 2.4, 3.0)),
    };
    let (w, d) = if rng.random_bool(0.5) { (w, d) } else { (d, w) };
    let pal = Palette::draw(&mut rng);
    let noise_seed: u64 = rng.random();
    let mut home = Home {
        lib,
        pool,
        kind,
        rng,
        b: MeshBuilder::new(PATCH, noise_seed),
        layout: Layout::new(w, d, h),
        pal,
        used: BTreeSet::new(),
        openings: Vec::new(),
        opening_models: Vec::new(),
        lights: Vec::new(),
        extras_rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0x4255_4C4B_4845_4144),
        finish_rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0x5741_4C4C_4649_4E31),
        home_spans: Vec::new(),
    };
    home.build()?;
    let Home { b, layout, used, home_spans, .. } = home;
    let mut mesh = b.finish();
    // Normals of library meshes that came without them.
    fill_missing_normals(&mut mesh);
    let home_labels = home_vertex_labels(&mesh, &home_spans);
    mesh.validate().map_err(|e| DataError::InvalidArgument(format!("generated room mesh is invalid: {e}")))?;
    let room = SyntheticRoom {
        style: kind.synth_style(),
        mesh,
        floor_min: Vec2::ZERO,
        floor_max: Vec2::new(w, d),
        ceiling_height: h,
        obstacles: layout.obstacles.iter().map(|r| (r.min, r.max)).collect(),
        interest_points: layout.interest,
    };
    Ok(LibraryRoom { room, kind, model_ids: used.into_iter().collect(), home_labels })
}

/// A room being generated: where its models come from, the random state, the mesh and the
/// occupancy of floor and walls so far, and what the shell and the shading still need.
struct Home<'a, S: ModelSource + ?Sized> {
    lib: &'a S,
    pool: Vec<&'a LibraryModel>,
    kind: HomeRoomKind,
    rng: ChaCha8Rng,
    b: MeshBuilder,
    layout: Layout,
    pal: Palette,
    used: BTreeSet<String>,
    openings: Vec<Opening>,
    /// Catalogue model set into each opening (parallel to `openings`).
    opening_models: Vec<Option<Piece<'a>>>,
    /// Where light comes from (windows, lamps), for the baked shading.
    lights: Vec<Vec3>,
    /// The random stream of what session 14 added (bulkheads, open doors): adding them left
    /// every other choice of a seed's room as it was, so earlier evaluations stay comparable.
    extras_rng: ChaCha8Rng,
    /// The random stream of the wall finishes (session 18), for the same reason.
    finish_rng: ChaCha8Rng,
    /// The vertices of each placed piece and its home class.
    home_spans: Vec<HomeSpan>,
}

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    fn build(&mut self) -> Result<()> {
        // Structure first (it reserves walls), then openings, then the shell around them.
        if matches!(self.kind, HomeRoomKind::Office | HomeRoomKind::Conference) && self.rng.random_bool(0.35) {
            let style = if self.kind == HomeRoomKind::Office { RoomStyle::Office } else { RoomStyle::Conference };
            shell::add_structure(&mut self.b, &mut self.layout, &mut self.rng, &self.pal, style);
        }
        self.plan_openings();
        self.bulkheads();
        let shell_end = self.build_shell();
        self.fill_openings();
        self.radiators();
        self.curtains();
        match self.kind {
            HomeRoomKind::Bedroom => self.bedroom(),
            HomeRoomKind::LivingRoom => self.living_room(),
            HomeRoomKind::Kitchen => self.kitchen(),
            HomeRoomKind::Bathroom => self.bathroom(),
            HomeRoomKind::Studio => self.studio(),
            HomeRoomKind::Office => self.office(),
            HomeRoomKind::Conference => self.conference(),
            HomeRoomKind::Corridor => self.corridor(),
        }
        self.wall_details();
        self.ceiling_lamp();
        self.bake_light(shell_end);
        Ok(())
    }
}

impl<S: ModelSource + ?Sized> Home<'_, S> {
    /// Beams along walls (bulkheads), most often in offices, conference rooms and corridors,
    /// now and then in homes; see [`shell::add_wall_beams`].
    fn bulkheads(&mut self) {
        let p = match self.kind {
            HomeRoomKind::Office | HomeRoomKind::Conference | HomeRoomKind::Corridor => 0.5,
            HomeRoomKind::LivingRoom | HomeRoomKind::Studio | HomeRoomKind::Kitchen => 0.15,
            HomeRoomKind::Bedroom | HomeRoomKind::Bathroom => 0.05,
        };
        if self.extras_rng.random_bool(p) {
            shell::add_wall_beams(&mut self.b, &mut self.layout, &mut self.extras_rng, &self.pal);
        }
    }
}

/// Area-weighted normals for vertices that have none (library meshes without normals).
fn fill_missing_normals(m: &mut LabeledMesh) {
    let mut acc = vec![Vec3::ZERO; m.positions.len()];
    let missing: Vec<bool> = m.normals.iter().map(|n| *n == Vec3::ZERO).collect();
    for t in &m.triangles {
        if !t.iter().any(|&i| missing[i as usize]) {
            continue;
        }
        let [a, b, c] = t.map(|i| m.positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    for (i, n) in m.normals.iter_mut().enumerate() {
        if missing[i] {
            *n = acc[i].normalize_or_zero();
        }
    }
}
