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
#![warn(missing_docs)]

use std::collections::BTreeSet;
use std::f32::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{FurnitureLibrary, LibraryModel, Split};
use crate::class::SemanticClass;
use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;
use crate::synth::clutter::{self, FloorItem, WallItem};
use crate::synth::furniture::{self, BoardKind, ChairStyle};
use crate::synth::layout::{footprint, Layout, Rect2};
use crate::synth::palette::{jitter, jitter_pick, pick, uniform, Palette};
use crate::synth::shapes::{splitmix, world_from_object, MeshBuilder, Rgb, SKIP_NEG_Y};
use crate::synth::shell::{self, Opening, OpeningKind};
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
}

/// Most triangles a room gets: decoration that would go over is left out.
pub const MAX_TRIANGLES: usize = 1_500_000;

/// Largest edge of a tessellation patch of the shell and procedural parts (metres).
const PATCH: f32 = 0.12;
/// Clearance a scan path keeps from walls and obstacles (see `scan_path`): every room keeps
/// a connected walkable area at this distance.
const WALK_CLEARANCE: f32 = 0.4;

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
    };
    home.build()?;
    let Home { b, layout, used, .. } = home;
    let mut mesh = b.finish();
    // Normals of library meshes that came without them.
    fill_missing_normals(&mut mesh);
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
    Ok(LibraryRoom { room, kind, model_ids: used.into_iter().collect() })
}

// ---------------------------------------------------------------------------------------
// Model categories (the `fine` column of `crates/data/furniture_classes.tsv`).

fn is(m: &LibraryModel, fines: &[&str]) -> bool {
    fines.contains(&m.fine.as_str())
}

fn name_has(m: &LibraryModel, words: &[&str]) -> bool {
    let n = m.name.to_ascii_lowercase();
    words.iter().any(|w| n.contains(w))
}

fn on_floor(m: &LibraryModel) -> bool {
    m.elevation < 0.05 && !m.door_or_window
}

fn is_bed(m: &LibraryModel) -> bool {
    is(m, &["bed"]) && on_floor(m) && m.size.x >= 0.8 && m.size.y >= 1.7 && m.size.y <= 2.45 && m.size.z > 0.25
}

fn is_sofa(m: &LibraryModel) -> bool {
    is(m, &["sofa", "sofa_bed"]) && on_floor(m) && m.size.x >= 1.2 && m.size.y <= 1.2
}

fn is_armchair(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.x <= 1.1
        && m.size.y <= 1.1
        && m.size.z >= 0.5
        && (is(m, &["armchair"]) || (is(m, &["sofa"]) && m.size.x < 1.1))
}

fn is_chair(m: &LibraryModel) -> bool {
    is(m, &["chair"]) && on_floor(m) && m.size.x <= 0.75 && m.size.y <= 0.8 && m.size.z >= 0.6 && m.size.z <= 1.4
}

fn is_office_chair(m: &LibraryModel) -> bool {
    is_chair(m) && name_has(m, &["office", "swivel", "desk", "computer"])
}

fn is_table(m: &LibraryModel) -> bool {
    is(m, &["table", "work_table"])
        && on_floor(m)
        && m.size.z >= 0.6
        && m.size.z <= 0.95
        && m.size.x >= 0.6
        && m.size.y >= 0.5
}

fn is_coffee_table(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z <= 0.6
        && m.size.z >= 0.25
        && (is(m, &["coffee_table"]) || (is(m, &["table"]) && m.size.z <= 0.55))
}

fn is_desk(m: &LibraryModel) -> bool {
    is(m, &["desk", "dressing_table"]) && on_floor(m) && m.size.x >= 0.8 && m.size.y <= 1.0
}

fn is_nightstand(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.x <= 0.65
        && m.size.y <= 0.65
        && m.size.z <= 0.8
        && m.size.z >= 0.35
        && (is(m, &["nightstand"]) || (is(m, &["cabinet"]) && m.size.z <= 0.7))
}

fn is_wardrobe(m: &LibraryModel) -> bool {
    is(m, &["wardrobe"]) && on_floor(m) && m.size.z >= 1.4 && m.size.y <= 0.8
}

fn is_dresser(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z <= 1.2
        && m.size.y <= 0.7
        && (is(m, &["dresser"]) || (is(m, &["cabinet"]) && m.size.x >= 0.4))
}

fn is_bookcase(m: &LibraryModel) -> bool {
    is(m, &["bookcase", "shelf"]) && on_floor(m) && m.size.y <= 0.6 && m.size.z >= 0.6
}

fn is_floor_cabinet(m: &LibraryModel) -> bool {
    is(m, &["cabinet"]) && on_floor(m) && m.size.y <= 0.75 && m.size.z >= 0.5 && m.size.z <= 2.3
}

fn is_kitchen(m: &LibraryModel) -> bool {
    m.category.eq_ignore_ascii_case("kitchen")
}

/// Lower kitchen modules: cabinets, sinks, stoves, dishwashers and washing machines that
/// stand on the floor at counter height.
fn is_kitchen_lower(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z >= 0.75
        && m.size.z <= 1.25
        && m.size.y >= 0.45
        && m.size.y <= 0.8
        && m.size.x <= 1.3
        && (is(m, &["cabinet", "oven", "washing_machine"]) || (is(m, &["sink"]) && is_kitchen(m)))
}

fn is_kitchen_upper(m: &LibraryModel) -> bool {
    is(m, &["cabinet"]) && m.elevation >= 1.2 && m.size.y <= 0.6 && m.size.z <= 1.0
}

fn is_fridge(m: &LibraryModel) -> bool {
    is(m, &["fridge"]) && on_floor(m) && m.size.z >= 1.2 && m.size.y <= 1.0
}

fn is_tv(m: &LibraryModel) -> bool {
    is(m, &["tv"]) && m.size.x >= 0.5 && m.size.z >= 0.35
}

fn is_tv_stand(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z >= 0.3
        && m.size.z <= 0.8
        && m.size.y <= 0.7
        && m.size.x >= 0.6
        && is(m, &["cabinet", "dresser", "shelf"])
}

fn is_toilet(m: &LibraryModel) -> bool {
    is(m, &["toilet"]) && on_floor(m) && m.size.y >= 0.45 && m.size.z >= 0.45
}

fn is_washbasin(m: &LibraryModel) -> bool {
    is(m, &["sink"]) && !is_kitchen(m) && m.size.x <= 2.0 && m.size.y <= 0.85 && m.elevation + m.size.z >= 0.7
}

fn is_bathtub(m: &LibraryModel) -> bool {
    is(m, &["bathtub"]) && on_floor(m) && m.size.z >= 0.3
}

fn is_shower(m: &LibraryModel) -> bool {
    is(m, &["shower"]) && on_floor(m) && m.size.z >= 1.8 && m.size.y >= 0.7
}

fn is_towel_rack(m: &LibraryModel) -> bool {
    is(m, &["towel"]) && m.size.y <= 0.25 && m.size.x >= 0.12 && m.size.z >= 0.1
}

fn is_radiator(m: &LibraryModel) -> bool {
    is(m, &["radiator"]) && m.size.y <= 0.3 && m.size.z <= 1.2 && m.elevation <= 0.5 && m.size.x >= 0.4
}

fn is_rug(m: &LibraryModel) -> bool {
    (is(m, &["rug"]) || name_has(m, &["mat"]))
        && m.size.z <= 0.06
        && m.size.x >= 0.5
        && m.size.y >= 0.4
        && !m.door_or_window
}

fn is_curtain(m: &LibraryModel) -> bool {
    is(m, &["curtain"]) && m.size.z >= 1.0
}

fn is_floor_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && on_floor(m) && m.size.z >= 1.1 && m.size.x <= 0.7 && m.size.y <= 0.7
}

fn is_ceiling_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && m.elevation + m.size.z >= 2.0 && m.size.x <= 1.4 && m.size.z <= 1.0
}

fn is_wall_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && m.elevation >= 1.0 && m.elevation + m.size.z < 2.0 && m.size.y <= 0.4
}

fn is_floor_plant(m: &LibraryModel) -> bool {
    is(m, &["plant"]) && on_floor(m) && m.size.z >= 0.5 && m.size.z <= 2.2 && m.size.x <= 1.0 && m.size.y <= 1.0
}

fn is_whiteboard(m: &LibraryModel) -> bool {
    is(m, &["whiteboard"]) && on_floor(m) && m.size.z <= 2.2
}

fn is_bench(m: &LibraryModel) -> bool {
    is(m, &["bench"]) && on_floor(m) && m.size.z <= 1.0 && m.size.y <= 0.6
}

fn is_wall_socket(m: &LibraryModel) -> bool {
    is(m, &["wall_socket"]) && m.size.y <= 0.1 && m.size.x <= 0.3 && m.size.z <= 0.3
}

/// Things that stand on the floor by a wall as clutter, by room kind: boxes, bags, fans,
/// and in homes instruments, toys, sports gear, a fireplace.
fn is_floor_clutter(m: &LibraryModel, kind: HomeRoomKind) -> bool {
    let fines: &[&str] = match kind {
        HomeRoomKind::Office | HomeRoomKind::Conference | HomeRoomKind::Corridor => {
            &["box", "bag", "fan", "air_conditioner"]
        }
        HomeRoomKind::LivingRoom | HomeRoomKind::Studio => {
            &["box", "bag", "musical_instrument", "fan", "air_conditioner", "fireplace", "toy"]
        }
        _ => &["box", "bag", "fan", "toy", "sport", "musical_instrument"],
    };
    on_floor(m) && m.size.z >= 0.25 && m.size.z <= 1.9 && m.size.x <= 1.6 && m.size.y <= 0.9 && is(m, fines)
}

/// Small things that go on tables, counters and shelves, by room kind.
fn is_small(m: &LibraryModel, kind: HomeRoomKind) -> bool {
    let general = [
        "vase",
        "object",
        "box",
        "stationery",
        "toy",
        "computer",
        "electronics",
        "clock",
        "lamp",
        "plant",
        "picture",
        "clothes",
        "bag",
        "tv",
    ];
    let fines: &[&str] = match kind {
        HomeRoomKind::Kitchen => &["kitchenware", "food", "microwave", "vase", "plant", "electronics", "oven"],
        HomeRoomKind::Bathroom => &["bathroom_accessory", "towel", "vase", "plant", "object"],
        HomeRoomKind::Office | HomeRoomKind::Conference => {
            &["computer", "stationery", "electronics", "lamp", "plant", "object", "vase", "box", "clock"]
        }
        _ => &general,
    };
    is(m, fines)
        && m.size.z <= 0.6
        && m.size.x.max(m.size.y) <= 0.75
        && m.elevation < 0.3
        && !m.door_or_window
        && (m.fine != "oven" || m.size.z <= 0.1)
}

