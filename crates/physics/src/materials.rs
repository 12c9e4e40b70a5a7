//! Contact materials (restitution, friction) per semantic class, the paper's "soft on a
//! sofa, hard on a desk". They live in a TOML file that users can edit; the defaults ship
//! as `crates/physics/materials.toml` (compiled in) and a user file only needs the keys it
//! changes. Every value is checked (restitution in 0..=1, friction finite and >= 0) and
//! errors name the file and the dotted key, because a typo in a class name would otherwise
//! silently fall back to a default.

use std::path::{Path, PathBuf};

use semrecon_data::class::UNLABELED;
use semrecon_data::{HomeClass, LabelSet, SemanticClass};

use crate::error::{PhysicsError, Result};

/// The shipped defaults, `crates/physics/materials.toml`.
pub const DEFAULT_MATERIALS_TOML: &str = include_str!("../materials.toml");

/// Name under which contacts with unlabelled triangles are reported, and the TOML table
/// of their material.
pub const UNLABELLED_NAME: &str = "unlabelled";

/// Surface material of one class as seen by a bouncing ball.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    /// Ratio of rebound to impact normal speed, 0..=1.
    pub restitution: f32,
    /// Coulomb friction coefficient, >= 0.
    pub friction: f32,
}

/// Materials of the 13 S3DIS classes, of the 21 home classes ([`HomeClass`]), and one for
/// unlabelled surfaces; [`MaterialTable::label`] reads the set chosen with
/// [`MaterialTable::with_label_set`] (S3DIS by default).
#[derive(Debug, Clone, PartialEq)]
pub struct MaterialTable {
    classes: [Material; SemanticClass::COUNT],
    home: [Material; HomeClass::COUNT],
    unlabelled: Material,
    label_set: LabelSet,
}

/// A home class's key in the TOML file: its name with `_` for a space (`shower_curtain`).
fn home_key(c: HomeClass) -> String {
    c.name().replace(' ', "_")
}

impl Default for MaterialTable {
    fn default() -> Self {
        Self::defaults()
    }
}

impl MaterialTable {
    /// The shipped defaults ([`DEFAULT_MATERIALS_TOML`]).
    pub fn defaults() -> Self {
        // The neutral fallback is never used in a released build: a unit test guarantees
        // that the shipped file parses.
        base_fallback()
            .overridden_by(DEFAULT_MATERIALS_TOML, Path::new("<built-in materials.toml>"))
            .unwrap_or_else(|_| base_fallback())
    }

