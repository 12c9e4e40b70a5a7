//! Which catalogue models count as what: a bed, a sofa, a chair, a kitchen cabinet, a
//! washbasin, a ceiling lamp..., from the `fine` column of
//! `crates/data/furniture_classes.tsv` and the model's size and elevation. The recipes pick
//! models through these predicates; their size limits keep out models that would not fit
//! the role (a doll's bed, a table too high to sit at), so they decide what a room may hold.

use super::HomeRoomKind;
use crate::library::LibraryModel;

pub(super) fn is(m: &LibraryModel, fines: &[&str]) -> bool {
    fines.contains(&m.fine.as_str())
}

fn name_has(m: &LibraryModel, words: &[&str]) -> bool {
    let n = m.name.to_ascii_lowercase();
    words.iter().any(|w| n.contains(w))
}

pub(super) fn on_floor(m: &LibraryModel) -> bool {
    m.elevation < 0.05 && !m.door_or_window
}

pub(super) fn is_bed(m: &LibraryModel) -> bool {
    is(m, &["bed"]) && on_floor(m) && m.size.x >= 0.8 && m.size.y >= 1.7 && m.size.y <= 2.45 && m.size.z > 0.25
}

pub(super) fn is_sofa(m: &LibraryModel) -> bool {
    is(m, &["sofa", "sofa_bed"]) && on_floor(m) && m.size.x >= 1.2 && m.size.y <= 1.2
}

pub(super) fn is_armchair(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.x <= 1.1
        && m.size.y <= 1.1
        && m.size.z >= 0.5
        && (is(m, &["armchair"]) || (is(m, &["sofa"]) && m.size.x < 1.1))
}

pub(super) fn is_chair(m: &LibraryModel) -> bool {
    is(m, &["chair"]) && on_floor(m) && m.size.x <= 0.75 && m.size.y <= 0.8 && m.size.z >= 0.6 && m.size.z <= 1.4
}

pub(super) fn is_office_chair(m: &LibraryModel) -> bool {
    is_chair(m) && name_has(m, &["office", "swivel", "desk", "computer"])
}

pub(super) fn is_table(m: &LibraryModel) -> bool {
    is(m, &["table", "work_table"])
        && on_floor(m)
        && m.size.z >= 0.6
        && m.size.z <= 0.95
        && m.size.x >= 0.6
        && m.size.y >= 0.5
}

pub(super) fn is_coffee_table(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z <= 0.6
        && m.size.z >= 0.25
        && (is(m, &["coffee_table"]) || (is(m, &["table"]) && m.size.z <= 0.55))
}

pub(super) fn is_desk(m: &LibraryModel) -> bool {
    is(m, &["desk", "dressing_table"]) && on_floor(m) && m.size.x >= 0.8 && m.size.y <= 1.0
}

pub(super) fn is_nightstand(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.x <= 0.65
        && m.size.y <= 0.65
        && m.size.z <= 0.8
        && m.size.z >= 0.35
        && (is(m, &["nightstand"]) || (is(m, &["cabinet"]) && m.size.z <= 0.7))
}

pub(super) fn is_wardrobe(m: &LibraryModel) -> bool {
    is(m, &["wardrobe"]) && on_floor(m) && m.size.z >= 1.4 && m.size.y <= 0.8
}

pub(super) fn is_dresser(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z <= 1.2
        && m.size.y <= 0.7
        && (is(m, &["dresser"]) || (is(m, &["cabinet"]) && m.size.x >= 0.4))
}

pub(super) fn is_bookcase(m: &LibraryModel) -> bool {
    is(m, &["bookcase", "shelf"]) && on_floor(m) && m.size.y <= 0.6 && m.size.z >= 0.6
}

pub(super) fn is_floor_cabinet(m: &LibraryModel) -> bool {
    is(m, &["cabinet"]) && on_floor(m) && m.size.y <= 0.75 && m.size.z >= 0.5 && m.size.z <= 2.3
}

fn is_kitchen(m: &LibraryModel) -> bool {
    m.category.eq_ignore_ascii_case("kitchen")
}

/// Lower kitchen modules: cabinets, sinks, stoves, dishwashers and washing machines that
/// stand on the floor at counter height.
pub(super) fn is_kitchen_lower(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z >= 0.75
        && m.size.z <= 1.25
        && m.size.y >= 0.45
        && m.size.y <= 0.8
        && m.size.x <= 1.3
        && (is(m, &["cabinet", "kitchen_cabinet", "oven", "washing_machine"]) || (is(m, &["sink"]) && is_kitchen(m)))
}