// ---------------------------------------------------------------------------------------
// The generator.

/// A thing to place: a catalogue model with its mesh, or a procedural stand-in.
#[derive(Clone)]
struct Piece<'a> {
    src: Src<'a>,
    /// Unscaled size (x width, y depth, z height).
    size: Vec3,
    /// Height of the surface things can stand on, above the piece's bottom (unscaled).
    top: f32,
    /// Elevation of the bottom above the floor the catalogue gives.
    elevation: f32,
    /// Upholstered: sometimes recoloured.
    fabric: bool,
}

#[derive(Clone)]
enum Src<'a> {
    Model { model: &'a LibraryModel, mesh: Arc<LabeledMesh>, lo: Vec3 },
    Proc(Proc),
}

#[derive(Clone, Copy)]
enum Proc {
    Table,
    Desk,
    Chair(ChairStyle),
    Sofa,
    Bookcase,
    Cabinet,
    Plant,
    Lamp,
}

/// A piece in the room.
#[derive(Debug, Clone, Copy)]
struct Placed {
    center: Vec2,
    yaw: f32,
    /// Scaled size.
    size: Vec3,
    /// World z of the bottom.
    z: f32,
    /// World z of the surface on top.
    top: f32,
    /// Wall and position along it, when against a wall.
    wall: Option<(usize, f32)>,
}

/// Yaw that turns a model's front (local -y) to face `dir`.
fn yaw_facing(dir: Vec2) -> f32 {
    dir.x.atan2(-dir.y)
}

/// `v` turned by `yaw` about z.
fn rot(v: Vec2, yaw: f32) -> Vec2 {
    Vec2::from_angle(yaw).rotate(v)
}

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
}