    /// Reads a materials file: the defaults with the file's values applied on top.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .map_err(|e| PhysicsError::MaterialsFile { path: path.to_path_buf(), message: e.to_string() })?;
        Self::defaults().overridden_by(&text, path)
    }

    /// Parses TOML `text` (named `path` in errors) and applies its values on top of `self`.
    ///
    /// Layout: `[unlabelled]` and `[classes.<name>]` tables with `restitution` and
    /// `friction` numbers; any other table or key is an error.
    pub fn overridden_by(&self, text: &str, path: &Path) -> Result<Self> {
        let file_err = |message: String| PhysicsError::MaterialsFile { path: path.to_path_buf(), message };
        let key_err = |key: &str, message: String| PhysicsError::MaterialsKey {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let root: toml::Table = text.parse().map_err(|e: toml::de::Error| file_err(e.to_string()))?;
        let mut out = self.clone();
        for (name, value) in &root {
            match name.as_str() {
                UNLABELLED_NAME => {
                    out.unlabelled = parse_material(value, out.unlabelled, UNLABELLED_NAME, path)?;
                }
                "classes" => {
                    let table = value.as_table().ok_or_else(|| key_err("classes", "must be a table".into()))?;
                    for (class_name, v) in table {
                        let key = format!("classes.{class_name}");
                        // Exact lower-case names only: `from_name` also maps S3DIS's
                        // `stairs` to clutter, which would be surprising in a materials file.
                        let class =
                            SemanticClass::ALL.into_iter().find(|c| c.name() == class_name).ok_or_else(|| {
                                let names: Vec<_> = SemanticClass::ALL.iter().map(|c| c.name()).collect();
                                key_err(&key, format!("unknown class (known: {})", names.join(", ")))
                            })?;
                        out.classes[class.id() as usize] =
                            parse_material(v, out.classes[class.id() as usize], &key, path)?;
                    }
                }
                "home" => {
                    let table = value.as_table().ok_or_else(|| key_err("home", "must be a table".into()))?;
                    for (class_name, v) in table {
                        let key = format!("home.{class_name}");
                        let class =
                            HomeClass::ALL.into_iter().find(|c| home_key(*c) == *class_name).ok_or_else(|| {
                                let names: Vec<_> = HomeClass::ALL.iter().map(|c| home_key(*c)).collect();
                                key_err(&key, format!("unknown home class (known: {})", names.join(", ")))
                            })?;
                        out.home[class.id() as usize] = parse_material(v, out.home[class.id() as usize], &key, path)?;
                    }
                }
                other => {
                    return Err(key_err(other, "unknown table (expected `unlabelled`, `classes` or `home`)".into()));
                }
            }
        }
        Ok(out)
    }

    /// Material of a class.
    pub fn class(&self, class: SemanticClass) -> Material {
        self.classes[class.id() as usize]
    }

    /// Material for unlabelled surfaces.
    pub fn unlabelled(&self) -> Material {
        self.unlabelled
    }

    /// Material of a home class.
    pub fn home_class(&self, class: HomeClass) -> Material {
        self.home[class.id() as usize]
    }

    /// The same materials, reading labels as `set` ([`MaterialTable::label`]).
    pub fn with_label_set(mut self, set: LabelSet) -> Self {
        self.label_set = set;
        self
    }

    /// The label set [`MaterialTable::label`] reads.
    pub fn label_set(&self) -> LabelSet {
        self.label_set
    }

    /// Material of a label id of the table's label set (0..13 for S3DIS, 0..21 for home;
    /// anything else, such as [`UNLABELED`], is unlabelled).
    pub fn label(&self, label: u8) -> Material {
        let table: &[Material] = match self.label_set {
            LabelSet::S3dis => &self.classes,
            LabelSet::Home => &self.home,
        };
        table.get(label as usize).copied().unwrap_or(self.unlabelled)
    }

    /// Name of a label id of the table's label set in contact reports: the class name or
    /// [`UNLABELLED_NAME`].
    pub fn label_name(&self, label: u8) -> &'static str {
        if label == UNLABELED {
            return UNLABELLED_NAME;
        }
        self.label_set.class_name(label).unwrap_or(UNLABELLED_NAME)
    }

    /// Sets the material of a class (values are not checked; use the TOML path for user input).
    pub fn set_class(&mut self, class: SemanticClass, material: Material) {
        self.classes[class.id() as usize] = material;
    }

    /// The table as TOML in the layout [`MaterialTable::load`] reads.
    pub fn to_toml(&self) -> String {
        let mut s = String::new();
        let mut push = |name: &str, m: Material| {
            s.push_str(&format!("[{name}]\nrestitution = {}\nfriction = {}\n\n", m.restitution, m.friction));
        };
        push(UNLABELLED_NAME, self.unlabelled);
        for c in SemanticClass::ALL {
            push(&format!("classes.{}", c.name()), self.class(c));
        }
        for c in HomeClass::ALL {
            push(&format!("home.{}", home_key(c)), self.home_class(c));
        }
        s
    }
}

fn base_fallback() -> MaterialTable {
    let neutral = Material { restitution: 0.5, friction: 0.5 };
    MaterialTable {
        classes: [neutral; SemanticClass::COUNT],
        home: [neutral; HomeClass::COUNT],
        unlabelled: neutral,
        label_set: LabelSet::S3dis,
    }
}

