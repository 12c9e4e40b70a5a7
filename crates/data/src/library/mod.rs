//! Real modelled furniture from Sweet Home 3D's furniture catalogues (Debian's
//! `sweethome3d-furniture`): every model's metadata, its S3DIS class and fine category from
//! the reviewed table `crates/data/furniture_classes.tsv`, and its mesh scaled to the
//! catalogue size with per-vertex colours from its materials and textures.
//!
//! The model files are never copied: they are read from the installed `.sh3f` archives
//! (zip files) on demand, and each loaded mesh is cached. A catalogue that cannot be read is
//! skipped with a warning (the others still serve); a model the class table does not cover,
//! or marks `use = no` (people, vehicles, outdoor things), is not listed in
//! [`FurnitureLibrary::models`].

pub mod catalogue;
pub mod class_table;
pub mod obj_mesh;
pub mod rooms;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use glam::Vec3;

use crate::error::{DataError, Result};
use crate::mesh::LabeledMesh;

pub use catalogue::{Catalogue, CatalogueEntry};
pub use class_table::{class_table, ClassRow};

/// Where Debian's package installs the catalogues.
pub const DEFAULT_FURNITURE_DIR: &str = "/usr/share/sweethome3d/furniture";

/// Environment variable that overrides [`DEFAULT_FURNITURE_DIR`].
pub const FURNITURE_DIR_ENV: &str = "SEMRECON_FURNITURE_DIR";

/// Whether a model may be used for training or is kept for testing only.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    /// Used by training rooms.
    Train,
    /// Never used by training rooms (a whole catalogue and some models of the others):
    /// furniture the network has never seen.
    HeldOut,
}

/// One catalogue model's metadata (no geometry).
#[derive(Debug, Clone, PartialEq)]
pub struct LibraryModel {
    /// Catalogue file stem (`BlendSwap-CC-0`, `Scopia`, ...).
    pub catalogue: String,
    /// The catalogue's unique id (`Blend Swap CC-0#bed1`).
    pub id: String,
    /// Display name (`Bed`).
    pub name: String,
    /// Catalogue category (`Bedroom`, `Kitchen`, `Doors and windows`, ...).
    pub category: String,
    /// Fine category from the class table (`bed`, `wardrobe`, `kitchen_cabinet`, `door`, ...).
    pub fine: String,
    /// S3DIS class id (0..13) from the class table.
    pub class: u8,
    /// Size in metres: x = width, y = depth, z = height.
    pub size: Vec3,
    /// Height above the floor of the model's bottom (metres).
    pub elevation: f32,
    /// Whether the model is a door or window (cut into a wall).
    pub door_or_window: bool,
    /// Author, for credits.
    pub creator: String,
    /// Training or held-out.
    pub split: Split,
}

/// The installed catalogues.
#[derive(Debug)]
pub struct FurnitureLibrary {
    /// Every model that the class table maps (people, vehicles and outdoor objects are
    /// mapped with `use = no` and left out of this list).
    pub models: Vec<LibraryModel>,
    /// Every catalogue that opened, with all its models (used or not), in file-name order.
    pub catalogues: Vec<Catalogue>,
    /// What was skipped while opening, one line each (an unreadable archive, a model the
    /// class table does not cover); each was also printed to stderr.
    pub warnings: Vec<String>,
    dir: PathBuf,
    /// Model id -> (index in `catalogues`, index in its `entries`).
    index: HashMap<String, (usize, usize)>,
    /// One open archive per catalogue: reading an entry needs `&mut`, hence the locks, held
    /// only while the entry's bytes are read (decoding happens outside).
    archives: Vec<Mutex<catalogue::Archive>>,
    cache: Mutex<HashMap<String, Arc<LabeledMesh>>>,
}