const ALL_WALLS: [usize; 4] = [0, 1, 2, 3];

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    fn build(&mut self) -> Result<()> {
        // Structure first (it reserves walls), then openings, then the shell around them.
        if matches!(self.kind, HomeRoomKind::Office | HomeRoomKind::Conference) && self.rng.random_bool(0.35) {
            let style = if self.kind == HomeRoomKind::Office { RoomStyle::Office } else { RoomStyle::Conference };
            shell::add_structure(&mut self.b, &mut self.layout, &mut self.rng, &self.pal, style);
        }
        self.plan_openings();
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

    // ----- models -----

    fn pick(&mut self, pred: impl Fn(&LibraryModel) -> bool) -> Option<&'a LibraryModel> {
        let c: Vec<&'a LibraryModel> = self.pool.iter().copied().filter(|m| pred(m)).collect();
        if c.is_empty() {
            return None;
        }
        Some(c[self.rng.random_range(0..c.len())])
    }

    fn load(&self, model: &'a LibraryModel, fabric: bool) -> Option<Piece<'a>> {
        let mesh = self.lib.mesh(model).ok()?;
        let (lo, hi) = mesh.bounds()?;
        if !lo.is_finite() || !hi.is_finite() || mesh.triangles.is_empty() {
            return None;
        }
        let size = (hi - lo).max(Vec3::splat(0.002));
        let top = support_top(&mesh, lo, size);
        Some(Piece { src: Src::Model { model, mesh, lo }, size, top, elevation: model.elevation, fabric })
    }

    /// A random model satisfying `pred`, loaded.
    fn piece(&mut self, pred: impl Fn(&LibraryModel) -> bool) -> Option<Piece<'a>> {
        let m = self.pick(pred)?;
        let fabric = is(m, &["sofa", "sofa_bed", "armchair", "chair", "bed"]);
        self.load(m, fabric)
    }

    fn proc_piece(&mut self, kind: Proc) -> Piece<'a> {
        let rng = &mut self.rng;
        let size = match kind {
            Proc::Table => Vec3::new(uniform(rng, 1.2, 1.8), uniform(rng, 0.8, 0.95), furniture::table_height(rng)),
            Proc::Desk => Vec3::new(uniform(rng, 1.2, 1.6), uniform(rng, 0.6, 0.8), furniture::table_height(rng)),
            Proc::Chair(style) => Vec3::new(style.size, style.size, 0.9),
            Proc::Sofa => Vec3::new(uniform(rng, 1.6, 2.2), uniform(rng, 0.8, 0.95), 0.85),
            Proc::Bookcase => Vec3::new(uniform(rng, 0.7, 1.2), uniform(rng, 0.3, 0.4), uniform(rng, 1.0, 2.0)),
            Proc::Cabinet => Vec3::new(uniform(rng, 0.4, 0.9), uniform(rng, 0.45, 0.6), uniform(rng, 0.6, 1.1)),
            Proc::Plant => {
                let r = uniform(rng, 0.3, 0.55);
                Vec3::new(r, r, uniform(rng, 0.6, 1.5))
            }
            Proc::Lamp => {
                let r = uniform(rng, 0.3, 0.45);
                Vec3::new(r, r, uniform(rng, 1.4, 1.8))
            }
        };
        let top = match kind {
            Proc::Chair(_) | Proc::Sofa => 0.45,
            _ => size.z,
        };
        Piece { src: Src::Proc(kind), size, top, elevation: 0.0, fabric: false }
    }

    fn chair_style(&mut self, swivel: bool) -> Proc {
        Proc::Chair(ChairStyle::draw(&mut self.rng, &self.pal, swivel))
    }

    /// A scale jitter for a catalogue piece: ±10 % half of the time.
    fn scale_for(&mut self, p: &Piece) -> f32 {
        match p.src {
            Src::Model { .. } if self.rng.random_bool(0.5) => uniform(&mut self.rng, 0.9, 1.1),
            _ => 1.0,
        }
    }

    // ----- emitting -----

    /// Appends the piece, its bottom-centre at `center` and height `z`, turned by `yaw`,
    /// scaled by `scale` (per axis). Returns false when over the triangle budget.
    fn emit(&mut self, p: &Piece, center: Vec2, z: f32, yaw: f32, scale: Vec3) -> bool {
        match &p.src {
            Src::Model { model, mesh, lo } => {
                let src: &LabeledMesh = mesh;
                if self.b.mesh.triangles.len() + src.triangles.len() > MAX_TRIANGLES {
                    return false;
                }
                let xf = world_from_object(center.extend(z), yaw);
                let origin = Vec3::new(lo.x + p.size.x * 0.5, lo.y + p.size.y * 0.5, lo.z);
                let paint = self.paint(p.fabric);
                let class = model.class;
                let m = &mut self.b.mesh;
                let base = m.positions.len() as u32;
                for (i, q) in src.positions.iter().enumerate() {
                    m.positions.push(xf.transform_point3((*q - origin) * scale));
                    m.colors.push(paint.apply(src.colors.get(i).copied().unwrap_or([180, 180, 180])));
                    m.vertex_labels.push(src.vertex_labels.get(i).copied().unwrap_or(class));
                    let n =
                        src.normals.get(i).map_or(Vec3::ZERO, |n| xf.transform_vector3(*n / scale).normalize_or_zero());
                    m.normals.push(n);
                }
                for (t, tri) in src.triangles.iter().enumerate() {
                    m.triangles.push(tri.map(|i| i + base));
                    m.triangle_labels.push(src.triangle_labels.get(t).copied().unwrap_or(class));
                }
                self.used.insert(model.id.clone());
                true
            }
            Src::Proc(kind) => {
                if self.b.mesh.triangles.len() > MAX_TRIANGLES {
                    return false;
                }
                let s = p.size * scale;
                // Procedural furniture faces local +y.
                self.b.place(center.extend(z), yaw + PI);
                let (b, rng, pal) = (&mut self.b, &mut self.rng, &self.pal);
                match *kind {
                    Proc::Table => {
                        furniture::table(b, rng, pal, s.x, s.y, s.z);
                    }
                    Proc::Desk => {
                        furniture::desk(b, rng, pal, s.x, s.y, s.z);
                    }
                    Proc::Chair(style) => furniture::chair(b, rng, &style),
                    Proc::Sofa => furniture::sofa(b, rng, pal, s.x, s.y),
                    Proc::Bookcase => furniture::bookcase(b, rng, pal, s.x, s.y, s.z),
                    Proc::Cabinet => clutter::floor_item(b, rng, pal, FloorItem::Cabinet, s.x, s.y, s.z),
                    Proc::Plant => clutter::floor_item(b, rng, pal, FloorItem::Plant, s.x, s.y, s.z),
                    Proc::Lamp => clutter::floor_item(b, rng, pal, FloorItem::Lamp, s.x, s.y, s.z),
                }
                true
            }
        }
    }

    fn paint(&mut self, fabric: bool) -> Paint {
        let gain = uniform(&mut self.rng, 0.9, 1.1);
        let hue = (fabric && self.rng.random_bool(0.4))
            .then(|| (self.rng.random::<f32>(), uniform(&mut self.rng, 0.6, 1.8), uniform(&mut self.rng, 0.0, 0.25)));
        Paint { gain, hue }
    }

    // ----- occupancy -----

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
    fn wall_piece_at(&mut self, p: &Piece, k: usize, s: f32, scale: f32, gap: f32, access: f32) -> Option<Placed> {
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
    fn wall_piece(&mut self, p: &Piece, walls: &[usize], gap: f32, access: f32, tries: usize) -> Option<Placed> {
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
    fn free_piece_at(&mut self, p: &Piece, center: Vec2, yaw: f32, scale: f32, clearance: f32) -> Option<Placed> {
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
    fn free_piece(&mut self, p: &Piece, region: Rect2, yaw: f32, clearance: f32, tries: usize) -> Option<Placed> {
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
    fn wall_hang(&mut self, p: &Piece, walls: &[usize], z0: Option<f32>, tries: usize) -> Option<Placed> {
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

    /// Small things on the top of `support`: up to `n`, side by side across its width.
    fn on_top(&mut self, support: &Placed, n: usize) {
        if n == 0 || support.size.x < 0.25 || support.size.y < 0.2 {
            return;
        }
        let kind = self.kind;
        let (w, d) = (support.size.x * 0.9, support.size.y * 0.85);
        let cell = w / n as f32;
        for i in 0..n {
            if self.b.mesh.triangles.len() > MAX_TRIANGLES * 9 / 10 || self.rng.random_bool(0.2) {
                continue;
            }
            let Some(p) = self.piece(|m| is_small(m, kind)) else { return };
            let ext = p.size.x.max(p.size.y);
            let room = (cell * 0.85).min(d * 0.9);
            let scale = (room / ext).min(1.0).min((self.layout.height - support.top - 0.3) / p.size.z);
            if scale < 0.35 {
                continue;
            }
            let spin = uniform(&mut self.rng, -0.4, 0.4);
            let half = footprint(Vec2::ZERO, p.size.x * scale, p.size.y * scale, spin).max;
            let x = -w * 0.5 + cell * (i as f32 + 0.5);
            let slack_x = (cell * 0.5 - half.x).max(0.0);
            let slack_y = (d * 0.5 - half.y).max(0.0);
            if half.x > cell * 0.5 + 1e-3 || half.y > d * 0.5 + 1e-3 {
                continue;
            }
            let local =
                Vec2::new(x + uniform(&mut self.rng, -slack_x, slack_x), uniform(&mut self.rng, -slack_y, slack_y));
            let c = support.center + rot(local, support.yaw);
            let yaw = support.yaw + spin;
            if self.emit(&p, c, support.top + 0.001, yaw, Vec3::splat(scale)) {
                self.layout.interest.push(c.extend(support.top + p.size.z * scale * 0.5));
            }
        }
    }

    /// Chairs around a table, facing it: along its front (local -y) and, unless the table
    /// stands against a wall (`back` false), its back; at the ends when `ends`.
    fn chairs_around(&mut self, table: &Placed, chair: &Piece, ends: bool, back: bool, max: usize) -> usize {
        let (tw, td) = (table.size.x, table.size.y);
        let cs = chair.size;
        let mut seats: Vec<(Vec2, Vec2)> = Vec::new(); // (local position, outward normal)
        let gap = uniform(&mut self.rng, 0.05, 0.2);
        let per_side = ((tw - 0.1) / (cs.x + 0.15)).floor().max(1.0) as usize;
        for side in [-1.0f32, 1.0] {
            if side > 0.0 && !back {
                continue;
            }
            for i in 0..per_side {
                let x = -tw * 0.5 + tw * (i as f32 + 0.5) / per_side as f32;
                seats.push((Vec2::new(x, side * (td * 0.5 + gap + cs.y * 0.5)), Vec2::new(0.0, side)));
            }
        }
        if ends {
            for side in [-1.0f32, 1.0] {
                seats.push((Vec2::new(side * (tw * 0.5 + gap + cs.y * 0.5), 0.0), Vec2::new(side, 0.0)));
            }
        }
        let mut placed = 0;
        for (pos, n) in seats {
            if placed >= max {
                break;
            }
            if self.rng.random_bool(0.1) {
                continue;
            }
            let c = table.center + rot(pos, table.yaw);
            let inward = -rot(n, table.yaw);
            let yaw = yaw_facing(inward) + uniform(&mut self.rng, -0.15, 0.15);
            if self.free_piece_at(chair, c, yaw, 1.0, 0.0).is_some() {
                placed += 1;
            }
        }
        placed
    }

    /// A table free-standing in the room with chairs around it.
    fn dining_set(&mut self, region: Rect2, max_chairs: usize, ends: bool) -> Option<Placed> {
        let region_size = region.max - region.min;
        let limit = region_size.min_element() - 1.4;
        let table = self
            .piece(|m| is_table(m) && m.size.y <= limit && m.size.x <= region_size.max_element() - 1.4)
            .unwrap_or_else(|| self.proc_piece(Proc::Table));
        let yaw = if region_size.x >= region_size.y { 0.0 } else { FRAC_PI_2 };
        let yaw = if self.rng.random_bool(0.2) { yaw + FRAC_PI_2 } else { yaw };
        let t = self.free_piece(&table, region, yaw, 0.75, 40)?;
        let chair = match self.piece(is_chair) {
            Some(c) => c,
            None => {
                let s = self.chair_style(false);
                self.proc_piece(s)
            }
        };
        self.chairs_around(&t, &chair, ends, true, max_chairs);
        let n = self.rng.random_range(0..=3);
        self.on_top(&t, n);
        Some(t)
    }

    /// A desk against a wall with a chair in front of it and things on top.
    fn desk_with_chair(&mut self, walls: &[usize], office: bool) -> Option<Placed> {
        let desk = self.piece(is_desk).unwrap_or_else(|| self.proc_piece(Proc::Desk));
        let placed = self.wall_piece(&desk, walls, 0.01, 0.0, 40)?;
        let chair =
            if office { self.piece(is_office_chair).or_else(|| self.piece(is_chair)) } else { self.piece(is_chair) };
        let chair = match chair {
            Some(c) => c,
            None => {
                let s = self.chair_style(office);
                self.proc_piece(s)
            }
        };
        let (k, _) = placed.wall.unwrap_or((0, 0.0));
        let wall = self.layout.walls[k];
        let c = placed.center
            + wall.normal * (placed.size.y * 0.5 + uniform(&mut self.rng, 0.05, 0.25) + chair.size.y * 0.5)
            + wall.dir * uniform(&mut self.rng, -0.15, 0.15) * placed.size.x;
        let yaw = yaw_facing(-wall.normal) + uniform(&mut self.rng, -0.35, 0.35);
        self.free_piece_at(&chair, c, yaw, 1.0, 0.0);
        let n = self.rng.random_range(1..=3);
        self.on_top(&placed, n);
        Some(placed)
    }

    fn rug(&mut self, center: Vec2, yaw: f32, max: Vec2) {
        let Some(p) = self.piece(is_rug) else { return };
        let scale = (max.x / p.size.x).min(max.y / p.size.y).min(1.1);
        if scale < 0.5 {
            return;
        }
        let fp = footprint(center, p.size.x * scale, p.size.y * scale, yaw);
        if !self.layout.floor().contains(&fp) {
            return;
        }
        self.emit(&p, center, 0.0, yaw, Vec3::new(scale, scale, 1.0));
    }

    fn floor_plant(&mut self, walls: &[usize]) {
        let p = self.piece(is_floor_plant).unwrap_or_else(|| self.proc_piece(Proc::Plant));
        self.wall_piece(&p, walls, 0.05, 0.0, 30);
    }

    fn floor_lamp(&mut self) {
        let p = self.piece(is_floor_lamp).unwrap_or_else(|| self.proc_piece(Proc::Lamp));
        if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.05, 0.0, 30) {
            self.lights.push(pl.center.extend(pl.z + pl.size.z));
        }
    }

    fn bookcases(&mut self, n: usize, walls: &[usize], max_depth: f32) {
        for _ in 0..n {
            let p = self
                .piece(|m| is_bookcase(m) && m.size.y <= max_depth)
                .unwrap_or_else(|| self.proc_piece(Proc::Bookcase));
            if let Some(pl) = self.wall_piece(&p, walls, 0.0, 0.5, 40) {
                if pl.top < 1.5 {
                    let n = self.rng.random_range(1..=3);
                    self.on_top(&pl, n);
                }
            }
        }
    }

    fn floor_clutter(&mut self, n: usize) {
        for _ in 0..n {
            let kind = self.kind;
            if let Some(p) = self.piece(|m| is_floor_clutter(m, kind)) {
                self.wall_piece(&p, &ALL_WALLS, 0.03, 0.0, 20);
            }
        }
    }

    fn long_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [0, 2]
        } else {
            [1, 3]
        }
    }

    fn short_walls(&self) -> [usize; 2] {
        if self.layout.width >= self.layout.depth {
            [1, 3]
        } else {
            [0, 2]
        }
    }

    fn inner(&self, margin: f32) -> Rect2 {
        Rect2::new(Vec2::splat(margin), Vec2::new(self.layout.width, self.layout.depth) - Vec2::splat(margin))
    }

    // ----- recipes -----

    fn bedroom(&mut self) {
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

    fn living_room(&mut self) {
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

    /// A row of kitchen modules along wall `k` from `s0` to `s1`, with a fridge at the
    /// start sometimes, upper cabinets above sometimes, things on the counter.
    fn kitchen_row(&mut self, k: usize, s0: f32, s1: f32, fridge: bool) -> usize {
        let mut s = s0;
        let mut modules: Vec<Placed> = Vec::new();
        let mut stoves: Vec<Placed> = Vec::new();
        let mut first = true;
        let mut sink = false;
        let mut misses = 0;
        while s < s1 - 0.3 && misses < 12 {
            let room = s1 - s;
            let p = if first && fridge {
                self.piece(|m| is_fridge(m) && m.size.x <= room)
            } else if !sink && self.rng.random_bool(0.35) {
                sink = true;
                self.piece(|m| is_kitchen_lower(m) && is(m, &["sink"]) && m.size.x <= room)
            } else {
                self.piece(|m| is_kitchen_lower(m) && m.size.x <= room)
            };
            first = false;
            let Some(p) = p else {
                misses += 1;
                continue;
            };
            match self.wall_piece_at(&p, k, s + p.size.x * 0.5 + 0.002, 1.0, 0.0, 0.0) {
                Some(pl) => {
                    s += p.size.x + 0.004;
                    if matches!(&p.src, Src::Model { model, .. } if model.fine == "oven") {
                        stoves.push(pl);
                    }
                    if pl.size.z < 1.2 {
                        modules.push(pl);
                    }
                }
                None => {
                    s += 0.1;
                    misses += 1;
                }
            }
        }
        if modules.is_empty() {
            return 0;
        }
        // Keep the floor in front of the row free.
        let wall = self.layout.walls[k];
        let (a, b) = (modules.first().map_or(s0, |m| m.wall.map_or(s0, |w| w.1 - m.size.x * 0.5)), s);
        let depth = modules.iter().map(|m| m.size.y).fold(0.0, f32::max);
        self.layout.add_keepout(footprint(wall.point((a + b) * 0.5, depth + 0.35), (b - a).max(0.1), 0.7, wall.yaw));
        // A hood above the first stove.
        if let Some(st) = stoves.first().copied() {
            if let (Some(hood), Some((_, hs))) = (self.piece(|m| is(m, &["range_hood"]) && m.size.y <= 0.6), st.wall) {
                let z = if hood.elevation >= 1.4 { hood.elevation } else { st.top + 0.65 };
                let z = z.min(self.layout.height - 0.02 - hood.size.z);
                let half = hood.size.x * 0.5;
                if z > st.top + 0.4
                    && hs - half >= 0.0
                    && hs + half <= wall.length
                    && self.layout.wall_free(k, hs - half, hs + half, z, z + hood.size.z, 0.0)
                {
                    let center = wall.point(hs, hood.size.y * 0.5);
                    if self.emit(&hood, center, z, yaw_facing(wall.normal), Vec3::ONE) {
                        self.layout.reserve_wall(k, hs - half, hs + half, z, z + hood.size.z);
                        self.layout.interest.push(center.extend(z + hood.size.z * 0.5));
                    }
                }
            }
        }
        // Upper cabinets.
        if self.rng.random_bool(0.6) {
            let mut t = a;
            let mut misses = 0;
            while t < b - 0.3 && misses < 8 {
                let room = b - t;
                let Some(p) = self.piece(|m| is_kitchen_upper(m) && m.size.x <= room) else { break };
                let z = p.elevation.min(self.layout.height - 0.05 - p.size.z);
                let sc = t + p.size.x * 0.5 + 0.002;
                if z > 1.3 && self.layout.wall_free(k, sc - p.size.x * 0.5, sc + p.size.x * 0.5, z, z + p.size.z, 0.0) {
                    let center = wall.point(sc, p.size.y * 0.5);
                    if self.emit(&p, center, z, yaw_facing(wall.normal), Vec3::ONE) {
                        self.layout.reserve_wall(k, sc - p.size.x * 0.5, sc + p.size.x * 0.5, z, z + p.size.z);
                        self.layout.interest.push(center.extend(z + p.size.z * 0.5));
                    }
                    t += p.size.x + 0.004;
                } else {
                    t += 0.2;
                    misses += 1;
                }
            }
        }
        for m in &modules {
            let n = if self.rng.random_bool(0.5) { 1 } else { 0 };
            self.on_top(m, n);
        }
        modules.len()
    }

    /// The wall with the most free length, among `walls`.
    fn freest_wall(&self, walls: &[usize]) -> usize {
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

    fn kitchen(&mut self) {
        let k = self.freest_wall(&ALL_WALLS);
        let len = self.layout.walls[k].length;
        let fridge = self.rng.random_bool(0.75);
        let n = self.kitchen_row(k, 0.0, len, fridge);
        if n == 0 {
            // No kitchen models: cabinets and a counter table.
            for _ in 0..3 {
                let p = self.proc_piece(Proc::Cabinet);
                self.wall_piece(&p, &[k], 0.0, 0.0, 20);
            }
        }
        if self.rng.random_bool(0.5) {
            let k2 = if self.rng.random_bool(0.5) { (k + 1) % 4 } else { (k + 3) % 4 };
            let len2 = self.layout.walls[k2].length;
            self.kitchen_row(k2, 0.0, len2, false);
        }
        let r = self.inner(0.2);
        if self.dining_set(r, 4, false).is_none() && self.rng.random_bool(0.7) {
            // A small table against a wall with two chairs.
            if let Some(t) = self.piece(|m| is_table(m) && m.size.x <= 1.4) {
                if let Some(pl) = self.wall_piece(&t, &ALL_WALLS, 0.0, 0.0, 30) {
                    if let Some(c) = self.piece(is_chair) {
                        self.chairs_around(&pl, &c, true, false, 2);
                    }
                }
            }
        }
        if self.rng.random_bool(0.3) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=1);
        self.pictures(n);
    }

    fn bathroom(&mut self) {
        if let Some(p) = self.piece(is_toilet) {
            self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 60);
        }
        if let Some(p) = self.piece(is_washbasin) {
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 60) {
                let n = self.rng.random_range(0..=2);
                self.on_top(&pl, n);
                // A mirror above: a flat procedural panel, labelled clutter like S3DIS does.
                if let Some((k, s)) = pl.wall {
                    let z0 = (pl.z + pl.size.z + 0.15).max(1.1);
                    let (mw, mh) = (pl.size.x.clamp(0.4, 1.2), uniform(&mut self.rng, 0.5, 0.8));
                    if z0 + mh < self.layout.height - 0.1
                        && self.layout.wall_free(k, s - mw * 0.5, s + mw * 0.5, z0, z0 + mh, 0.0)
                    {
                        let wall = self.layout.walls[k];
                        self.b.place(wall.start.extend(0.0), wall.yaw);
                        let glass = jitter(&mut self.rng, [0.62, 0.66, 0.68], 0.08);
                        self.b.cuboid(
                            Vec3::new(s - mw * 0.5, 0.0, z0),
                            Vec3::new(s + mw * 0.5, 0.02, z0 + mh),
                            SKIP_NEG_Y,
                            SemanticClass::Clutter,
                            glass,
                        );
                        self.layout.reserve_wall(k, s - mw * 0.5, s + mw * 0.5, z0, z0 + mh);
                    }
                }
            }
        }
        if self.rng.random_bool(0.6) {
            if let Some(p) = self.piece(is_bathtub) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 60);
            }
        } else if let Some(p) = self.piece(is_shower) {
            self.wall_piece(&p, &ALL_WALLS, 0.0, 0.5, 60);
        }
        if self.rng.random_bool(0.4) {
            if let Some(p) = self.piece(|m| is_floor_cabinet(m) && m.size.y <= 0.5) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30);
            }
        }
        if self.rng.random_bool(0.25) {
            if let Some(p) = self.piece(|m| is(m, &["washing_machine"]) && on_floor(m)) {
                self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30);
            }
        }
        for _ in 0..self.rng.random_range(1..=2) {
            if let Some(p) = self.piece(is_towel_rack) {
                let z = if p.elevation > 0.3 { None } else { Some(uniform(&mut self.rng, 0.9, 1.3)) };
                self.wall_hang(&p, &ALL_WALLS, z, 20);
            }
        }
        if self.rng.random_bool(0.5) {
            let c = Vec2::new(self.layout.width, self.layout.depth) * 0.5;
            let yaw = if self.rng.random_bool(0.5) { 0.0 } else { FRAC_PI_2 };
            self.rug(c, yaw, Vec2::new(0.9, 0.6));
        }
    }

    fn studio(&mut self) {
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

    fn office(&mut self) {
        let (w, d) = (self.layout.width, self.layout.depth);
        let n = ((w + d) / 3.0) as usize + self.rng.random_range(0..=1);
        for _ in 0..n {
            self.desk_with_chair(&ALL_WALLS, true);
        }
        // A block of two desks face to face in the middle of a big office.
        if w.min(d) >= 5.0 && self.rng.random_bool(0.6) {
            if let Some(desk) = self.piece(|m| is_desk(m) && m.size.z <= 0.9) {
                let yaw = if w >= d { 0.0 } else { FRAC_PI_2 };
                let c = Vec2::new(w, d) * 0.5
                    + Vec2::new(uniform(&mut self.rng, -0.5, 0.5), uniform(&mut self.rng, -0.5, 0.5));
                let off = rot(Vec2::new(0.0, desk.size.y * 0.5 + 0.01), yaw);
                let chair = self.piece(is_office_chair).or_else(|| self.piece(is_chair));
                for (sign, y) in [(1.0f32, yaw + PI), (-1.0, yaw)] {
                    // Each desk's back towards the other.
                    if let Some(pl) = self.free_piece_at(&desk, c + off * sign, y, 1.0, 0.0) {
                        let n = self.rng.random_range(1..=3);
                        self.on_top(&pl, n);
                        if let Some(ch) = &chair {
                            let front = rot(Vec2::new(0.0, -1.0), y);
                            let cc = pl.center + front * (pl.size.y * 0.5 + 0.15 + ch.size.y * 0.5);
                            let cy = yaw_facing(-front) + uniform(&mut self.rng, -0.3, 0.3);
                            self.free_piece_at(ch, cc, cy, 1.0, 0.0);
                        }
                    }
                }
            }
        }
        let n = self.rng.random_range(1..=3);
        self.bookcases(n, &ALL_WALLS, 0.5);
        for _ in 0..self.rng.random_range(0..=2) {
            let p = self.piece(is_floor_cabinet).unwrap_or_else(|| self.proc_piece(Proc::Cabinet));
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.4, 30) {
                if pl.top < 1.3 {
                    self.on_top(&pl, 2);
                }
            }
        }
        let n = self.rng.random_range(1..=2);
        self.boards(n, &ALL_WALLS);
        if self.rng.random_bool(0.4) {
            if let Some(p) = self.piece(is_sofa) {
                self.wall_piece(&p, &ALL_WALLS, 0.05, 0.0, 30);
            }
        }
        for _ in 0..self.rng.random_range(1..=3) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=2);
        self.floor_clutter(n);
        let n = self.rng.random_range(0..=2);
        self.pictures(n);
    }

    fn conference(&mut self) {
        let (w, d) = (self.layout.width, self.layout.depth);
        let along_x = w >= d;
        let (long, short) = (w.max(d), w.min(d));
        let yaw = if along_x { 0.0 } else { FRAC_PI_2 };
        let c = Vec2::new(w, d) * 0.5 + Vec2::new(uniform(&mut self.rng, -0.2, 0.2), uniform(&mut self.rng, -0.2, 0.2));
        let table = self
            .piece(|m| is_table(m) && m.size.x >= 1.2 && m.size.y <= short - 2.4 && m.size.x <= long - 2.6)
            .unwrap_or_else(|| self.proc_piece(Proc::Table));
        // Tables end to end make the long table.
        let n = ((long - 2.8) / table.size.x).round().clamp(1.0, 3.0) as usize;
        let chair = match self.piece(is_chair) {
            Some(c) => c,
            None => {
                let swivel = self.rng.random_bool(0.5);
                let s = self.chair_style(swivel);
                self.proc_piece(s)
            }
        };
        let dir = rot(Vec2::X, yaw);
        let mut tables = Vec::new();
        for i in 0..n {
            let off = (i as f32 - (n as f32 - 1.0) * 0.5) * (table.size.x + 0.005);
            if let Some(t) = self.free_piece_at(&table, c + dir * off, yaw, 1.0, 0.0) {
                tables.push(t);
            }
        }
        let count = tables.len();
        for t in &tables {
            let ends = count == 1 && self.rng.random_bool(0.7);
            self.chairs_around(t, &chair, ends, true, 8);
            let n = self.rng.random_range(0..=3);
            self.on_top(t, n);
        }
        let ends = self.short_walls();
        self.boards(1, &ends);
        if self.rng.random_bool(0.4) {
            if let Some(tv) = self.piece(|m| is_tv(m) && m.elevation >= 0.5) {
                self.wall_hang(&tv, &ends, None, 20);
            }
        }
        let sides = self.long_walls();
        for _ in 0..self.rng.random_range(1..=2) {
            let p = self
                .piece(|m| is_floor_cabinet(m) && m.size.y <= 0.6)
                .unwrap_or_else(|| self.proc_piece(Proc::Cabinet));
            if let Some(pl) = self.wall_piece(&p, &ALL_WALLS, 0.0, 0.0, 30) {
                if pl.top < 1.3 {
                    self.on_top(&pl, 2);
                }
            }
        }
        if self.rng.random_bool(0.4) {
            self.bookcases(1, &sides, 0.45);
        }
        for _ in 0..self.rng.random_range(0..=2) {
            self.floor_plant(&ALL_WALLS);
        }
        let n = self.rng.random_range(0..=2);
        self.pictures(n);
    }

    fn corridor(&mut self) {
        let sides = self.long_walls();
        let width = self.layout.width.min(self.layout.depth);
        let max_d = (width - 1.0).min(0.5);
        for _ in 0..self.rng.random_range(1..=3) {
            let p = self.piece(|m| (is_floor_cabinet(m) || is_dresser(m) || is_bookcase(m)) && m.size.y <= max_d);
            if let Some(p) = p {
                if let Some(pl) = self.wall_piece(&p, &sides, 0.0, 0.0, 30) {
                    if pl.top < 1.3 {
                        self.on_top(&pl, 2);
                    }
                }
            }
        }
        if self.rng.random_bool(0.6) {
            if let Some(p) = self.piece(|m| is_bench(m) && m.size.y <= max_d) {
                self.wall_piece(&p, &sides, 0.02, 0.0, 30);
            }
        }
        if self.rng.random_bool(0.5) {
            let ends = self.short_walls();
            self.floor_plant(&ends);
        }
        if self.rng.random_bool(0.4) {
            self.boards(1, &sides);
        }
        let n = self.rng.random_range(1..=3);
        self.pictures(n);
    }

    // ----- walls -----

    /// A procedural picture (or clock) centred at `s`, `zc` on wall `k`, if the wall is free.
    fn picture_at(&mut self, k: usize, s: f32, zc: f32, w: f32, h: f32) -> bool {
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
        clutter::wall_item(&mut self.b, &mut self.rng, &self.pal, kind, s, zc, w, h);
        self.layout.reserve_wall(k, s0, s1, z0, z1);
        self.layout.interest.push(wall.point(s, 0.0).extend(zc));
        true
    }

    fn pictures(&mut self, n: usize) {
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
    fn boards(&mut self, n: usize, walls: &[usize]) {
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
    fn radiators(&mut self) {
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
    fn curtains(&mut self) {
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
    fn wall_details(&mut self) {
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

    fn ceiling_lamp(&mut self) {
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

    // ----- shell -----

    /// Doors and windows for the kind, catalogue models where they fit.
    fn plan_openings(&mut self) {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let long = if w >= d { [0usize, 2] } else { [1, 3] };
        let short = if w >= d { [1usize, 3] } else { [0, 2] };
        let (door_walls, n_doors): (Vec<usize>, usize) = match self.kind {
            HomeRoomKind::Corridor => (long.to_vec(), self.rng.random_range(2..=5)),
            HomeRoomKind::LivingRoom | HomeRoomKind::Office | HomeRoomKind::Conference => {
                (ALL_WALLS.to_vec(), self.rng.random_range(1..=2))
            }
            _ => (ALL_WALLS.to_vec(), 1),
        };
        let mut doors = 0;
        let mut tries = 0;
        while (doors < n_doors && tries < 100) || (doors == 0 && tries < 300) {
            tries += 1;
            let k = door_walls[self.rng.random_range(0..door_walls.len())];
            let len = self.layout.walls[k].length;
            let double =
                matches!(self.kind, HomeRoomKind::LivingRoom | HomeRoomKind::Conference) && self.rng.random_bool(0.25);
            let model = if self.rng.random_bool(0.75) {
                self.piece(|m| {
                    m.door_or_window
                        && is(m, &["door"])
                        && m.size.z >= 1.9
                        && m.size.z <= (h - 0.15).min(2.5)
                        && m.size.x >= 0.6
                        && m.size.x <= if double { 1.9 } else { 1.15 }
                })
            } else {
                None
            };
            let (dw, dh) = match &model {
                Some(p) => (p.size.x, p.size.z),
                None => {
                    let dw = if double { uniform(&mut self.rng, 1.4, 1.7) } else { uniform(&mut self.rng, 0.8, 0.95) };
                    (dw, uniform(&mut self.rng, 2.0, 2.15).min(h - 0.15))
                }
            };
            if len < dw + 0.7 {
                continue;
            }
            let s = uniform(&mut self.rng, 0.3 + dw * 0.5, len - 0.3 - dw * 0.5);
            let recess = uniform(&mut self.rng, 0.03, 0.07);
            if shell::try_add_opening(
                &mut self.layout,
                &mut self.openings,
                k,
                s,
                dw,
                0.0,
                dh,
                OpeningKind::Door,
                recess,
            ) {
                let wall = self.layout.walls[k];
                self.layout.add_keepout(footprint(wall.point(s, 0.45), dw + 0.2, 0.9, wall.yaw));
                self.opening_models.push(model);
                doors += 1;
            }
        }
        // Windows.
        let (outside, wanted, small): (Vec<usize>, usize, bool) = match self.kind {
            HomeRoomKind::Corridor => (vec![short[self.rng.random_range(0..2)]], self.rng.random_range(0..=1), false),
            HomeRoomKind::Bathroom => (ALL_WALLS.to_vec(), self.rng.random_range(0..=1), true),
            _ => {
                let first = self.rng.random_range(0..4);
                let walls = if self.rng.random_bool(0.35) { vec![first, (first + 1) % 4] } else { vec![first] };
                (walls, self.rng.random_range(1..=3), false)
            }
        };
        let mut windows = 0;
        let mut tries = 0;
        while windows < wanted && tries < 80 {
            tries += 1;
            let k = outside[self.rng.random_range(0..outside.len())];
            let len = self.layout.walls[k].length;
            let model = if self.rng.random_bool(0.7) {
                self.piece(|m| {
                    m.door_or_window
                        && is(m, &["window"])
                        && m.size.x >= 0.45
                        && m.size.x <= len - 0.8
                        && m.size.z >= 0.5
                        && m.size.y >= 0.05
                        && m.elevation + m.size.z <= h - 0.15
                        && (!small || (m.size.x <= 1.1 && m.size.z <= 1.4))
                })
            } else {
                None
            };
            let (ww, z0, z1) = match &model {
                Some(p) => {
                    let z0 = if p.elevation > 0.05 { p.elevation } else { 0.9 };
                    let z0 = z0.min(h - 0.15 - p.size.z);
                    (p.size.x, z0, z0 + p.size.z)
                }
                None if small => {
                    let z0 = uniform(&mut self.rng, 1.2, 1.5);
                    (uniform(&mut self.rng, 0.5, 0.9), z0, (z0 + uniform(&mut self.rng, 0.5, 0.8)).min(h - 0.2))
                }
                None => {
                    let z0 = uniform(&mut self.rng, 0.6, 1.0);
                    (uniform(&mut self.rng, 0.8, 1.8), z0, uniform(&mut self.rng, 2.0, 2.3).min(h - 0.2))
                }
            };
            if ww > len - 0.8 || z1 - z0 < 0.4 {
                continue;
            }
            let s = uniform(&mut self.rng, 0.4 + ww * 0.5, len - 0.4 - ww * 0.5);
            let recess = uniform(&mut self.rng, 0.08, 0.2);
            if shell::try_add_opening(
                &mut self.layout,
                &mut self.openings,
                k,
                s,
                ww,
                z0,
                z1,
                OpeningKind::Window,
                recess,
            ) {
                self.opening_models.push(model);
                let wall = self.layout.walls[k];
                self.lights.push(wall.point(s, 0.0).extend((z0 + z1) * 0.5));
                windows += 1;
            }
        }
    }

    /// Floor, ceiling, walls with their holes, skirting; returns the number of shell
    /// vertices (they get the material patterns).
    fn build_shell(&mut self) -> usize {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let kind = self.kind;
        let rng = &mut self.rng;
        let b = &mut self.b;
        b.place(Vec3::ZERO, 0.0);
        // Floor.
        let floor = FloorMaterial::draw(rng, kind);
        floor.build(b, rng, w, d);
        // Ceiling: white mostly.
        let ceiling = if rng.random_bool(0.85) {
            jitter(rng, [0.93, 0.93, 0.91], 0.03)
        } else {
            jitter_pick(rng, &[[0.85, 0.83, 0.78], [0.80, 0.82, 0.84]], 0.03)
        };
        b.set_noise(0.02);
        b.rect(Vec3::Z * h, Vec3::X * w, Vec3::Y * d, -Vec3::Z, SemanticClass::Ceiling, ceiling);
        // Walls: one paint, sometimes an accent wall.
        let paint = wall_paint(rng);
        let accent = if rng.random_bool(0.2) {
            let k = rng.random_range(0..4);
            Some((k, wall_paint(rng)))
        } else {
            None
        };
        b.set_noise(0.025);
        for k in 0..4 {
            let wall = self.layout.walls[k];
            let holes: Vec<[f32; 4]> =
                self.openings.iter().filter(|o| o.wall == k).map(|o| [o.s0, o.s1, o.z0, o.z1]).collect();
            let color = match accent {
                Some((a, c)) if a == k => c,
                _ => paint,
            };
            b.place(wall.start.extend(0.0), wall.yaw);
            b.rect_with_holes(
                Vec3::ZERO,
                Vec3::X * wall.length,
                Vec3::Z * h,
                Vec3::Y,
                &holes,
                SemanticClass::Wall,
                color,
            );
        }
        let shell_end = b.mesh.positions.len();
        // Tiles on the lower walls of bathrooms and some kitchens.
        let tiles = match kind {
            HomeRoomKind::Bathroom => rng.random_bool(0.8),
            HomeRoomKind::Kitchen => rng.random_bool(0.3),
            _ => false,
        };
        if tiles {
            let band = if kind == HomeRoomKind::Bathroom { uniform(rng, 1.2, h) } else { uniform(rng, 1.4, 1.7) };
            let t = uniform(rng, 0.1, 0.3);
            let tile = pick(
                rng,
                &[[0.93, 0.93, 0.92], [0.85, 0.88, 0.90], [0.80, 0.85, 0.82], [0.75, 0.72, 0.68], [0.35, 0.45, 0.55]],
            );
            let tile = jitter(rng, tile, 0.04);
            let seed: u64 = rng.random();
            let m = &mut b.mesh;
            for i in 0..shell_end {
                if m.vertex_labels[i] != SemanticClass::Wall.id() || m.positions[i].z > band {
                    continue;
                }
                let p = m.positions[i];
                let along = if m.normals[i].x.abs() > 0.5 { p.y } else { p.x };
                let cell = splitmix(
                    seed ^ ((along / t).floor() as i64 as u64).wrapping_mul(31)
                        ^ ((p.z / t).floor() as i64 as u64) << 20,
                );
                let c = scale_rgb(tile, 1.0 + 0.08 * (unit(cell) - 0.5));
                m.colors[i] = to_u8(c);
            }
        }
        // Skirting boards along the walls, except across door openings.
        if kind != HomeRoomKind::Bathroom && rng.random_bool(0.75) {
            let sk_h = uniform(rng, 0.05, 0.1);
            let sk_t = uniform(rng, 0.01, 0.02);
            let sk_c =
                if rng.random_bool(0.6) { jitter(rng, [0.92, 0.92, 0.9], 0.03) } else { scale_rgb(floor.base, 0.8) };
            b.set_noise(0.02);
            for k in 0..4 {
                let wall = self.layout.walls[k];
                let mut cuts: Vec<(f32, f32)> = self
                    .openings
                    .iter()
                    .filter(|o| o.wall == k && o.z0 < sk_h)
                    .map(|o| (o.s0 - 0.1, o.s1 + 0.1))
                    .collect();
                cuts.sort_by(|a, b| a.0.total_cmp(&b.0));
                let mut s = 0.0;
                b.place(wall.start.extend(0.0), wall.yaw);
                for (a, c) in cuts.into_iter().chain(std::iter::once((wall.length, wall.length))) {
                    if a - s > 0.05 {
                        b.cuboid(
                            Vec3::new(s, 0.0, 0.0),
                            Vec3::new(a, sk_t, sk_h),
                            SKIP_NEG_Y,
                            SemanticClass::Wall,
                            sk_c,
                        );
                    }
                    s = s.max(c);
                }
            }
        }
        b.set_noise(0.06);
        shell_end
    }

    /// Catalogue doors and windows in their openings, the procedural ones elsewhere.
    fn fill_openings(&mut self) {
        let openings = self.openings.clone();
        let models = std::mem::take(&mut self.opening_models);
        for (o, model) in openings.iter().zip(models) {
            let wall = self.layout.walls[o.wall];
            match model {
                Some(p) => {
                    let s = (o.s0 + o.s1) * 0.5;
                    let depth = p.size.y.min(0.35);
                    let scale = Vec3::new((o.s1 - o.s0) / p.size.x, depth / p.size.y, (o.z1 - o.z0) / p.size.z);
                    // The model's front at the wall plane, its body in the wall behind it.
                    let center = wall.point(s, -depth * 0.5);
                    self.emit(&p, center, o.z0, yaw_facing(wall.normal), scale);
                    // A backing behind it: glass, or a closed leaf, for what the model leaves open.
                    let (class, color) = match o.kind {
                        OpeningKind::Window => (SemanticClass::Window, jitter(&mut self.rng, self.pal.glass, 0.05)),
                        OpeningKind::Door => (SemanticClass::Door, jitter(&mut self.rng, self.pal.door, 0.05)),
                    };
                    self.b.place(wall.start.extend(0.0), wall.yaw);
                    self.b.set_noise(0.03);
                    self.b.rect(
                        Vec3::new(o.s0, -depth - 0.01, o.z0),
                        Vec3::X * (o.s1 - o.s0),
                        Vec3::Z * (o.z1 - o.z0),
                        Vec3::Y,
                        class,
                        color,
                    );
                    // Reveals between the wall plane and the backing where the model is thinner.
                    self.b.set_noise(0.06);
                }
                None => {
                    self.b.place(wall.start.extend(0.0), wall.yaw);
                    match o.kind {
                        OpeningKind::Window => shell::window(&mut self.b, o, &mut self.rng, &self.pal),
                        OpeningKind::Door => shell::door(&mut self.b, o, &mut self.rng, &self.pal),
                    }
                }
            }
        }
    }

    /// Bakes slow light variation into every colour: darker towards corners and the
    /// ceiling edges and away from windows and lamps, with a white balance per room.
    fn bake_light(&mut self, _shell_end: usize) {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let exposure = uniform(&mut self.rng, 0.85, 1.08);
        let warm = uniform(&mut self.rng, -0.05, 0.06);
        let balance = [1.0 + warm, 1.0, 1.0 - warm];
        let lights = self.lights.clone();
        let m = &mut self.b.mesh;
        for (p, c) in m.positions.iter().zip(m.colors.iter_mut()) {
            let dx = p.x.min(w - p.x).max(0.0);
            let dy = p.y.min(d - p.y).max(0.0);
            let dz_c = (h - p.z).max(0.0);
            let corner = 0.14 * (-(dx + dy) / 0.35).exp()
                + 0.08 * (-(dx.min(dy) + dz_c) / 0.3).exp()
                + 0.06 * (-(dx.min(dy) + p.z) / 0.25).exp();
            let mut lit = 0.0f32;
            for l in &lights {
                lit = lit.max((-(*p - *l).length() / 3.0).exp());
            }
            let f = exposure * (0.8 + 0.25 * lit) * (1.0 - corner);
            for k in 0..3 {
                c[k] = (c[k] as f32 * f * balance[k]).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Materials and colours.

/// A floor covering.
struct FloorMaterial {
    kind: FloorKind,
    base: Rgb,
}

#[derive(Clone, Copy, PartialEq)]
enum FloorKind {
    Planks,
    Laminate,
    Tiles,
    Carpet,
    Plain,
}

impl FloorMaterial {
    fn draw(rng: &mut ChaCha8Rng, kind: HomeRoomKind) -> Self {
        use FloorKind::*;
        let options: &[FloorKind] = match kind {
            HomeRoomKind::Bathroom => &[Tiles, Tiles, Tiles, Tiles, Plain],
            HomeRoomKind::Kitchen => &[Tiles, Tiles, Tiles, Laminate, Planks, Plain],
            HomeRoomKind::Bedroom => &[Planks, Planks, Laminate, Carpet, Carpet],
            HomeRoomKind::LivingRoom | HomeRoomKind::Studio => &[Planks, Planks, Laminate, Tiles, Carpet],
            HomeRoomKind::Office | HomeRoomKind::Conference => &[Carpet, Carpet, Laminate, Plain, Tiles],
            HomeRoomKind::Corridor => &[Tiles, Planks, Laminate, Plain, Carpet],
        };
        let fk = pick(rng, options);
        let base = match fk {
            Planks | Laminate => jitter_pick(
                rng,
                &[[0.72, 0.55, 0.36], [0.58, 0.40, 0.24], [0.42, 0.28, 0.17], [0.80, 0.68, 0.50], [0.62, 0.55, 0.48]],
                0.05,
            ),
            Tiles => jitter_pick(
                rng,
                &[[0.85, 0.84, 0.80], [0.62, 0.62, 0.60], [0.75, 0.68, 0.58], [0.35, 0.35, 0.37], [0.55, 0.42, 0.32]],
                0.05,
            ),
            Carpet => jitter_pick(
                rng,
                &[[0.45, 0.45, 0.47], [0.30, 0.32, 0.40], [0.55, 0.50, 0.42], [0.35, 0.30, 0.28], [0.62, 0.60, 0.55]],
                0.05,
            ),
            Plain => jitter_pick(rng, &[[0.60, 0.60, 0.58], [0.70, 0.68, 0.64], [0.48, 0.50, 0.52]], 0.05),
        };
        Self { kind: fk, base }
    }

    /// Emits the floor rectangle `[0, w] x [0, d]` (z = 0, facing up) in this material:
    /// planks and tiles as separate pieces with their own tone, grout between tiles.
    fn build(&self, b: &mut MeshBuilder, rng: &mut ChaCha8Rng, w: f32, d: f32) {
        let class = SemanticClass::Floor;
        match self.kind {
            FloorKind::Planks | FloorKind::Laminate => {
                let laminate = self.kind == FloorKind::Laminate;
                let along_x = rng.random_bool(0.5);
                let (len_u, len_v) = if along_x { (w, d) } else { (d, w) };
                let pw = if laminate { uniform(rng, 0.18, 0.22) } else { uniform(rng, 0.1, 0.2) };
                let pl = if laminate { uniform(rng, 1.2, 1.4) } else { uniform(rng, 0.6, 1.6) };
                let var = if laminate { 0.06 } else { 0.14 };
                b.set_noise(if laminate { 0.02 } else { 0.04 });
                let mut v = 0.0;
                while v < len_v - 1e-4 {
                    let v1 = (v + pw).min(len_v);
                    let mut u = -uniform(rng, 0.0, pl);
                    while u < len_u - 1e-4 {
                        let this = if laminate { pl } else { pl * uniform(rng, 0.6, 1.4) };
                        let (u0, u1) = (u.max(0.0), (u + this).min(len_u));
                        let tone = 1.0 + var * (rng.random::<f32>() * 2.0 - 1.0);
                        let mut c = scale_rgb(self.base, tone);
                        c[0] = (c[0] + uniform(rng, -0.02, 0.02)).clamp(0.0, 1.0);
                        let (corner, du, dv) = if along_x {
                            (Vec3::new(u0, v, 0.0), Vec3::X * (u1 - u0), Vec3::Y * (v1 - v))
                        } else {
                            (Vec3::new(v, u0, 0.0), Vec3::Y * (u1 - u0), Vec3::X * (v1 - v))
                        };
                        if u1 - u0 > 1e-3 {
                            b.rect(corner, du, dv, Vec3::Z, class, c);
                        }
                        u += this;
                    }
                    v = v1;
                }
            }
            FloorKind::Tiles => {
                let t = uniform(rng, 0.3, 0.6);
                let g = 0.008;
                let checker = rng.random_bool(0.15);
                let second = jitter(rng, scale_rgb(self.base, 0.6), 0.05);
                let grout = jitter(rng, scale_rgb(self.base, 0.72), 0.04);
                b.set_noise(0.02);
                let (nx, ny) = ((w / t).ceil() as usize, (d / t).ceil() as usize);
                for j in 0..ny {
                    let (y0, y1) = (j as f32 * t, ((j + 1) as f32 * t).min(d));
                    for i in 0..nx {
                        let (x0, x1) = (i as f32 * t, ((i + 1) as f32 * t).min(w));
                        let base = if checker && (i + j) % 2 == 1 { second } else { self.base };
                        let c = scale_rgb(base, 1.0 + uniform(rng, -0.04, 0.04));
                        // The tile, inset by half the grout on inner edges; the grout strips fill the rest.
                        let a0 = if i > 0 { x0 + g * 0.5 } else { x0 };
                        let a1 = if x1 < w { x1 - g * 0.5 } else { x1 };
                        let c0 = if j > 0 { y0 + g * 0.5 } else { y0 };
                        let c1 = if y1 < d { y1 - g * 0.5 } else { y1 };
                        if a1 - a0 > 1e-3 && c1 - c0 > 1e-3 {
                            b.rect(Vec3::new(a0, c0, 0.0), Vec3::X * (a1 - a0), Vec3::Y * (c1 - c0), Vec3::Z, class, c);
                        }
                        // Grout to the right of this tile and above it.
                        if x1 < w {
                            b.rect(Vec3::new(a1, c0, 0.0), Vec3::X * g, Vec3::Y * (c1 - c0), Vec3::Z, class, grout);
                        }
                        if y1 < d {
                            let e1 = if x1 < w { x1 + g * 0.5 } else { x1 };
                            b.rect(Vec3::new(a0, c1, 0.0), Vec3::X * (e1 - a0), Vec3::Y * g, Vec3::Z, class, grout);
                        }
                    }
                }
            }
            FloorKind::Carpet => {
                b.set_noise(0.09);
                b.rect(Vec3::ZERO, Vec3::X * w, Vec3::Y * d, Vec3::Z, class, self.base);
            }
            FloorKind::Plain => {
                b.set_noise(0.05);
                b.rect(Vec3::ZERO, Vec3::X * w, Vec3::Y * d, Vec3::Z, class, self.base);
            }
        }
        b.set_noise(0.06);
    }
}

/// A wall paint: white or off-white most of the time, a pastel sometimes, a colour rarely.
fn wall_paint(rng: &mut ChaCha8Rng) -> Rgb {
    match rng.random_range(0..10) {
        0..=5 => jitter_pick(
            rng,
            &[[0.93, 0.93, 0.91], [0.90, 0.88, 0.83], [0.88, 0.86, 0.80], [0.91, 0.91, 0.93], [0.84, 0.83, 0.80]],
            0.03,
        ),
        6..=8 => jitter_pick(
            rng,
            &[
                [0.86, 0.82, 0.70],
                [0.78, 0.86, 0.84],
                [0.84, 0.80, 0.86],
                [0.88, 0.80, 0.74],
                [0.80, 0.84, 0.74],
                [0.76, 0.80, 0.86],
            ],
            0.04,
        ),
        _ => jitter_pick(
            rng,
            &[[0.45, 0.55, 0.62], [0.60, 0.35, 0.30], [0.35, 0.45, 0.38], [0.70, 0.60, 0.35], [0.40, 0.40, 0.45]],
            0.05,
        ),
    }
}

fn scale_rgb(c: Rgb, f: f32) -> Rgb {
    c.map(|x| (x * f).clamp(0.0, 1.0))
}

fn to_u8(c: Rgb) -> [u8; 3] {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
}

fn unit(bits: u64) -> f32 {
    (bits & 0xFFFF) as f32 / 65535.0
}

/// Colour change of one placed model: brightness, and optionally a new hue.
struct Paint {
    gain: f32,
    /// (new hue in turns, saturation factor, strength of the pull of grey towards it).
    hue: Option<(f32, f32, f32)>,
}

impl Paint {
    fn apply(&self, c: [u8; 3]) -> [u8; 3] {
        let rgb = c.map(|x| x as f32 / 255.0);
        let out = match self.hue {
            None => rgb,
            Some((hue, sat, pull)) => {
                let (_, s, v) = rgb_to_hsv(rgb);
                let s2 = (s * sat).max(pull).min(1.0);
                hsv_to_rgb(hue, s2, v)
            }
        };
        to_u8(out.map(|x| x * self.gain))
    }
}

fn rgb_to_hsv(c: Rgb) -> (f32, f32, f32) {
    let (r, g, b) = (c[0], c[1], c[2]);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let delta = max - min;
    let h = if delta < 1e-6 {
        0.0
    } else if max == r {
        ((g - b) / delta).rem_euclid(6.0) / 6.0
    } else if max == g {
        ((b - r) / delta + 2.0) / 6.0
    } else {
        ((r - g) / delta + 4.0) / 6.0
    };
    let s = if max > 1e-6 { delta / max } else { 0.0 };
    (h, s, max)
}

fn hsv_to_rgb(h: f32, s: f32, v: f32) -> Rgb {
    let h6 = h.rem_euclid(1.0) * 6.0;
    let c = v * s;
    let x = c * (1.0 - (h6 % 2.0 - 1.0).abs());
    let (r, g, b) = match h6 as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r + m, g + m, b + m]
}

/// Height above the bottom of the highest large horizontal surface of a mesh (a table's
/// top, a counter, a shelf's top board): what things placed on it stand on.
fn support_top(mesh: &LabeledMesh, lo: Vec3, size: Vec3) -> f32 {
    const BIN: f32 = 0.02;
    let n = (size.z / BIN).ceil() as usize + 1;
    let mut area = vec![0.0f32; n];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let cr = (b - a).cross(c - a);
        let len = cr.length();
        if len < 1e-12 || cr.z.abs() < 0.9 * len {
            continue;
        }
        let z = (a.z + b.z + c.z) / 3.0 - lo.z;
        let k = ((z / BIN) as usize).min(n - 1);
        area[k] += 0.5 * len;
    }
    let need = 0.2 * size.x * size.y;
    for k in (0..n).rev() {
        if area[k] >= need {
            return ((k as f32 + 1.0) * BIN).min(size.z);
        }
    }
    size.z
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// A fake catalogue: one box per model, its front face (-y) darker so that tests can
    /// tell which way it faces.
    pub(crate) struct BoxLibrary {
        models: Vec<LibraryModel>,
        meshes: HashMap<String, Arc<LabeledMesh>>,
    }

    fn box_mesh(size: Vec3, class: u8, color: [u8; 3]) -> LabeledMesh {
        let mut b = MeshBuilder::new(0.5, 1);
        let cls = SemanticClass::from_id(class).unwrap_or(SemanticClass::Clutter);
        let c = color.map(|x| x as f32 / 255.0);
        b.cuboid(Vec3::ZERO, size, 0, cls, c);
        // The front face marked dark.
        b.rect(Vec3::new(0.0, -0.001, 0.0), Vec3::X * size.x, Vec3::Z * size.z, -Vec3::Y, cls, [0.05; 3]);
        b.finish()
    }

    impl BoxLibrary {
        pub(crate) fn new() -> Self {
            // (fine, class, w, d, h, elevation, door_or_window, category, name)
            #[allow(clippy::type_complexity)]
            let specs: &[(&str, u8, f32, f32, f32, f32, bool, &str, &str)] = &[
                ("bed", 12, 1.6, 2.1, 0.9, 0.0, false, "Bedroom", "Bed"),
                ("bed", 12, 0.95, 2.0, 0.8, 0.0, false, "Bedroom", "Single bed"),
                ("nightstand", 12, 0.5, 0.45, 0.5, 0.0, false, "Bedroom", "Bedside table"),
                ("wardrobe", 12, 1.5, 0.6, 2.1, 0.0, false, "Bedroom", "Wardrobe"),
                ("dresser", 12, 1.2, 0.5, 0.85, 0.0, false, "Bedroom", "Chest"),
                ("sofa", 10, 2.0, 0.9, 0.85, 0.0, false, "Living room", "Sofa"),
                ("armchair", 7, 0.85, 0.85, 0.9, 0.0, false, "Living room", "Armchair"),
                ("coffee_table", 8, 1.1, 0.6, 0.45, 0.0, false, "Living room", "Coffee table"),
                ("table", 8, 1.6, 0.9, 0.75, 0.0, false, "Kitchen", "Table"),
                ("table", 8, 1.0, 0.8, 0.74, 0.0, false, "Kitchen", "Small table"),
                ("chair", 7, 0.45, 0.5, 0.9, 0.0, false, "Kitchen", "Chair"),
                ("chair", 7, 0.62, 0.62, 1.1, 0.0, false, "Office", "Office chair"),
                ("desk", 8, 1.4, 0.7, 0.75, 0.0, false, "Office", "Desk"),
                ("bookcase", 9, 0.9, 0.35, 1.8, 0.0, false, "Living room", "Bookcase"),
                ("shelf", 12, 0.8, 0.4, 0.8, 0.0, false, "Living room", "Shelves"),
                ("cabinet", 12, 0.6, 0.6, 0.88, 0.0, false, "Kitchen", "Lower cabinet"),
                ("cabinet", 12, 0.6, 0.4, 0.72, 1.45, false, "Kitchen", "Upper cabinet"),
                ("cabinet", 12, 0.45, 0.5, 0.6, 0.0, false, "Office", "Filing cabinet"),
                ("sink", 12, 0.9, 0.6, 0.95, 0.0, false, "Kitchen", "Sink"),
                ("oven", 12, 0.6, 0.6, 0.9, 0.0, false, "Kitchen", "Stove"),
                ("fridge", 12, 0.7, 0.7, 1.8, 0.0, false, "Kitchen", "Fridge"),
                ("tv", 12, 0.9, 0.15, 0.55, 0.0, false, "Living room", "TV"),
                ("toilet", 12, 0.4, 0.65, 0.75, 0.0, false, "Bathroom", "Toilets unit"),
                ("sink", 12, 0.6, 0.45, 0.9, 0.0, false, "Bathroom", "Washbasin"),
                ("bathtub", 12, 1.7, 0.7, 0.6, 0.0, false, "Bathroom", "Bath"),
                ("shower", 12, 0.9, 0.9, 2.0, 0.0, false, "Bathroom", "Shower stall"),
                ("towel", 12, 0.6, 0.1, 0.45, 0.4, false, "Bathroom", "Towel rack"),
                ("radiator", 12, 0.8, 0.12, 0.6, 0.1, false, "Miscellaneous", "Radiator"),
                ("rug", 12, 1.6, 2.2, 0.01, 0.0, false, "Living room", "Rug"),
                ("curtain", 12, 1.3, 0.05, 2.2, 0.08, false, "Living room", "Curtain"),
                ("lamp", 12, 0.4, 0.4, 1.6, 0.0, false, "Lights", "Floor lamp"),
                ("lamp", 12, 0.3, 0.3, 0.45, 0.0, false, "Lights", "Little lamp"),
                ("lamp", 12, 0.5, 0.5, 0.6, 1.9, false, "Lights", "Hanging light"),
                ("plant", 12, 0.5, 0.5, 1.2, 0.0, false, "Living room", "Plant"),
                ("plant", 12, 0.2, 0.2, 0.3, 0.0, false, "Living room", "Little plant"),
                ("vase", 12, 0.15, 0.15, 0.3, 0.0, false, "Living room", "Vase"),
                ("kitchenware", 12, 0.3, 0.2, 0.15, 0.0, false, "Kitchen", "Pan"),
                ("computer", 12, 0.35, 0.25, 0.3, 0.0, false, "Office", "Laptop"),
                ("bathroom_accessory", 12, 0.1, 0.1, 0.2, 0.0, false, "Bathroom", "Soap"),
                ("whiteboard", 11, 1.25, 0.55, 1.3, 0.0, false, "Office", "White board"),
                ("bench", 7, 1.2, 0.45, 0.45, 0.0, false, "Miscellaneous", "Bench"),
                ("box", 12, 0.5, 0.4, 0.4, 0.0, false, "Miscellaneous", "Box"),
                ("wall_socket", 12, 0.08, 0.03, 0.08, 0.3, false, "Miscellaneous", "Wall socket"),
                ("door", 6, 0.9, 0.15, 2.05, 0.0, true, "Doors and windows", "Door"),
                ("window", 5, 1.1, 0.3, 1.3, 0.85, true, "Doors and windows", "Window"),
            ];
            let mut models = Vec::new();
            let mut meshes = HashMap::new();
            for (split, tag) in [(Split::Train, "train"), (Split::HeldOut, "held")] {
                for (i, &(fine, class, w, d, h, e, dw, cat, name)) in specs.iter().enumerate() {
                    let id = format!("fake-{tag}#{fine}{i}");
                    let size = Vec3::new(w, d, h);
                    let color = [(40 + i * 4) as u8, 120, if split == Split::Train { 200 } else { 90 }];
                    meshes.insert(id.clone(), Arc::new(box_mesh(size, class, color)));
                    models.push(LibraryModel {
                        catalogue: format!("Fake{tag}"),
                        id,
                        name: name.to_string(),
                        category: cat.to_string(),
                        fine: fine.to_string(),
                        class,
                        size,
                        elevation: e,
                        door_or_window: dw,
                        creator: "test".into(),
                        split,
                    });
                }
            }
            Self { models, meshes }
        }
    }

    impl ModelSource for BoxLibrary {
        fn models(&self) -> &[LibraryModel] {
            &self.models
        }

        fn mesh(&self, model: &LibraryModel) -> Result<Arc<LabeledMesh>> {
            self.meshes.get(&model.id).cloned().ok_or_else(|| DataError::InvalidArgument(format!("no {}", model.id)))
        }
    }

    fn room(lib: &BoxLibrary, seed: u64, kind: HomeRoomKind, split: Split) -> LibraryRoom {
        generate_library_room_detailed(&LibraryRoomConfig { seed, kind: Some(kind), split }, lib)
            .unwrap_or_else(|e| panic!("{kind} seed {seed}: {e}"))
    }

    #[test]
    fn kind_names_round_trip() {
        for k in HomeRoomKind::ALL {
            assert_eq!(k.name().parse::<HomeRoomKind>().ok(), Some(k));
        }
        assert_eq!("Living Room".parse::<HomeRoomKind>().ok(), Some(HomeRoomKind::LivingRoom));
        assert!("garage".parse::<HomeRoomKind>().is_err());
    }

    #[test]
    fn every_kind_generates_valid_closed_rooms() {
        let lib = BoxLibrary::new();
        for kind in HomeRoomKind::ALL {
            for seed in 0..6 {
                let r = room(&lib, seed, kind, Split::Train);
                let m = &r.room.mesh;
                m.validate().unwrap_or_else(|e| panic!("{kind} {seed}: {e}"));
                assert_eq!(m.normals.len(), m.positions.len());
                assert_eq!(m.vertex_labels.len(), m.positions.len());
                assert!(m.triangle_labels.iter().all(|&l| (l as usize) < SemanticClass::COUNT));
                assert!(m.vertex_labels.iter().all(|&l| (l as usize) < SemanticClass::COUNT));
                for class in [SemanticClass::Floor, SemanticClass::Ceiling, SemanticClass::Wall, SemanticClass::Door] {
                    assert!(m.triangle_labels.contains(&class.id()), "{kind} {seed}: no {}", class.name());
                }
                assert!(m.triangle_count() <= MAX_TRIANGLES + 100_000);
                assert!(!r.model_ids.is_empty(), "{kind} {seed}: no models");
                let (w, d, h) = (r.room.floor_max.x, r.room.floor_max.y, r.room.ceiling_height);
                // Everything inside the room; doors and windows may sit in the wall behind.
                for (p, &l) in m.positions.iter().zip(&m.vertex_labels) {
                    // Reveals and thresholds of openings lie in the wall's thickness.
                    let slack =
                        if [SemanticClass::Door, SemanticClass::Window, SemanticClass::Wall, SemanticClass::Floor]
                            .iter()
                            .any(|c| c.id() == l)
                        {
                            0.4
                        } else {
                            1e-3
                        };
                    assert!(
                        p.x >= -slack
                            && p.y >= -slack
                            && p.x <= w + slack
                            && p.y <= d + slack
                            && p.z >= -1e-3
                            && p.z <= h + 1e-3,
                        "{kind} {seed}: vertex {p} (class {l}) outside {w} x {d} x {h}"
                    );
                }
                // Obstacles inside the floor and pairwise disjoint.
                for (i, a) in r.room.obstacles.iter().enumerate() {
                    assert!(a.0.x >= -1e-4 && a.0.y >= -1e-4 && a.1.x <= w + 1e-4 && a.1.y <= d + 1e-4);
                    for b in &r.room.obstacles[i + 1..] {
                        let overlap = a.0.x < b.1.x - 1e-4
                            && b.0.x < a.1.x - 1e-4
                            && a.0.y < b.1.y - 1e-4
                            && b.0.y < a.1.y - 1e-4;
                        assert!(!overlap, "{kind} {seed}: obstacles {a:?} and {b:?} overlap");
                    }
                }
                assert!(!r.room.interest_points.is_empty());
            }
        }
    }

    #[test]
    fn scan_paths_find_their_way_through_every_kind() {
        let lib = BoxLibrary::new();
        for kind in HomeRoomKind::ALL {
            for seed in 0..4 {
                let r = room(&lib, seed, kind, Split::Train).room;
                let layout = crate::scan_path::RoomLayout {
                    floor_min: r.floor_min,
                    floor_max: r.floor_max,
                    floor_z: 0.0,
                    ceiling_height: r.ceiling_height,
                    obstacles: r.obstacles.clone(),
                    interest_points: r.interest_points.clone(),
                };
                let plan = crate::scan_path::ScanPlan::new(layout, seed);
                plan.poses(60).unwrap_or_else(|e| panic!("{kind} {seed}: {e}"));
            }
        }
    }

    #[test]
    fn rooms_are_deterministic_and_kinds_drawn_from_the_seed_are_stable() {
        let lib = BoxLibrary::new();
        for seed in 0..8 {
            let a = generate_library_room_detailed(&LibraryRoomConfig::new(seed), &lib).expect("room");
            let b = generate_library_room_detailed(&LibraryRoomConfig::new(seed), &lib).expect("room");
            assert_eq!(a, b);
            let given = generate_library_room_detailed(
                &LibraryRoomConfig { seed, kind: Some(a.kind), split: Split::Train },
                &lib,
            )
            .expect("room");
            assert_eq!(a, given, "seed {seed}: naming the drawn kind changes the room");
        }
        let kinds: BTreeSet<&str> = (0..64)
            .map(|seed| generate_library_room_detailed(&LibraryRoomConfig::new(seed), &lib).expect("room").kind.name())
            .collect();
        assert_eq!(kinds.len(), HomeRoomKind::ALL.len(), "64 seeds draw every kind");
    }

    #[test]
    fn splits_use_only_their_own_models() {
        let lib = BoxLibrary::new();
        for kind in HomeRoomKind::ALL {
            for seed in 0..3 {
                for (split, tag) in [(Split::Train, "fake-train#"), (Split::HeldOut, "fake-held#")] {
                    let r = room(&lib, seed, kind, split);
                    assert!(r.model_ids.iter().all(|id| id.starts_with(tag)), "{kind} {seed}: {:?}", r.model_ids);
                }
            }
        }
    }

    #[test]
    fn wall_furniture_faces_into_the_room() {
        // The fake models' fronts are dark: in a bedroom, the dark faces of the wardrobe and
        // bed must point away from the nearest wall.
        let lib = BoxLibrary::new();
        for seed in 0..6 {
            let r = room(&lib, seed, HomeRoomKind::Bedroom, Split::Train).room;
            let m = &r.mesh;
            let (w, d) = (r.floor_max.x, r.floor_max.y);
            let mut checked = 0;
            for (t, &l) in m.triangles.iter().zip(&m.triangle_labels) {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                let dark = t.iter().all(|&i| m.colors[i as usize].iter().all(|&x| x < 40));
                let outside = a.x < 0.0 || a.y < 0.0 || a.x > w || a.y > d;
                if !dark
                    || outside
                    || [SemanticClass::Wall, SemanticClass::Door, SemanticClass::Window].iter().any(|c| c.id() == l)
                {
                    continue;
                }
                let n = (b - a).cross(c - a).normalize_or_zero();
                let p = (a + b + c) / 3.0;
                // Nearest wall's inward normal.
                let dists = [(p.y, Vec2::Y), (w - p.x, -Vec2::X), (d - p.y, -Vec2::Y), (p.x, Vec2::X)];
                let (dist, inward) =
                    dists.iter().fold((f32::MAX, Vec2::ZERO), |acc, x| if x.0 < acc.0 { *x } else { acc });
                if dist < 0.1 && n.z.abs() < 0.5 {
                    // A dark face right at a wall would be a back turned to the room.
                    assert!(n.truncate().dot(inward) > -0.5, "seed {seed}: a front faces the wall at {p}");
                }
                checked += 1;
            }
            assert!(checked > 0);
        }
    }

    #[test]
    fn colour_helpers_round_trip() {
        for c in [[0.2, 0.5, 0.8], [0.9, 0.1, 0.1], [0.5, 0.5, 0.5]] {
            let (h, s, v) = rgb_to_hsv(c);
            let back = hsv_to_rgb(h, s, v);
            for k in 0..3 {
                assert!((back[k] - c[k]).abs() < 1e-4, "{c:?} -> {back:?}");
            }
        }
        assert!((yaw_facing(Vec2::Y) - PI).abs() < 1e-6);
        let front = rot(Vec2::new(0.0, -1.0), yaw_facing(Vec2::new(1.0, 0.0)));
        assert!((front - Vec2::X).length() < 1e-5);
    }
}