fn parse_material(value: &toml::Value, mut material: Material, key: &str, path: &Path) -> Result<Material> {
    let key_err = |key: String, message: String| PhysicsError::MaterialsKey { path: PathBuf::from(path), key, message };
    let table = value.as_table().ok_or_else(|| key_err(key.to_string(), "must be a table".into()))?;
    for (field, v) in table {
        let full = format!("{key}.{field}");
        let x = match v {
            toml::Value::Float(f) => *f,
            toml::Value::Integer(i) => *i as f64,
            _ => return Err(key_err(full, format!("must be a number, found {}", v.type_str()))),
        };
        match field.as_str() {
            "restitution" => {
                if !(0.0..=1.0).contains(&x) {
                    return Err(key_err(full, format!("{x} is outside 0..=1")));
                }
                material.restitution = x as f32;
            }
            "friction" => {
                if !x.is_finite() || x < 0.0 {
                    return Err(key_err(full, format!("{x} must be finite and >= 0")));
                }
                material.friction = x as f32;
            }
            _ => return Err(key_err(full, "unknown key (expected `restitution` or `friction`)".into())),
        }
    }
    Ok(material)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<MaterialTable> {
        MaterialTable::defaults().overridden_by(text, Path::new("user.toml"))
    }

    #[test]
    fn shipped_defaults_parse_and_cover_every_class() {
        let neutral = base_fallback();
        let parsed =
            neutral.overridden_by(DEFAULT_MATERIALS_TOML, Path::new("materials.toml")).expect("defaults parse");
        // Every class must be listed in the file: none may keep the neutral fallback.
        let root: toml::Table = DEFAULT_MATERIALS_TOML.parse().expect("toml");
        let classes = root["classes"].as_table().expect("classes table");
        for c in SemanticClass::ALL {
            assert!(classes.contains_key(c.name()), "{} missing from materials.toml", c.name());
        }
        let home = root["home"].as_table().expect("home table");
        for c in HomeClass::ALL {
            assert!(home.contains_key(&home_key(c)), "home.{} missing from materials.toml", home_key(c));
        }
        let home_table = parsed.clone().with_label_set(LabelSet::Home);
        assert!(home_table.label(HomeClass::Bed.id()).restitution < 0.3);
        assert!(home_table.label(HomeClass::Toilet.id()).restitution >= 0.8);
        assert_eq!(home_table.label(HomeClass::Ceiling.id()), parsed.class(SemanticClass::Ceiling));
        assert_eq!(home_table.label(21), parsed.unlabelled());
        assert_eq!(parsed, MaterialTable::defaults());
        let sofa = parsed.class(SemanticClass::Sofa);
        let floor = parsed.class(SemanticClass::Floor);
        assert!(sofa.restitution < 0.3 && floor.restitution >= 0.8);
        assert!(parsed.class(SemanticClass::Table).restitution >= 0.8);
        assert_eq!(parsed.label(UNLABELED), parsed.unlabelled());
    }

    #[test]
    fn user_file_overrides_only_what_it_names() {
        let t = parse("[classes.sofa]\nrestitution = 0.1\n").expect("valid");
        let d = MaterialTable::defaults();
        assert_eq!(t.class(SemanticClass::Sofa).restitution, 0.1);
        assert_eq!(t.class(SemanticClass::Sofa).friction, d.class(SemanticClass::Sofa).friction);
        assert_eq!(t.class(SemanticClass::Floor), d.class(SemanticClass::Floor));
        let round = base_fallback().overridden_by(&d.to_toml(), Path::new("x")).expect("round trip");
        assert_eq!(round, d);
        let int = parse("[unlabelled]\nrestitution = 1\nfriction = 0\n").expect("integers are numbers");
        assert_eq!(int.unlabelled(), Material { restitution: 1.0, friction: 0.0 });
    }

    #[test]
    fn bad_files_name_the_file_and_key() {
        let cases = [
            ("[classes.sofaa]\nrestitution = 0.1\n", "classes.sofaa", "unknown class"),
            ("[classes.sofa]\nrestitution = 1.5\n", "classes.sofa.restitution", "outside 0..=1"),
            ("[classes.sofa]\nrestitution = -0.1\n", "classes.sofa.restitution", "outside 0..=1"),
            ("[classes.sofa]\nrestitution = nan\n", "classes.sofa.restitution", "outside 0..=1"),
            ("[classes.floor]\nfriction = -1\n", "classes.floor.friction", ">= 0"),
            ("[classes.floor]\nfriction = inf\n", "classes.floor.friction", "finite"),
            ("[classes.floor]\nfriction = \"high\"\n", "classes.floor.friction", "must be a number"),
            ("[classes.floor]\nbounciness = 0.2\n", "classes.floor.bounciness", "unknown key"),
            ("[material.floor]\nfriction = 0.2\n", "material", "unknown table"),
            ("classes = 3\n", "classes", "must be a table"),
        ];
        for (text, key, msg) in cases {
            let e = parse(text).expect_err(text).to_string();
            assert!(e.starts_with("user.toml: "), "{e}");
            assert!(e.contains(key) && e.contains(msg), "{text:?} -> {e}");
        }
        let e = parse("[classes.sofa\nrestitution = 0.1").expect_err("syntax").to_string();
        assert!(e.starts_with("user.toml: ") && e.contains("line"), "{e}");
        let dir = tempfile::tempdir().expect("tempdir");
        let missing = dir.path().join("none.toml");
        let e = MaterialTable::load(&missing).expect_err("missing").to_string();
        assert!(e.contains("none.toml"), "{e}");
    }

    #[test]
    fn label_names() {
        let t = MaterialTable::defaults();
        assert_eq!(t.label_name(10), "sofa");
        assert_eq!(t.label_name(UNLABELED), UNLABELLED_NAME);
        assert_eq!(t.label_name(77), UNLABELLED_NAME);
        let home = t.with_label_set(LabelSet::Home);
        assert_eq!(home.label_name(3), "bed");
        assert_eq!(home.label_name(15), "shower curtain");
        assert!(parse("[home.shower_curtain]\nfriction = 2\n").is_ok());
        let e = parse("[home.shower]\nfriction = 2\n").expect_err("unknown").to_string();
        assert!(e.contains("home.shower") && e.contains("unknown home class"), "{e}");
    }
}