pub(super) fn is_kitchen_upper(m: &LibraryModel) -> bool {
    is(m, &["cabinet", "kitchen_cabinet"]) && m.elevation >= 1.2 && m.size.y <= 0.6 && m.size.z <= 1.0
}

pub(super) fn is_fridge(m: &LibraryModel) -> bool {
    is(m, &["fridge"]) && on_floor(m) && m.size.z >= 1.2 && m.size.y <= 1.0
}

pub(super) fn is_tv(m: &LibraryModel) -> bool {
    is(m, &["tv"]) && m.size.x >= 0.5 && m.size.z >= 0.35
}

pub(super) fn is_tv_stand(m: &LibraryModel) -> bool {
    on_floor(m)
        && m.size.z >= 0.3
        && m.size.z <= 0.8
        && m.size.y <= 0.7
        && m.size.x >= 0.6
        && is(m, &["cabinet", "dresser", "shelf"])
}

pub(super) fn is_toilet(m: &LibraryModel) -> bool {
    is(m, &["toilet"]) && on_floor(m) && m.size.y >= 0.45 && m.size.z >= 0.45
}

pub(super) fn is_washbasin(m: &LibraryModel) -> bool {
    is(m, &["sink"]) && !is_kitchen(m) && m.size.x <= 2.0 && m.size.y <= 0.85 && m.elevation + m.size.z >= 0.7
}

pub(super) fn is_bathtub(m: &LibraryModel) -> bool {
    is(m, &["bathtub"]) && on_floor(m) && m.size.z >= 0.3
}

pub(super) fn is_shower(m: &LibraryModel) -> bool {
    is(m, &["shower"]) && on_floor(m) && m.size.z >= 1.8 && m.size.y >= 0.7
}

pub(super) fn is_towel_rack(m: &LibraryModel) -> bool {
    is(m, &["towel"]) && m.size.y <= 0.25 && m.size.x >= 0.12 && m.size.z >= 0.1
}

pub(super) fn is_radiator(m: &LibraryModel) -> bool {
    is(m, &["radiator"]) && m.size.y <= 0.3 && m.size.z <= 1.2 && m.elevation <= 0.5 && m.size.x >= 0.4
}

pub(super) fn is_rug(m: &LibraryModel) -> bool {
    (is(m, &["rug"]) || name_has(m, &["mat"]))
        && m.size.z <= 0.06
        && m.size.x >= 0.5
        && m.size.y >= 0.4
        && !m.door_or_window
}

pub(super) fn is_curtain(m: &LibraryModel) -> bool {
    is(m, &["curtain"]) && m.size.z >= 1.0
}

pub(super) fn is_floor_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && on_floor(m) && m.size.z >= 1.1 && m.size.x <= 0.7 && m.size.y <= 0.7
}

pub(super) fn is_ceiling_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && m.elevation + m.size.z >= 2.0 && m.size.x <= 1.4 && m.size.z <= 1.0
}

pub(super) fn is_wall_lamp(m: &LibraryModel) -> bool {
    is(m, &["lamp"]) && m.elevation >= 1.0 && m.elevation + m.size.z < 2.0 && m.size.y <= 0.4
}

pub(super) fn is_floor_plant(m: &LibraryModel) -> bool {
    is(m, &["plant"]) && on_floor(m) && m.size.z >= 0.5 && m.size.z <= 2.2 && m.size.x <= 1.0 && m.size.y <= 1.0
}

pub(super) fn is_whiteboard(m: &LibraryModel) -> bool {
    is(m, &["whiteboard"]) && on_floor(m) && m.size.z <= 2.2
}

pub(super) fn is_bench(m: &LibraryModel) -> bool {
    is(m, &["bench"]) && on_floor(m) && m.size.z <= 1.0 && m.size.y <= 0.6
}

pub(super) fn is_wall_socket(m: &LibraryModel) -> bool {
    is(m, &["wall_socket"]) && m.size.y <= 0.1 && m.size.x <= 0.3 && m.size.z <= 0.3
}

/// Things that stand on the floor by a wall as clutter, by room kind: boxes, bags, fans,
/// and in homes instruments, toys, sports gear, a fireplace.
pub(super) fn is_floor_clutter(m: &LibraryModel, kind: HomeRoomKind) -> bool {
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
pub(super) fn is_small(m: &LibraryModel, kind: HomeRoomKind) -> bool {
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
