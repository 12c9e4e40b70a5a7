//! The second label set: ScanNet's 20 benchmark classes (bed, cabinet, counter, desk,
//! curtain, refrigerator, toilet, sink, bathtub, picture, ...) plus the ceiling, for homes,
//! where S3DIS's 13 classes call most of what is in a room `clutter`.
//!
//! Ids 0..20 follow the ScanNet benchmark's order (its NYU40 ids 1, 2, 3, 4, 5, 6, 7, 8, 9,
//! 10, 11, 12, 14, 16, 24, 28, 33, 34, 36, 39); id 20 is the ceiling, which ScanNet leaves
//! unscored but a map needs (the AR physics takes each surface's material from its class).
//! Everything ScanNet ignores (lamps, boxes, TVs, shelves, nightstands, dressers, beams,
//! whiteboards...) is [`UNLABELED`] in ground truth, and [`home_class_of_fine`] says so
//! explicitly for every fine category of the furniture table, so that a new category cannot
//! slip into training unmapped.

use crate::class::{SemanticClass, UNLABELED};

/// One class of the home label set. `class as u8` is the label id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
#[allow(missing_docs)]
pub enum HomeClass {
    Wall = 0,
    Floor = 1,
    Cabinet = 2,
    Bed = 3,
    Chair = 4,
    Sofa = 5,
    Table = 6,
    Door = 7,
    Window = 8,
    Bookshelf = 9,
    Picture = 10,
    Counter = 11,
    Desk = 12,
    Curtain = 13,
    Refrigerator = 14,
    ShowerCurtain = 15,
    Toilet = 16,
    Sink = 17,
    Bathtub = 18,
    OtherFurniture = 19,
    Ceiling = 20,
}

impl HomeClass {
    /// Number of classes (ScanNet's 20 and the ceiling).
    pub const COUNT: usize = 21;

    /// Every class in label-id order.
    pub const ALL: [HomeClass; 21] = [
        Self::Wall,
        Self::Floor,
        Self::Cabinet,
        Self::Bed,
        Self::Chair,
        Self::Sofa,
        Self::Table,
        Self::Door,
        Self::Window,
        Self::Bookshelf,
        Self::Picture,
        Self::Counter,
        Self::Desk,
        Self::Curtain,
        Self::Refrigerator,
        Self::ShowerCurtain,
        Self::Toilet,
        Self::Sink,
        Self::Bathtub,
        Self::OtherFurniture,
        Self::Ceiling,
    ];

    /// The classes that stand in a room or hang on its walls, as opposed to its shell (wall,
    /// floor, ceiling, door, window): the ones the home head chooses among.
    pub const OBJECTS: [HomeClass; 16] = [
        Self::Cabinet,
        Self::Bed,
        Self::Chair,
        Self::Sofa,
        Self::Table,
        Self::Bookshelf,
        Self::Picture,
        Self::Counter,
        Self::Desk,
        Self::Curtain,
        Self::Refrigerator,
        Self::ShowerCurtain,
        Self::Toilet,
        Self::Sink,
        Self::Bathtub,
        Self::OtherFurniture,
    ];

    /// The class with label id `id`, if any.
    pub fn from_id(id: u8) -> Option<Self> {
        Self::ALL.get(id as usize).copied()
    }

    /// Label id (0..21).
    pub fn id(self) -> u8 {
        self as u8
    }

    /// Whether the class is one of [`Self::OBJECTS`].
    pub fn is_object(self) -> bool {
        !matches!(self, Self::Wall | Self::Floor | Self::Door | Self::Window | Self::Ceiling)
    }

