//! Training and evaluation data of the network: where labelled rooms come from and how they
//! become [`VoxelSample`]s, through the augmentation of [`crate::augment`] (re-exported here
//! as [`Augment`]).
//!
//! A data source is a string, so that the command line, configuration files and tests name
//! data the same way ([`DataSource::parse`]):
//!
//! | source | rooms |
//! |---|---|
//! | `synth:A..B` | procedural rooms of seeds `A..B` (`semrecon_data::synth`), style drawn from the seed |
//! | `synth:A..B:office,lounge` | the same seeds, styles taken in turn from the list (`seed % len`) |
//! | `synth:A..B:classroom` | the held-out style, which no seed draws: rooms unlike any in training |
//! | `synth-lib:A..B` | homes and offices furnished with real modelled furniture (`semrecon_data::library`, needs Debian's `sweethome3d-furniture`), kind drawn from the seed, training models only |
//! | `synth-lib:A..B:bedroom,kitchen` | the same, kinds taken in turn |
//! | `synth-lib:A..B:held-out` (or `:KINDS:held-out`) | furnished only with the held-out models (a whole catalogue and a tenth of the others): furniture training never saw |
//! | `s3dis:PATH` | S3DIS rooms under `PATH` (root, `Area_N` or room folder) |
//! | `scannet:PATH` | one ScanNet scene (folder or `.labels.ply`), or a folder of scene folders |
//! | `ply:PATH` | a PLY file, or every `.ply` file of a folder (sorted), with a vertex `label` property |
//!
//! Meshes (synthetic rooms, ScanNet scenes, PLY files with faces, such as fused TSDF
//! reconstructions of rendered scans) are sampled over their surface at
//! [`points_per_m2`] (several points per voxel, [`crate::surface::sample_surface`]); point
//! clouds (S3DIS, PLY files without faces) are used as they are. The cloud is augmented
//! ([`Augment`]) and voxelised ([`VoxelSample::from_cloud`]).
//!
//! **Split.** Synthetic training and validation rooms are told apart by their seeds only: the
//! recipe in docs/model.md trains on `synth:0..100000` and validates on
//! `synth:1000000..1000040`, seeds that training never sees; [`RoomRef::group`] (the room
//! style for synthetic rooms) lets validation report per style. The `classroom` style
//! (`RoomStyle::HELD_OUT`) is never drawn from a seed, so `synth:A..B` never holds one:
//! `synth:1000000..1000040:classroom` tests on rooms of a style training never saw. For
//! S3DIS the usual split is
//! by area (train Areas 1-4 and 6, validate on Area 5), given as two `s3dis:` sources.
//!
//! Everything is deterministic: a room and a seed give the same sample, bit for bit.
//!
//! ```
//! use semrecon_net::dataset::{load_sample, Augment, DataSource};
//!
//! let source = DataSource::parse("synth:7..9:office")?;
//! let rooms = source.rooms()?;
//! assert_eq!(rooms.len(), 2);
//! assert_eq!(rooms[0].group, "office");
//! let sample = load_sample(&rooms[0], 0.1, Some(&Augment::training()), 42)?;
//! assert!(sample.len() > 100);
//! # Ok::<(), semrecon_net::NetError>(())
//! ```

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use semrecon_data::library::rooms::{generate_library_room, HomeRoomKind, LibraryRoomConfig};
use semrecon_data::library::{FurnitureLibrary, Split};
use semrecon_data::synth::{generate_room, RoomConfig, RoomStyle};
use semrecon_data::{read_ply, LabeledMesh, LabeledPointCloud};

pub use crate::augment::Augment;
use crate::error::{NetError, Result};
use crate::sample::VoxelSample;
use crate::surface::sample_surface;

/// Surface samples per voxel face area: enough that every surface voxel gets several points.
const POINTS_PER_VOXEL_FACE: f32 = 6.0;

/// Density of surface sampling (points per square metre) for a voxel size (metres): about
/// six points per voxel face.
pub fn points_per_m2(voxel_size: f32) -> f32 {
    POINTS_PER_VOXEL_FACE / (voxel_size * voxel_size).max(1e-8)
}

