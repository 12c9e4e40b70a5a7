//! Unit tests of the room generator on a fake catalogue of boxes (`BoxLibrary`): every kind
//! generates valid closed rooms that a scan path can get through, the same for the same
//! seed, from its own split's models only, with wall furniture facing into the room; and
//! the colour and yaw helpers.

use std::collections::{BTreeSet, HashMap};
use std::f32::consts::PI;
use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::pieces::{hsv_to_rgb, rgb_to_hsv, rot, yaw_facing};
use super::{generate_library_room_detailed, HomeRoomKind, LibraryRoom, LibraryRoomConfig, ModelSource, MAX_TRIANGLES};
use crate::class::SemanticClass;
use crate::error::{DataError, Result};
use crate::library::{LibraryModel, Split};
use crate::mesh::LabeledMesh;
use crate::synth::shapes::MeshBuilder;

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
    let mut beyond_open_doors = 0;
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
            // Everything inside the room; doors and windows may sit in the wall behind, and
            // an open door shows the floor, walls and ceiling of the space behind it.
            for (p, &l) in m.positions.iter().zip(&m.vertex_labels) {
                let is = |classes: &[SemanticClass]| classes.iter().any(|c| c.id() == l);
                // Reveals and thresholds of openings lie in the wall's thickness.
                let slack = if is(&[SemanticClass::Floor, SemanticClass::Wall, SemanticClass::Ceiling]) {
                    2.75
                } else if is(&[SemanticClass::Door, SemanticClass::Window]) {
                    0.4
                } else {
                    1e-3
                };
                let outside = (-p.x).max(-p.y).max(p.x - w).max(p.y - d);
                if outside > 0.4 {
                    beyond_open_doors += 1;
                }
                assert!(
                    outside <= slack && p.z >= -1e-3 && p.z <= h + 1e-3,
                    "{kind} {seed}: vertex {p} (class {l}) outside {w} x {d} x {h}"
                );
            }
            // Obstacles inside the floor and pairwise disjoint.
            for (i, a) in r.room.obstacles.iter().enumerate() {
                assert!(a.0.x >= -1e-4 && a.0.y >= -1e-4 && a.1.x <= w + 1e-4 && a.1.y <= d + 1e-4);
                for b in &r.room.obstacles[i + 1..] {
                    let overlap =
                        a.0.x < b.1.x - 1e-4 && b.0.x < a.1.x - 1e-4 && a.0.y < b.1.y - 1e-4 && b.0.y < a.1.y - 1e-4;
                    assert!(!overlap, "{kind} {seed}: obstacles {a:?} and {b:?} overlap");
                }
            }
            assert!(!r.room.interest_points.is_empty());
        }
    }
    assert!(beyond_open_doors > 0, "no room has an open door");
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
                tall_obstacles: Vec::new(),
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
        let given =
            generate_library_room_detailed(&LibraryRoomConfig { seed, kind: Some(a.kind), split: Split::Train }, &lib)
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
            let (dist, inward) = dists.iter().fold((f32::MAX, Vec2::ZERO), |acc, x| if x.0 < acc.0 { *x } else { acc });
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

#[test]
fn home_labels_follow_each_models_fine_category() {
    use crate::class::UNLABELED;
    use crate::home_class::HomeClass;
    let lib = BoxLibrary::new();
    let mut seen = BTreeSet::new();
    for (i, kind) in HomeRoomKind::ALL.into_iter().enumerate() {
        let r = room(&lib, 40 + i as u64, kind, Split::Train);
        let m = &r.room.mesh;
        assert_eq!(r.home_labels.len(), m.positions.len(), "{kind}");
        for (v, (&home, &s3dis)) in r.home_labels.iter().zip(&m.vertex_labels).enumerate() {
            let s3dis = SemanticClass::from_id(s3dis).unwrap_or(SemanticClass::Clutter);
            match s3dis {
                // The shell keeps its class.
                SemanticClass::Ceiling | SemanticClass::Floor | SemanticClass::Wall => {
                    assert_eq!(HomeClass::from_id(home), HomeClass::from_s3dis(s3dis), "{kind} vertex {v}")
                }
                SemanticClass::Beam | SemanticClass::Column => assert_eq!(home, HomeClass::Wall.id()),
                _ => {}
            }
            assert!(home == UNLABELED || (home as usize) < HomeClass::COUNT);
            seen.insert(home);
        }
    }
    // Beds, cabinets (wardrobes), tables, chairs, sofas and counters from the box catalogue.
    for c in [HomeClass::Bed, HomeClass::Cabinet, HomeClass::Table, HomeClass::Chair, HomeClass::Sofa] {
        assert!(seen.contains(&c.id()), "{c} never labelled: {seen:?}");
    }
    assert!(seen.contains(&UNLABELED), "nightstands and lamps are unscored");
}