    /// Lower-case name, as ScanNet writes it (`shower curtain`, `otherfurniture`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Wall => "wall",
            Self::Floor => "floor",
            Self::Cabinet => "cabinet",
            Self::Bed => "bed",
            Self::Chair => "chair",
            Self::Sofa => "sofa",
            Self::Table => "table",
            Self::Door => "door",
            Self::Window => "window",
            Self::Bookshelf => "bookshelf",
            Self::Picture => "picture",
            Self::Counter => "counter",
            Self::Desk => "desk",
            Self::Curtain => "curtain",
            Self::Refrigerator => "refrigerator",
            Self::ShowerCurtain => "shower curtain",
            Self::Toilet => "toilet",
            Self::Sink => "sink",
            Self::Bathtub => "bathtub",
            Self::OtherFurniture => "otherfurniture",
            Self::Ceiling => "ceiling",
        }
    }

    /// Parses a name (case-insensitive; `_` and `-` taken for a space, `other furniture`
    /// for `otherfurniture`).
    pub fn from_name(name: &str) -> Option<Self> {
        let lower = name.trim().to_ascii_lowercase().replace(['_', '-'], " ");
        let lower = if lower == "other furniture" { "otherfurniture".to_string() } else { lower };
        Self::ALL.into_iter().find(|c| c.name() == lower)
    }

    /// Display colour (sRGB): ScanNet's benchmark palette for its 20 classes, the S3DIS
    /// ceiling's for the ceiling.
    pub fn color(self) -> [u8; 3] {
        match self {
            Self::Wall => [174, 199, 232],
            Self::Floor => [152, 223, 138],
            Self::Cabinet => [31, 119, 180],
            Self::Bed => [255, 187, 120],
            Self::Chair => [188, 189, 34],
            Self::Sofa => [140, 86, 75],
            Self::Table => [255, 152, 150],
            Self::Door => [214, 39, 40],
            Self::Window => [197, 176, 213],
            Self::Bookshelf => [148, 103, 189],
            Self::Picture => [196, 156, 148],
            Self::Counter => [23, 190, 207],
            Self::Desk => [247, 182, 210],
            Self::Curtain => [219, 219, 141],
            Self::Refrigerator => [255, 127, 14],
            Self::ShowerCurtain => [158, 218, 229],
            Self::Toilet => [44, 160, 44],
            Self::Sink => [112, 128, 144],
            Self::Bathtub => [227, 119, 194],
            Self::OtherFurniture => [82, 84, 163],
            Self::Ceiling => [210, 210, 190],
        }
    }

    /// The home class of a surface whose S3DIS class is `class`, where that says it: the
    /// shell (ceiling, floor, wall, door, window) and the S3DIS furniture classes that are
    /// ScanNet classes too (chair, table, bookcase, sofa). Beams and columns are walls to a
    /// home (ScanNet has no class for them and scores them nowhere); board and clutter say
    /// nothing (`None`).
    pub fn from_s3dis(class: SemanticClass) -> Option<Self> {
        Some(match class {
            SemanticClass::Ceiling => Self::Ceiling,
            SemanticClass::Floor => Self::Floor,
            SemanticClass::Wall | SemanticClass::Beam | SemanticClass::Column => Self::Wall,
            SemanticClass::Window => Self::Window,
            SemanticClass::Door => Self::Door,
            SemanticClass::Chair => Self::Chair,
            SemanticClass::Table => Self::Table,
            SemanticClass::Bookcase => Self::Bookshelf,
            SemanticClass::Sofa => Self::Sofa,
            SemanticClass::Board | SemanticClass::Clutter => return None,
        })
    }
}

impl std::fmt::Display for HomeClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Which label set a labelled mesh or point cloud carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LabelSet {
    /// The 13 S3DIS classes ([`SemanticClass`]), the default everywhere.
    #[default]
    S3dis,
    /// ScanNet's 20 classes and the ceiling ([`HomeClass`]).
    Home,
}

impl LabelSet {
    /// Name of label `id` in this set (`None` past the set's classes, [`UNLABELED`] included).
    pub fn class_name(self, id: u8) -> Option<&'static str> {
        match self {
            Self::S3dis => SemanticClass::from_id(id).map(SemanticClass::name),
            Self::Home => HomeClass::from_id(id).map(HomeClass::name),
        }
    }

    /// Number of classes.
    pub fn count(self) -> usize {
        match self {
            Self::S3dis => SemanticClass::COUNT,
            Self::Home => HomeClass::COUNT,
        }
    }

    /// Display colour of label `id` (grey past the set's classes).
    pub fn color(self, id: u8) -> [u8; 3] {
        match self {
            Self::S3dis => SemanticClass::from_id(id).map_or([128, 128, 128], SemanticClass::color),
            Self::Home => HomeClass::from_id(id).map_or([128, 128, 128], HomeClass::color),
        }
    }
}

impl std::str::FromStr for LabelSet {
    type Err = String;

    /// `s3dis`, or `home` (also `scannet20`, `scannet`).
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "s3dis" => Ok(Self::S3dis),
            "home" | "scannet20" | "scannet" => Ok(Self::Home),
            _ => Err(format!("`{s}`: expected s3dis or home")),
        }
    }
}

/// What a fine furniture category (`crates/data/furniture_classes.tsv`'s `fine` column) is in
/// the home label set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FineMapping {
    /// One of the home classes.
    Class(HomeClass),
    /// Not scored by ScanNet (lamps, TVs, boxes, dressers, nightstands, shelves...):
    /// [`UNLABELED`] in ground truth.
    Ignored,
}

impl FineMapping {
    /// The label id: the class's, or [`UNLABELED`].
    pub fn label(self) -> u8 {
        match self {
            Self::Class(c) => c.id(),
            Self::Ignored => UNLABELED,
        }
    }
}