/// Where labelled rooms come from (see the module table for the string forms).
#[derive(Debug, Clone, PartialEq)]
pub enum DataSource {
    /// Procedural rooms.
    Synth {
        /// Room seeds.
        seeds: Range<u64>,
        /// Styles taken in turn (`seed % len`); empty: drawn from the seed.
        styles: Vec<RoomStyle>,
    },
    /// Rooms furnished from the furniture catalogues (`semrecon_data::library`).
    Library {
        /// Room seeds.
        seeds: Range<u64>,
        /// Kinds taken in turn (`seed % len`); empty: drawn from the seed.
        kinds: Vec<HomeRoomKind>,
        /// Training models, or the held-out ones only.
        split: Split,
    },
    /// S3DIS rooms under a folder.
    S3dis(PathBuf),
    /// ScanNet scenes: one scene (folder or `.labels.ply`) or a folder of scene folders.
    Scannet(PathBuf),
    /// A labelled PLY file or a folder of them.
    Ply(PathBuf),
}

/// One room of a [`DataSource`], cheap to list and to send to a loader thread.
#[derive(Debug, Clone, PartialEq)]
pub struct RoomRef {
    /// Short unique name (`synth:17`, a path) for logs.
    pub name: String,
    /// Group for per-group reports: the style of a synthetic room, else the source kind
    /// (`s3dis`, `scannet`, `ply`).
    pub group: String,
    kind: RoomKind,
}

#[derive(Debug, Clone, PartialEq)]
enum RoomKind {
    Synth { seed: u64, style: Option<RoomStyle> },
    Library { seed: u64, kind: Option<HomeRoomKind>, split: Split },
    S3dis(PathBuf),
    Scannet(PathBuf),
    Ply(PathBuf),
}

impl DataSource {
    /// Parses `synth:A..B[:style,style]`, `s3dis:PATH`, `scannet:PATH` or `ply:PATH`.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] naming the string and what is wrong (paths are checked
    /// later, by [`Self::rooms`]).
    pub fn parse(spec: &str) -> Result<Self> {
        let bad = |why: &str| {
            NetError::InvalidInput(format!(
                "data source {spec:?}: {why} (expected synth:A..B[:style,...], synth-lib:A..B[:kind,...][:held-out], s3dis:PATH, scannet:PATH or ply:PATH)"
            ))
        };
        let (kind, rest) = spec.split_once(':').ok_or_else(|| bad("no `kind:` prefix"))?;
        let seed_range = |range: &str| -> Result<Range<u64>> {
            let (a, b) = range.split_once("..").ok_or_else(|| bad("seeds must be a range A..B"))?;
            let a: u64 = a.trim().parse().map_err(|_| bad("first seed is not an integer"))?;
            let b: u64 = b.trim().parse().map_err(|_| bad("last seed is not an integer"))?;
            if b <= a {
                return Err(bad("empty seed range"));
            }
            Ok(a..b)
        };
        match kind {
            "synth-lib" => {
                let mut parts = rest.split(':');
                let seeds = seed_range(parts.next().unwrap_or_default())?;
                let mut kinds = Vec::new();
                let mut split = Split::Train;
                for part in parts {
                    if part.trim().eq_ignore_ascii_case("held-out") {
                        split = Split::HeldOut;
                    } else if kinds.is_empty() && split == Split::Train {
                        kinds = part
                            .split(',')
                            .map(|x| x.parse::<HomeRoomKind>().map_err(|e| bad(&e.to_string())))
                            .collect::<Result<Vec<_>>>()?;
                    } else {
                        return Err(bad(&format!("unexpected part {part:?}")));
                    }
                }
                Ok(Self::Library { seeds, kinds, split })
            }
            "synth" => {
                let (range, styles) = match rest.split_once(':') {
                    Some((r, s)) => (r, Some(s)),
                    None => (rest, None),
                };
                let seeds = seed_range(range)?;
                let styles = match styles {
                    Some(s) => s
                        .split(',')
                        .map(|x| x.parse::<RoomStyle>().map_err(|e| bad(&e.to_string())))
                        .collect::<Result<Vec<_>>>()?,
                    None => Vec::new(),
                };
                Ok(Self::Synth { seeds, styles })
            }
            "s3dis" | "scannet" | "ply" if rest.is_empty() => Err(bad("empty path")),
            "s3dis" => Ok(Self::S3dis(PathBuf::from(rest))),
            "scannet" => Ok(Self::Scannet(PathBuf::from(rest))),
            "ply" => Ok(Self::Ply(PathBuf::from(rest))),
            _ => Err(bad(&format!("unknown kind `{kind}`"))),
        }
    }