impl FurnitureLibrary {
    /// Opens the catalogues of `dir` (`*.sh3f`).
    pub fn open(dir: &Path) -> Result<Self> {
        let listing = std::fs::read_dir(dir).map_err(|e| missing_package(dir, &e.to_string()))?;
        let mut paths: Vec<PathBuf> = listing
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("sh3f")))
            .collect();
        paths.sort();
        let table = class_table()?;
        let rows: HashMap<(&str, &str), &ClassRow> =
            table.iter().map(|r| ((r.catalogue.as_str(), r.id.as_str()), r)).collect();
        let mut lib = FurnitureLibrary {
            models: Vec::new(),
            catalogues: Vec::new(),
            warnings: Vec::new(),
            dir: dir.to_path_buf(),
            index: HashMap::new(),
            archives: Vec::new(),
            cache: Mutex::new(HashMap::new()),
        };
        for path in &paths {
            let opened =
                catalogue::open_archive(path).and_then(|mut a| catalogue::read_catalogue(path, &mut a).map(|c| (a, c)));
            let (archive, cat) = match opened {
                Ok(x) => x,
                Err(e) => {
                    lib.warn(format!("skipping furniture catalogue {e}"));
                    continue;
                }
            };
            let ci = lib.catalogues.len();
            for (ei, entry) in cat.entries.iter().enumerate() {
                lib.index.insert(entry.id.clone(), (ci, ei));
                let Some(row) = rows.get(&(cat.stem.as_str(), entry.id.as_str())) else {
                    lib.warn(format!(
                        "{}: model {:?} ({}) has no row in crates/data/furniture_classes.tsv; not used",
                        path.display(),
                        entry.id,
                        entry.name
                    ));
                    continue;
                };
                if !row.used {
                    continue;
                }
                lib.models.push(LibraryModel {
                    catalogue: cat.stem.clone(),
                    id: entry.id.clone(),
                    name: entry.name.clone(),
                    category: entry.category.clone(),
                    fine: row.fine.clone(),
                    class: row.class.id(),
                    size: entry.size,
                    elevation: entry.elevation,
                    door_or_window: entry.door_or_window,
                    creator: entry.creator.clone(),
                    split: row.split,
                });
            }
            lib.catalogues.push(cat);
            lib.archives.push(Mutex::new(archive));
        }
        if lib.catalogues.is_empty() {
            return Err(missing_package(dir, "no readable .sh3f catalogue there"));
        }
        Ok(lib)
    }

    /// Opens `$SEMRECON_FURNITURE_DIR` or [`DEFAULT_FURNITURE_DIR`]; a clear error saying how to
    /// install the package when it is absent.
    pub fn open_default() -> Result<Self> {
        Self::open(&default_dir())
    }

    /// The folder the catalogues were read from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The model with this id, if it is used.
    pub fn model(&self, id: &str) -> Option<&LibraryModel> {
        self.models.iter().find(|m| m.id == id)
    }

    /// The catalogue entry (all properties) of a model id, used or not.
    pub fn entry(&self, id: &str) -> Option<&CatalogueEntry> {
        let &(ci, ei) = self.index.get(id)?;
        self.catalogues.get(ci)?.entries.get(ei)
    }

    /// The model's mesh in its local frame: x in `[0, size.x]` (width), y in `[0, size.y]`
    /// (depth, the front faces -y), z in `[0, size.z]` (height, bottom at 0; the caller adds
    /// [`LibraryModel::elevation`]); every triangle labelled `model.class`, per-vertex
    /// colours from the materials (texture colours sampled at the vertices, big triangles
    /// subdivided so that colour varies over them). Cached: loading a model twice is cheap.
    pub fn load_mesh(&self, model: &LibraryModel) -> Result<std::sync::Arc<LabeledMesh>> {
        if let Some(mesh) = lock(&self.cache).get(&model.id) {
            return Ok(mesh.clone());
        }
        let &(ci, ei) = self.index.get(&model.id).ok_or_else(|| {
            DataError::InvalidArgument(format!("no model {:?} in the catalogues of {}", model.id, self.dir.display()))
        })?;
        let (cat, archive) = (&self.catalogues[ci], &self.archives[ci]);
        let entry = &cat.entries[ei];
        // The lock is not held while decoding: two threads may load the same model at once,
        // and the second insert simply replaces an identical mesh.
        let mesh = Arc::new(obj_mesh::load_entry_mesh(&cat.path, archive, entry, model.class)?);
        lock(&self.cache).insert(model.id.clone(), mesh.clone());
        Ok(mesh)
    }
}

impl FurnitureLibrary {
    /// Drops the cached meshes (all used models together hold about 11.5 M triangles, a few
    /// hundred MB); meshes still held elsewhere stay alive through their `Arc`s.
    pub fn clear_cache(&self) {
        lock(&self.cache).clear();
    }
}

/// `$SEMRECON_FURNITURE_DIR` when set, else [`DEFAULT_FURNITURE_DIR`].
pub fn default_dir() -> PathBuf {
    std::env::var_os(FURNITURE_DIR_ENV).map(PathBuf::from).unwrap_or_else(|| PathBuf::from(DEFAULT_FURNITURE_DIR))
}

/// The error for a folder without catalogues: says how to get them.
fn missing_package(dir: &Path, why: &str) -> DataError {
    DataError::dataset(
        dir,
        format!(
            "no Sweet Home 3D furniture catalogues ({why}): install them with \
             `sudo apt-get install sweethome3d-furniture` (Debian/Ubuntu), or set \
             ${FURNITURE_DIR_ENV} to a folder of .sh3f files"
        ),
    )
}

impl FurnitureLibrary {
    fn warn(&mut self, message: String) {
        eprintln!("warning: {message}");
        self.warnings.push(message);
    }
}

/// Locks a mutex, recovering from poisoning: the guarded maps stay valid even if a thread
/// panicked while holding them (an insert either happened or did not).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
