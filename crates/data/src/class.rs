//! The 13 semantic classes of S3DIS, in the order every model, file and label image of
//! semrecon uses (label id = index), with a fixed display colour per class.

use serde::{Deserialize, Serialize};

/// Label value meaning "no class" in label images and per-vertex labels (no surface hit,
/// unlabeled input).
pub const UNLABELED: u8 = 255;

/// One of the 13 S3DIS classes. `class as u8` is the label id written to files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
#[serde(rename_all = "lowercase")]
#[allow(missing_docs)]
pub enum SemanticClass {
    Ceiling = 0,
    Floor = 1,
    Wall = 2,
    Beam = 3,
    Column = 4,
    Window = 5,
    Door = 6,
    Chair = 7,
    Table = 8,
    Bookcase = 9,
    Sofa = 10,
    Board = 11,
    Clutter = 12,
}

impl SemanticClass {
    /// Number of classes.
    pub const COUNT: usize = 13;

    /// All classes in label-id order.
    pub const ALL: [SemanticClass; 13] = [
        Self::Ceiling,
        Self::Floor,
        Self::Wall,
        Self::Beam,
        Self::Column,
        Self::Window,
        Self::Door,
        Self::Chair,
        Self::Table,
        Self::Bookcase,
        Self::Sofa,
        Self::Board,
        Self::Clutter,
    ];

    /// The class with label id `id`, if any.
    pub fn from_id(id: u8) -> Option<Self> {
        Self::ALL.get(id as usize).copied()
    }

    /// Label id (0..13).
    pub fn id(self) -> u8 {
        self as u8
    }

    /// Lower-case name as used by S3DIS annotation files (`chair_1.txt` -> `chair`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Ceiling => "ceiling",
            Self::Floor => "floor",
            Self::Wall => "wall",
            Self::Beam => "beam",
            Self::Column => "column",
            Self::Window => "window",
            Self::Door => "door",
            Self::Chair => "chair",
            Self::Table => "table",
            Self::Bookcase => "bookcase",
            Self::Sofa => "sofa",
            Self::Board => "board",
            Self::Clutter => "clutter",
        }
    }

    /// Parses a class name (case-insensitive). S3DIS's `stairs` is not one of the 13 and
    /// maps to `clutter`, as is usual for Area 5 evaluations.
    pub fn from_name(name: &str) -> Option<Self> {
        let lower = name.trim().to_ascii_lowercase();
        if lower == "stairs" {
            return Some(Self::Clutter);
        }
        Self::ALL.into_iter().find(|c| c.name() == lower)
    }

    /// Display colour (sRGB) of the class in semantic renders and `semantic.ply`. Chosen to
    /// be distinct and to keep the room readable: pale ceiling, brown floor, grey walls.
    pub fn color(self) -> [u8; 3] {
        match self {
            Self::Ceiling => [210, 210, 190],
            Self::Floor => [140, 100, 60],
            Self::Wall => [170, 175, 185],
            Self::Beam => [230, 200, 40],
            Self::Column => [255, 130, 20],
            Self::Window => [80, 200, 240],
            Self::Door => [160, 60, 200],
            Self::Chair => [230, 40, 40],
            Self::Table => [40, 160, 60],
            Self::Bookcase => [0, 130, 130],
            Self::Sofa => [240, 100, 170],
            Self::Board => [30, 60, 200],
            Self::Clutter => [90, 90, 90],
        }
    }
}

impl std::fmt::Display for SemanticClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_names_and_colors_round_trip() {
        for (i, c) in SemanticClass::ALL.iter().enumerate() {
            assert_eq!(c.id() as usize, i);
            assert_eq!(SemanticClass::from_id(i as u8), Some(*c));
            assert_eq!(SemanticClass::from_name(c.name()), Some(*c));
        }
        assert_eq!(SemanticClass::from_id(13), None);
        assert_eq!(SemanticClass::from_name("Stairs"), Some(SemanticClass::Clutter));
        let mut colors: Vec<_> = SemanticClass::ALL.iter().map(|c| c.color()).collect();
        colors.sort();
        colors.dedup();
        assert_eq!(colors.len(), 13, "class colours must be distinct");
    }
}
