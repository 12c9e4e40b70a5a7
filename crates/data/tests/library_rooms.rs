//! Rooms furnished from the installed furniture catalogues (`library::rooms`), for every
//! kind and several seeds: valid meshes with labels in range, the shell's classes present,
//! everything inside the room, disjoint obstacles, a walkable floor for scan paths, the same
//! bits twice, training rooms built only from training models and held-out rooms only from
//! held-out ones, and generation time. Skips with a message when Debian's
//! `sweethome3d-furniture` package is not installed.

use std::path::Path;
use std::time::Instant;

use semrecon_data::library::rooms::{generate_library_room_detailed, HomeRoomKind, LibraryRoom, LibraryRoomConfig};
use semrecon_data::library::{FurnitureLibrary, Split, DEFAULT_FURNITURE_DIR, FURNITURE_DIR_ENV};
use semrecon_data::scan_path::{RoomLayout, ScanPlan};
use semrecon_data::SemanticClass;

fn library() -> Option<FurnitureLibrary> {
    let dir = std::env::var_os(FURNITURE_DIR_ENV).map(std::path::PathBuf::from);
    let dir = dir.unwrap_or_else(|| Path::new(DEFAULT_FURNITURE_DIR).to_path_buf());
    if !dir.is_dir() {
        eprintln!(
            "skipping: no furniture catalogues at {} (install Debian's sweethome3d-furniture or set {FURNITURE_DIR_ENV})",
            dir.display()
        );
        return None;
    }
    Some(FurnitureLibrary::open(&dir).expect("the installed catalogues open"))
}

fn room(lib: &FurnitureLibrary, seed: u64, kind: HomeRoomKind, split: Split) -> LibraryRoom {
    generate_library_room_detailed(&LibraryRoomConfig { seed, kind: Some(kind), split }, lib)
        .unwrap_or_else(|e| panic!("{kind} seed {seed}: {e}"))
}

fn check_room(r: &LibraryRoom, what: &str) {
    let m = &r.room.mesh;
    m.validate().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert_eq!(m.normals.len(), m.positions.len(), "{what}");
    assert_eq!(m.vertex_labels.len(), m.positions.len(), "{what}");
    assert!(m.triangle_labels.iter().chain(&m.vertex_labels).all(|&l| (l as usize) < SemanticClass::COUNT), "{what}");
    for class in [SemanticClass::Floor, SemanticClass::Ceiling, SemanticClass::Wall, SemanticClass::Door] {
        assert!(m.triangle_labels.contains(&class.id()), "{what}: no {}", class.name());
    }
    assert!(m.triangle_count() <= 1_600_000, "{what}: {} triangles", m.triangle_count());
    let (w, d, h) = (r.room.floor_max.x, r.room.floor_max.y, r.room.ceiling_height);
    // Doors, windows and the reveals of openings may lie in the wall's thickness; an open door
    // shows the floor, walls and ceiling of the space behind it (up to 2.7 m).
    let in_wall = [SemanticClass::Door, SemanticClass::Window];
    let beyond = [SemanticClass::Wall, SemanticClass::Floor, SemanticClass::Ceiling];
    for (p, &l) in m.positions.iter().zip(&m.vertex_labels) {
        let slack = if beyond.iter().any(|c| c.id() == l) {
            2.75
        } else if in_wall.iter().any(|c| c.id() == l) {
            0.4
        } else {
            2e-3
        };
        let outside = (-p.x).max(-p.y).max(p.x - w).max(p.y - d);
        assert!(
            outside <= slack && p.z >= -2e-3 && p.z <= h + 2e-3,
            "{what}: vertex {p} (class {l}) outside {w} x {d} x {h}"
        );
    }
    for (i, a) in r.room.obstacles.iter().enumerate() {
        assert!(a.0.x >= -1e-4 && a.0.y >= -1e-4 && a.1.x <= w + 1e-4 && a.1.y <= d + 1e-4, "{what}: {a:?}");
        for b in &r.room.obstacles[i + 1..] {
            let overlap = a.0.x < b.1.x - 1e-4 && b.0.x < a.1.x - 1e-4 && a.0.y < b.1.y - 1e-4 && b.0.y < a.1.y - 1e-4;
            assert!(!overlap, "{what}: obstacles {a:?} and {b:?} overlap");
        }
    }
    let layout = RoomLayout {
        floor_min: r.room.floor_min,
        floor_max: r.room.floor_max,
        floor_z: 0.0,
        ceiling_height: h,
        obstacles: r.room.obstacles.clone(),
        interest_points: r.room.interest_points.clone(),
        tall_obstacles: Vec::new(),
    };
    ScanPlan::new(layout, 7).poses(90).unwrap_or_else(|e| panic!("{what}: no scan path: {e}"));
}

#[test]
fn every_kind_furnishes_valid_walkable_rooms_from_the_catalogues() {
    let Some(lib) = library() else { return };
    for kind in HomeRoomKind::ALL {
        for seed in 0..4 {
            let r = room(&lib, seed, kind, Split::Train);
            check_room(&r, &format!("{kind} seed {seed}"));
            assert!(r.model_ids.len() >= 3, "{kind} seed {seed}: only {:?}", r.model_ids);
        }
    }
}

#[test]
fn splits_keep_to_their_models_and_rooms_repeat_bit_for_bit() {
    let Some(lib) = library() else { return };
    let split_of = |id: &str| lib.models.iter().find(|m| m.id == id).map(|m| m.split);
    for kind in HomeRoomKind::ALL {
        for seed in [11u64, 12] {
            for split in [Split::Train, Split::HeldOut] {
                let a = room(&lib, seed, kind, split);
                let b = room(&lib, seed, kind, split);
                assert!(a == b, "{kind} seed {seed} {split:?}: two generations differ");
                for id in &a.model_ids {
                    assert_eq!(split_of(id), Some(split), "{kind} seed {seed}: {id} in a {split:?} room");
                }
                if split == Split::HeldOut {
                    check_room(&a, &format!("held-out {kind} seed {seed}"));
                }
            }
        }
    }
}

#[test]
fn rooms_generate_well_under_a_second_with_cached_meshes() {
    let Some(lib) = library() else { return };
    let configs: Vec<LibraryRoomConfig> = (100..116).map(LibraryRoomConfig::new).collect();
    for c in &configs {
        generate_library_room_detailed(c, &lib).expect("room");
    }
    let t = Instant::now();
    let mut triangles = 0;
    for c in &configs {
        triangles += generate_library_room_detailed(c, &lib).expect("room").room.mesh.triangle_count();
    }
    let per_room = t.elapsed().as_secs_f64() / configs.len() as f64;
    eprintln!("{:.0} ms a room with cached meshes, {} triangles on average", per_room * 1e3, triangles / configs.len());
    // Release builds take about a tenth of this; the bound leaves room for debug builds.
    assert!(per_room < 3.0, "{per_room} s a room");
}