    /// The rooms of the source, in a fixed order (seeds ascending, paths sorted).
    ///
    /// # Errors
    /// Missing folders or folders without rooms ([`NetError::Data`]).
    pub fn rooms(&self) -> Result<Vec<RoomRef>> {
        match self {
            Self::Synth { seeds, styles } => Ok(seeds
                .clone()
                .map(|seed| {
                    let style =
                        if styles.is_empty() { None } else { Some(styles[(seed % styles.len() as u64) as usize]) };
                    RoomRef {
                        name: format!("synth:{seed}"),
                        group: style.unwrap_or_else(|| drawn_style(seed)).name().to_string(),
                        kind: RoomKind::Synth { seed, style },
                    }
                })
                .collect()),
            Self::Library { seeds, kinds, split } => Ok(seeds
                .clone()
                .map(|seed| {
                    let kind = if kinds.is_empty() { None } else { Some(kinds[(seed % kinds.len() as u64) as usize]) };
                    let held_out = if *split == Split::HeldOut { "-held-out" } else { "" };
                    RoomRef {
                        name: format!("synth-lib:{seed}{held_out}"),
                        group: format!("lib-{}{held_out}", kind.unwrap_or_else(|| drawn_kind(seed)).name()),
                        kind: RoomKind::Library { seed, kind, split: *split },
                    }
                })
                .collect()),
            Self::S3dis(root) => Ok(semrecon_data::s3dis::find_s3dis_rooms(root)?
                .into_iter()
                .map(|p| RoomRef { name: p.display().to_string(), group: "s3dis".into(), kind: RoomKind::S3dis(p) })
                .collect()),
            Self::Scannet(path) => {
                let scenes = if path.is_dir() && !semrecon_data::scannet_mesh::scannet_labels_path(path).exists() {
                    folder_rooms(
                        path,
                        |p| semrecon_data::scannet_mesh::scannet_labels_path(p).exists(),
                        "no ScanNet scene (*_vh_clean_2.labels.ply) found",
                    )?
                } else {
                    single_room(path, path.exists())?
                };
                Ok(scenes
                    .into_iter()
                    .map(|p| RoomRef {
                        name: p.display().to_string(),
                        group: "scannet".into(),
                        kind: RoomKind::Scannet(p),
                    })
                    .collect())
            }
            Self::Ply(path) => {
                let files = if path.is_dir() {
                    folder_rooms(
                        path,
                        |p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")) && p.is_file(),
                        "no .ply file in the folder",
                    )?
                } else {
                    single_room(path, path.is_file())?
                };
                Ok(files
                    .into_iter()
                    .map(|p| RoomRef { name: p.display().to_string(), group: "ply".into(), kind: RoomKind::Ply(p) })
                    .collect())
            }
        }
    }
}

/// Rooms of several sources, concatenated in order.
///
/// # Errors
/// The first failing source's error.
pub fn rooms_of(sources: &[DataSource]) -> Result<Vec<RoomRef>> {
    let mut all = Vec::new();
    for s in sources {
        all.extend(s.rooms()?);
    }
    Ok(all)
}

/// The entries of the folder `dir` that `is_room` accepts, sorted; an error naming `dir` with
/// `none_found` when there is none.
fn folder_rooms(dir: &Path, is_room: impl Fn(&Path) -> bool, none_found: &str) -> Result<Vec<PathBuf>> {
    let mut rooms: Vec<PathBuf> = list_dir(dir)?.into_iter().filter(|p| is_room(p)).collect();
    rooms.sort();
    if rooms.is_empty() {
        return Err(semrecon_data::DataError::dataset(dir, none_found).into());
    }
    Ok(rooms)
}

/// The one room `path` when it `exists` (as the kind of source wants it), else an error.
fn single_room(path: &Path, exists: bool) -> Result<Vec<PathBuf>> {
    if exists {
        Ok(vec![path.to_path_buf()])
    } else {
        Err(semrecon_data::DataError::dataset(path, "does not exist").into())
    }
}

fn list_dir(path: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(path).map_err(|e| NetError::io(path, e))?;
    let mut out = Vec::new();
    for e in entries {
        out.push(e.map_err(|e| NetError::io(path, e))?.path());
    }
    Ok(out)
}

/// The style `generate_room` draws for `seed` when none is given: its first draw from the
/// seeded generator (checked against `generate_room` by a test), so listing rooms does not
/// have to generate them.
fn drawn_style(seed: u64) -> RoomStyle {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    RoomStyle::ALL[rng.random_range(0..RoomStyle::ALL.len())]
}