/// The home class of a fine category, following the ScanNet benchmark's mapping of its raw
/// categories (a wardrobe and a kitchen cabinet are cabinets, an armchair and a stool are
/// chairs, a coffee table is a table, a radiator or a washing machine other furniture, a
/// nightstand, a dresser or a lamp not scored). `None` for a category this table does not
/// know: the furniture table's test fails on it, so every category is decided here once.
pub fn home_class_of_fine(fine: &str) -> Option<FineMapping> {
    use FineMapping::{Class, Ignored};
    use HomeClass as H;
    Some(match fine {
        "bed" | "mattress" => Class(H::Bed),
        "sofa" | "sofa_bed" => Class(H::Sofa),
        "chair" | "office_chair" | "armchair" | "lounge_chair" | "stool" | "high_chair" | "beanbag" => Class(H::Chair),
        "table" | "coffee_table" | "game_table" | "work_table" | "bar_table" | "changing_table" | "dressing_table" => {
            Class(H::Table)
        }
        "desk" => Class(H::Desk),
        "cabinet" | "kitchen_cabinet" | "wardrobe" | "locker" | "wall_unit" | "tv_stand" => Class(H::Cabinet),
        "bookcase" => Class(H::Bookshelf),
        "picture" => Class(H::Picture),
        "counter" => Class(H::Counter),
        "curtain" => Class(H::Curtain),
        "fridge" => Class(H::Refrigerator),
        "shower_curtain" => Class(H::ShowerCurtain),
        "toilet" | "bidet" => Class(H::Toilet),
        "sink" | "basin" => Class(H::Sink),
        "bathtub" => Class(H::Bathtub),
        "door" | "garage_door" => Class(H::Door),
        "window" | "shutter" => Class(H::Window),
        "bench" | "radiator" | "heater" | "washing_machine" | "stove" | "oven" | "range_hood" | "water_heater"
        | "clothes_rack" | "room_divider" | "musical_instrument" | "fitness" | "fireplace" | "trash_can"
        | "laundry_basket" | "safe" | "water_cooler" | "kitchen_appliance" | "game_machine" | "aquarium" => {
            Class(H::OtherFurniture)
        }
        "accessory" | "air_conditioner" | "animal" | "bag" | "basket" | "bathroom_accessory" | "blinds" | "book"
        | "bottle" | "box" | "candle" | "chimney" | "cleaning" | "clock" | "clothes" | "computer" | "container"
        | "decoration" | "dresser" | "electronics" | "elevator" | "extinguisher" | "fan" | "firewood" | "food"
        | "kitchenware" | "ladder" | "lamp" | "mailbox" | "microwave" | "money" | "nightstand" | "object"
        | "outdoor" | "pallet" | "person" | "plant" | "potty" | "printer" | "projector" | "railing" | "rug"
        | "shelf" | "shower" | "sign" | "sleeping_bag" | "sport" | "staircase" | "stationery" | "tool" | "towel"
        | "toy" | "tree" | "tv" | "vase" | "vehicle" | "wall_socket" | "wheelchair" | "whiteboard" => Ignored,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::library::class_table;

    #[test]
    fn ids_names_and_colours_round_trip() {
        for (i, c) in HomeClass::ALL.iter().enumerate() {
            assert_eq!(c.id() as usize, i);
            assert_eq!(HomeClass::from_id(i as u8), Some(*c));
            assert_eq!(HomeClass::from_name(c.name()), Some(*c));
        }
        assert_eq!(HomeClass::from_id(21), None);
        assert_eq!(HomeClass::from_name("Shower_Curtain"), Some(HomeClass::ShowerCurtain));
        assert_eq!(HomeClass::from_name("other furniture"), Some(HomeClass::OtherFurniture));
        let mut colours: Vec<_> = HomeClass::ALL.iter().map(|c| c.color()).collect();
        colours.sort();
        colours.dedup();
        assert_eq!(colours.len(), HomeClass::COUNT, "class colours must be distinct");
        assert_eq!(HomeClass::OBJECTS.len(), HomeClass::ALL.iter().filter(|c| c.is_object()).count());
        assert!(HomeClass::OBJECTS.iter().all(|c| c.is_object()));
    }

    #[test]
    fn every_fine_category_of_the_furniture_table_is_mapped() {
        let rows = class_table().expect("the committed table parses");
        let unmapped: std::collections::BTreeSet<&str> =
            rows.iter().map(|r| r.fine.as_str()).filter(|f| home_class_of_fine(f).is_none()).collect();
        assert!(
            unmapped.is_empty(),
            "fine categories with no home class (add them to home_class_of_fine): {unmapped:?}"
        );
    }

    #[test]
    fn the_shell_and_shared_furniture_classes_carry_over_from_s3dis() {
        assert_eq!(HomeClass::from_s3dis(SemanticClass::Beam), Some(HomeClass::Wall));
        assert_eq!(HomeClass::from_s3dis(SemanticClass::Bookcase), Some(HomeClass::Bookshelf));
        assert_eq!(HomeClass::from_s3dis(SemanticClass::Clutter), None);
        assert_eq!(home_class_of_fine("wardrobe"), Some(FineMapping::Class(HomeClass::Cabinet)));
        assert_eq!(home_class_of_fine("nightstand"), Some(FineMapping::Ignored));
        assert_eq!(FineMapping::Ignored.label(), UNLABELED);
    }
}