/// The furniture catalogues, opened once per process (they are read-only, and their model
/// meshes are cached inside).
fn furniture_library() -> Result<&'static FurnitureLibrary> {
    static LIBRARY: OnceLock<std::result::Result<FurnitureLibrary, String>> = OnceLock::new();
    LIBRARY
        .get_or_init(|| FurnitureLibrary::open_default().map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|e| NetError::InvalidInput(e.clone()))
}

/// The kind `generate_library_room` draws for `seed` when none is given: its first draw
/// (checked against the generator by a test over the installed library), so listing rooms
/// does not have to generate them.
fn drawn_kind(seed: u64) -> HomeRoomKind {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4C49_4252_4152_5931);
    HomeRoomKind::ALL[rng.random_range(0..HomeRoomKind::ALL.len())]
}

/// The labelled point cloud of a room, before augmentation: surface samples of meshes
/// (seeded by `seed`), the points of point clouds.
///
/// # Errors
/// Unreadable or invalid files, naming the file.
pub fn load_cloud(room: &RoomRef, voxel_size: f32, seed: u64) -> Result<LabeledPointCloud> {
    let density = points_per_m2(voxel_size);
    let from_mesh = |mesh: &LabeledMesh| {
        if mesh.triangles.is_empty() {
            LabeledPointCloud::from_mesh(mesh)
        } else {
            sample_surface(mesh, density, seed)
        }
    };
    Ok(match &room.kind {
        RoomKind::Synth { seed: room_seed, style } => {
            let r = generate_room(&RoomConfig { seed: *room_seed, style: *style });
            sample_surface(&r.mesh, density, seed)
        }
        RoomKind::Library { seed: room_seed, kind, split } => {
            let config = LibraryRoomConfig { seed: *room_seed, kind: *kind, split: *split };
            let r = generate_library_room(&config, furniture_library()?)?;
            sample_surface(&r.mesh, density, seed)
        }
        RoomKind::S3dis(p) => semrecon_data::s3dis::read_s3dis_room(p)?,
        RoomKind::Scannet(p) => from_mesh(&semrecon_data::scannet_mesh::read_scannet_mesh(p)?),
        RoomKind::Ply(p) => {
            let mesh = read_ply(p)?;
            if mesh.vertex_labels.is_empty() && mesh.triangle_labels.is_empty() {
                return Err(semrecon_data::DataError::parse(
                    p,
                    None,
                    "no vertex or face `label` property: not a labelled room",
                )
                .into());
            }
            from_mesh(&mesh)
        }
    })
}

/// A room as network input: [`load_cloud`], then `augment` (seeded by `seed`) when given,
/// then [`VoxelSample::from_cloud`] at `voxel_size`. An empty room gives an empty sample.
///
/// # Errors
/// Those of [`load_cloud`] and of voxelisation.
pub fn load_sample(room: &RoomRef, voxel_size: f32, augment: Option<&Augment>, seed: u64) -> Result<VoxelSample> {
    let mut cloud = load_cloud(room, voxel_size, seed)?;
    if let Some(a) = augment {
        a.apply(&mut cloud, seed);
    }
    VoxelSample::from_cloud(&cloud, voxel_size)
}

/// Seed of the sample of `room_index` in `epoch` of a run seeded with `run_seed`: every
/// (epoch, room) pair gets its own augmentation, reproducibly.
pub fn sample_seed(run_seed: u64, epoch: u64, room_index: u64) -> u64 {
    // SplitMix64 finaliser over the packed triple: nearby inputs give unrelated seeds.
    let mut z = run_seed ^ epoch.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ room_index.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use glam::Vec3;
    use semrecon_data::class::SemanticClass;

    #[test]
    fn parses_sources_and_rejects_bad_ones() {
        assert_eq!(DataSource::parse("synth:3..5").unwrap(), DataSource::Synth { seeds: 3..5, styles: vec![] });
        assert_eq!(
            DataSource::parse("synth:0..10:office,hallway").unwrap(),
            DataSource::Synth { seeds: 0..10, styles: vec![RoomStyle::Office, RoomStyle::Hallway] }
        );
        assert_eq!(DataSource::parse("ply:/x/y").unwrap(), DataSource::Ply("/x/y".into()));
        for bad in ["synth:5..5", "synth:a..b", "synth:0..3:kitchen", "foo:bar", "s3dis:", "nothing"] {
            let e = DataSource::parse(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{e}");
        }
        let e = DataSource::parse("ply:/no/such/dir").unwrap().rooms().unwrap_err().to_string();
        assert!(e.contains("/no/such/dir"), "{e}");
    }

    #[test]
    fn parses_library_sources() {
        assert_eq!(
            DataSource::parse("synth-lib:3..5").unwrap(),
            DataSource::Library { seeds: 3..5, kinds: vec![], split: Split::Train }
        );
        assert_eq!(
            DataSource::parse("synth-lib:0..4:bedroom,kitchen:held-out").unwrap(),
            DataSource::Library {
                seeds: 0..4,
                kinds: vec![HomeRoomKind::Bedroom, HomeRoomKind::Kitchen],
                split: Split::HeldOut
            }
        );
        assert_eq!(
            DataSource::parse("synth-lib:0..4:held-out").unwrap(),
            DataSource::Library { seeds: 0..4, kinds: vec![], split: Split::HeldOut }
        );
        let rooms = DataSource::parse("synth-lib:0..4:bedroom,kitchen:held-out").unwrap().rooms().unwrap();
        let groups: Vec<_> = rooms.iter().map(|r| r.group.as_str()).collect();
        assert_eq!(
            groups,
            ["lib-bedroom-held-out", "lib-kitchen-held-out", "lib-bedroom-held-out", "lib-kitchen-held-out"]
        );
        for bad in ["synth-lib:5..5", "synth-lib:0..3:garage", "synth-lib:0..3:held-out:bedroom", "synth-lib:"] {
            let e = DataSource::parse(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{e}");
        }
    }

    #[test]
    fn listed_kind_is_the_generated_kind() {
        let Ok(lib) = furniture_library() else {
            println!("skipping: the furniture catalogues are not installed (apt-get install sweethome3d-furniture)");
            return;
        };
        for seed in 0..3 {
            let room = semrecon_data::library::rooms::generate_library_room_detailed(
                &LibraryRoomConfig { seed, kind: None, split: Split::Train },
                lib,
            )
            .unwrap();
            assert_eq!(room.kind, drawn_kind(seed));
        }
    }

    #[test]
    fn listed_style_is_the_generated_style() {
        let rooms = DataSource::parse("synth:0..6").unwrap().rooms().unwrap();
        for r in &rooms[..3] {
            let RoomKind::Synth { seed, .. } = r.kind else { unreachable!() };
            assert_eq!(generate_room(&RoomConfig { seed, style: None }).style.name(), r.group);
        }
        let fixed = DataSource::parse("synth:0..4:office,lounge").unwrap().rooms().unwrap();
        let groups: Vec<_> = fixed.iter().map(|r| r.group.as_str()).collect();
        assert_eq!(groups, ["office", "lounge", "office", "lounge"]);
        // The held-out style only when named; the room really is one.
        let held_out = DataSource::parse("synth:7..9:Classroom").unwrap().rooms().unwrap();
        assert!(held_out.iter().all(|r| r.group == "classroom"));
        let RoomKind::Synth { seed, style } = held_out[0].kind else { unreachable!() };
        assert_eq!(generate_room(&RoomConfig { seed, style }).style, RoomStyle::Classroom);
        let drawn = DataSource::parse("synth:0..200").unwrap().rooms().unwrap();
        assert!(drawn.iter().all(|r| r.group != "classroom"));
    }

    #[test]
    fn samples_are_deterministic_and_augmentation_changes_them() {
        let room = &DataSource::parse("synth:11..12").unwrap().rooms().unwrap()[0];
        let plain = load_sample(room, 0.1, None, 1).unwrap();
        assert_eq!(plain, load_sample(room, 0.1, None, 1).unwrap());
        let labelled = plain.labels.iter().filter(|&&l| l < 13).count();
        assert!(labelled * 10 > plain.len() * 9, "{labelled} of {}", plain.len());
        let aug = Augment::training();
        let a = load_sample(room, 0.1, Some(&aug), 2).unwrap();
        assert_eq!(a, load_sample(room, 0.1, Some(&aug), 2).unwrap());
        assert_ne!(a, plain);
        assert!(!a.is_empty());
        let mut cloud = load_cloud(room, 0.1, 1).unwrap();
        let before = cloud.clone();
        Augment::none().apply(&mut cloud, 5);
        assert_eq!(cloud.positions.len(), before.positions.len());
        assert_eq!(cloud.colors, before.colors);
        assert_eq!(VoxelSample::from_cloud(&LabeledPointCloud::default(), 0.1).unwrap().len(), 0);
    }

    #[test]
    fn translation_moves_the_floor_off_z_zero_and_only_shifts() {
        let room = &DataSource::parse("synth:11..12").unwrap().rooms().unwrap()[0];
        // `none` still centres the room horizontally: compare with that.
        let mut cloud = load_cloud(room, 0.1, 1).unwrap();
        Augment::none().apply(&mut cloud, 0);
        let shift_only = Augment { translate: [0.0, 0.0, 0.8], ..Augment::none() };
        let mut floors = Vec::new();
        for seed in 0..8 {
            let mut moved = load_cloud(room, 0.1, 1).unwrap();
            shift_only.apply(&mut moved, seed);
            assert_eq!(moved.colors, cloud.colors);
            assert_eq!(moved.labels, cloud.labels);
            let dz = moved.positions[0].z - cloud.positions[0].z;
            assert!(dz.abs() <= 0.8);
            for (a, b) in moved.positions.iter().zip(&cloud.positions) {
                assert!((a.z - b.z - dz).abs() < 1e-4 && a.truncate() == b.truncate());
            }
            floors.push(dz);
        }
        // Different seeds, different heights.
        assert!(floors.iter().any(|&z| (z - floors[0]).abs() > 0.1), "{floors:?}");
    }

    #[test]
    fn height_cut_keeps_exactly_the_points_below_the_cut() {
        let room = &DataSource::parse("synth:11..12").unwrap().rooms().unwrap()[0];
        let original = load_cloud(room, 0.1, 1).unwrap();
        let top = original.positions.iter().fold(f32::MIN, |m, p| m.max(p.z));
        let cut = Augment { height_cut_probability: 1.0, height_cut: [1.2, 1.2], ..Augment::none() };
        let mut cloud = original.clone();
        cut.apply(&mut cloud, 3);
        let below: Vec<_> = original.labels.iter().zip(&original.positions).filter(|(_, p)| p.z <= 1.2).collect();
        assert!(top > 2.0 && !below.is_empty() && below.len() < original.len());
        assert_eq!(cloud.len(), below.len());
        assert!(cloud.positions.iter().all(|p| p.z <= 1.2));
        assert!(cloud.labels.iter().zip(&below).all(|(a, (b, _))| a == *b));
        // Probability 0: nothing cut; the recipe cuts some samples and not others.
        let mut whole = original.clone();
        Augment { height_cut_probability: 0.0, ..cut.clone() }.apply(&mut whole, 3);
        assert_eq!(whole.len(), original.len());
        let recipe = Augment { height_cut_probability: 0.35, height_cut: [1.0, 2.2], ..Augment::none() };
        let sizes: Vec<usize> = (0..12)
            .map(|seed| {
                let mut c = original.clone();
                recipe.apply(&mut c, seed);
                c.len()
            })
            .collect();
        assert!(sizes.contains(&original.len()) && sizes.iter().any(|&n| n < original.len()), "{sizes:?}");
        // A box crop keeps all heights.
        let crop = Augment { crop_probability: 1.0, crop_size: [4.0, 4.0], ..cut };
        let mut cropped = original.clone();
        crop.apply(&mut cropped, 3);
        assert!(cropped.positions.iter().any(|p| p.z > 2.0));
    }

    #[test]
    fn context_drop_removes_exactly_the_ceiling_or_the_floor() {
        let room = &DataSource::parse("synth:11..12").unwrap().rooms().unwrap()[0];
        let original = load_cloud(room, 0.1, 1).unwrap();
        let count = |c: &LabeledPointCloud, class: u8| c.labels.iter().filter(|&&l| l == class).count();
        assert!(count(&original, 0) > 0 && count(&original, 1) > 0);
        for (ceiling, floor) in [(1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            let drop = Augment { ceiling_drop_probability: ceiling, floor_drop_probability: floor, ..Augment::none() };
            let mut cloud = original.clone();
            drop.apply(&mut cloud, 5);
            let gone = |class: u8, p: f32| if p > 0.0 { 0 } else { count(&original, class) };
            assert_eq!(count(&cloud, 0), gone(0, ceiling));
            assert_eq!(count(&cloud, 1), gone(1, floor));
            // Everything else stays, in order.
            let rest: Vec<u8> = original.labels.iter().copied().filter(|&l| l > 1).collect();
            let kept: Vec<u8> = cloud.labels.iter().copied().filter(|&l| l > 1).collect();
            assert_eq!(rest, kept);
        }
        // The recipe drops the ceiling from some samples and keeps it in others.
        let with_ceiling: Vec<bool> = (0..16)
            .map(|seed| {
                let mut c = original.clone();
                Augment { ceiling_drop_probability: 0.5, ..Augment::none() }.apply(&mut c, seed);
                count(&c, 0) > 0
            })
            .collect();
        assert!(with_ceiling.contains(&true) && with_ceiling.contains(&false), "{with_ceiling:?}");
        // A sample of nothing but ceiling keeps it.
        let mut only_ceiling = original.clone();
        only_ceiling.labels.iter_mut().for_each(|l| *l = 0);
        Augment { ceiling_drop_probability: 1.0, ..Augment::none() }.apply(&mut only_ceiling, 5);
        assert_eq!(only_ceiling.len(), original.len());
    }

    #[test]
    fn wall_drop_removes_only_wall_points_of_the_chosen_sides() {
        let room = &DataSource::parse("synth:11..12").unwrap().rooms().unwrap()[0];
        let original = load_cloud(room, 0.1, 1).unwrap();
        let wall = SemanticClass::Wall.id();
        let count = |c: &LabeledPointCloud, class: u8| c.labels.iter().filter(|&&l| l == class).count();
        // The four sides together are every wall point; one side is some of them.
        let all = crate::augment::walls_along_sides(&original, [true; 4]);
        assert_eq!(all.iter().filter(|&&d| d).count(), count(&original, wall));
        let one = crate::augment::walls_along_sides(&original, [true, false, false, false]);
        let n_one = one.iter().filter(|&&d| d).count();
        assert!(n_one > 0 && n_one < count(&original, wall), "{n_one}");
        // Plain reference: a wall point of the low-x side is nearer to it than to any other.
        let (lo, hi) = original
            .positions
            .iter()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(a, b), p| (a.min(*p), b.max(*p)));
        for ((p, &l), &d) in original.positions.iter().zip(&original.labels).zip(&one) {
            let dx = p.x - lo.x;
            let nearest_low_x = l == wall && dx <= hi.x - p.x && dx <= p.y - lo.y && dx <= hi.y - p.y;
            assert_eq!(d, nearest_low_x);
        }
        // The recipe drops walls from some samples, never another class.
        let drop = Augment { wall_drop_probability: 1.0, ..Augment::none() };
        let rest: Vec<u8> = original.labels.iter().copied().filter(|&l| l != wall).collect();
        let mut fewer = 0;
        for seed in 0..6 {
            let mut c = original.clone();
            drop.apply(&mut c, seed);
            let kept: Vec<u8> = c.labels.iter().copied().filter(|&l| l != wall).collect();
            assert_eq!(kept, rest);
            fewer += usize::from(count(&c, wall) < count(&original, wall));
        }
        assert_eq!(fewer, 6);
        assert_eq!(Augment::from_recipe("real-fragments"), Some(Augment::real_fragments()));
    }

    #[test]
    fn ply_rooms_with_colour_and_label_load() {
        let dir = tempfile::tempdir().unwrap();
        let mesh = generate_room(&RoomConfig { seed: 3, style: None }).mesh;
        let mut recon = mesh.clone();
        recon.triangle_labels.clear();
        semrecon_data::write_ply(dir.path().join("a.ply"), &recon, semrecon_data::PlyEncoding::BinaryLittleEndian)
            .unwrap();
        let rooms = DataSource::parse(&format!("ply:{}", dir.path().display())).unwrap().rooms().unwrap();
        assert_eq!(rooms.len(), 1);
        let s = load_sample(&rooms[0], 0.1, None, 0).unwrap();
        assert!(s.len() > 100);
        assert!(s.labels.iter().filter(|&&l| l < 13).count() * 10 > s.len() * 9);
        let mut unlabelled = recon;
        unlabelled.vertex_labels.clear();
        let p = dir.path().join("b.ply");
        semrecon_data::write_ply(&p, &unlabelled, semrecon_data::PlyEncoding::Ascii).unwrap();
        let e = load_sample(&DataSource::Ply(p).rooms().unwrap()[0], 0.1, None, 0).unwrap_err().to_string();
        assert!(e.contains("b.ply") && e.contains("label"), "{e}");
    }
}
