//! `semrecon segment`: labels every vertex of a point cloud or mesh (PLY) with one of the 13
//! classes by running CBSCN on it, and writes the same file with a `label` vertex property
//! (u8, MISSION.md's class order) added or replaced; every other element and property (faces,
//! normals, colours, anything else) is kept as it was.
//!
//! The network sees voxels of coloured surface: for a mesh, the vertices alone can be far
//! apart on large flat triangles, so the surface is also sampled densely (several points per
//! voxel, as the training data is made) and every vertex takes the class of its voxel. Inputs
//! are in metres with z up (the S3DIS and ScanNet convention), unless the file records its
//! up direction (`comment semrecon up X Y Z`: the meshes of `semrecon run`, `live` and `demo`,
//! whose map frame is the dataset's or the first camera's); `--up` names another up axis or
//! direction. The input is turned so that up is +z for the network only (the output keeps the
//! input's coordinates and comments).
//!
//! `--structure` refines the network's voxel labels with the room's geometry (segment votes,
//! floor and ceiling planes; `semrecon_net::structure`) and `--tta N` averages the network
//! over N turns and mirrors of the room about z (`semrecon_net::tta`); docs/model.md
//! measures both.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use semrecon_data::ply::{mesh_from_ply, Column, PlyFile, PlyFormat, Property, PropertyData};
use semrecon_data::{LabelSet, LabeledMesh, PlyEncoding};
use semrecon_net::dataset::points_per_m2;
use semrecon_net::structure::{
    refine, BeamFaceParams, PlaneParams, Refinement, SegmentParams, StructureConfig, StructureMode,
};
use semrecon_net::surface::sample_surface;
use semrecon_net::{shipped, NetConfig, Segmenter, Tta, TtaMean};

/// Arguments of `semrecon segment`.
#[derive(clap::Args)]
pub struct SegmentArgs {
    /// Input point cloud or mesh (PLY: x y z, optional red green blue, optional faces).
    #[arg(long)]
    input: PathBuf,
    /// Output PLY: the input with a `label` vertex property (0..12, or 0..20 with `--labels
    /// home`).
    #[arg(long)]
    out: PathBuf,
    /// Model file (safetensors); default: the shipped model (see `SEMRECON_MODEL`).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Configuration of a model file that does not store one (s20, s50, live or a file); when
    /// the file stores one, the two must agree.
    #[arg(long)]
    config: Option<String>,
    /// The input's up axis (x, y, z, -x, -y, -z) or direction (x,y,z); it is turned onto +z
    /// for the network. Default: the up direction the file records (meshes of `semrecon run`,
    /// `live` and `demo`), else z.
    #[arg(long, value_parser = parse_up, allow_hyphen_values = true)]
    up: Option<Up>,
    /// Label set written: s3dis (the 13 S3DIS classes) or home (ScanNet's 20 classes, ids in
    /// the ScanNet benchmark's order, and the ceiling as 20: beds, cabinets, counters,
    /// toilets... where S3DIS says clutter; needs a model with the home head, as shipped).
    #[arg(long, default_value = "s3dis", value_parser = parse_label_set)]
    labels: LabelSet,
    #[command(flatten)]
    structure: StructureArgs,
    #[command(flatten)]
    device: crate::device::DeviceArgs,
}

/// Parses `s3dis|home` (`scannet20` for `home`).
pub fn parse_label_set(s: &str) -> Result<LabelSet, String> {
    s.parse()
}

/// The structure and test-time augmentation options of `segment` and `eval seg`.
#[derive(clap::Args, Clone, Debug)]
pub struct StructureArgs {
    /// Room structure applied to the network's labels: none (the network alone), segments
    /// (each geometric segment takes the class of its summed probabilities), planes (floor
    /// and ceiling from the big horizontal planes, z up) or all.
    #[arg(long, default_value = DEFAULT_STRUCTURE, value_parser = parse_structure)]
    pub structure: StructureMode,
    /// Test-time augmentation: average the network over N views of the room about z (N
    /// network calls): 1 (off), 2 (half turn), 4 (the four 90-degree yaws) or 8 (the four
    /// yaws x a mirror in x).
    #[arg(long, default_value_t = 1, value_parser = parse_tta)]
    pub tta: u32,
    /// Test-time augmentation: average the views' probabilities or their logits.
    #[arg(long, default_value_t = TtaMean::Probabilities, value_parser = parse_tta_mean)]
    pub tta_mean: TtaMean,
    /// Segments: Felzenszwalb-Huttenlocher's k (larger: larger segments).
    #[arg(long, default_value_t = SegmentParams::default().k)]
    pub segment_k: f32,
    /// Segments: weight of the colour difference against the normal angle in edge weights.
    #[arg(long, default_value_t = SegmentParams::default().color_weight)]
    pub segment_color: f32,
    /// Segments: smallest segment in voxels (smaller ones merge into a neighbour).
    #[arg(long, default_value_t = SegmentParams::default().min_size)]
    pub segment_min_size: usize,
    /// Segments: leave wall faces that rise from a beam's underside as the vote made them
    /// (by default they become beam, as S3DIS labels a bulkhead's faces).
    #[arg(long)]
    pub no_beam_faces: bool,
}

/// The default `--structure`: segment votes, the one step that helped the real labelled scan
/// (S3DIS fragment: accuracy 47.1 -> 55.7 %) without hurting generated rooms, at about a
/// tenth of the network's time (docs/model.md, "Structure at inference").
pub const DEFAULT_STRUCTURE: &str = "segments";

/// Parses `none|segments|planes|all`.
pub fn parse_structure(s: &str) -> Result<StructureMode, String> {
    s.parse()
}

/// Parses `--tta`: 1, 2, 4 or 8.
pub fn parse_tta(s: &str) -> Result<u32, String> {
    let n: u32 = s.trim().parse().map_err(|_| format!("`{s}`: expected a number of views, 1, 2, 4 or 8"))?;
    Tta::new(n as usize).map_err(|e| e.to_string())?;
    Ok(n)
}

/// Parses `--tta-mean`: probabilities or logits.
pub fn parse_tta_mean(s: &str) -> Result<TtaMean, String> {
    s.parse()
}

impl StructureArgs {
    /// The test-time augmentation these options describe.
    ///
    /// # Errors
    /// A number of views other than 1, 2, 4 or 8 (which `--tta` already rejects).
    pub fn tta(&self) -> anyhow::Result<Tta> {
        Ok(Tta::new(self.tta as usize)?.with_mean(self.tta_mean))
    }

    /// The structure configuration these options describe.
    pub fn config(&self) -> StructureConfig {
        StructureConfig {
            mode: self.structure,
            segments: SegmentParams {
                k: self.segment_k,
                color_weight: self.segment_color,
                min_size: self.segment_min_size,
            },
            planes: PlaneParams::default(),
            beam_faces: (!self.no_beam_faces).then(BeamFaceParams::default),
        }
    }
}

/// Labels of voxels from the network with test-time augmentation and structure: the class
/// of every voxel and what the structure step found, with the time of the network calls and
/// of the structure step.
///
/// # Shapes
/// `coords`: `[v]`, `features`: `[v, 3]`, `logits`: the network's scores of the unmoved
/// voxels when the caller already has them (`[v, classes]`).
pub fn voxel_labels(
    net: &mut Segmenter,
    coords: &[semrecon_sparse::Coord],
    features: &[f32],
    logits: Option<Vec<f32>>,
    options: &StructureArgs,
) -> anyhow::Result<(Refinement, f64, f64)> {
    let k = net.config().classes;
    let t = Instant::now();
    let probs = options.tta()?.probabilities(net, coords, features, logits)?;
    let network_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let refinement = refine(coords, features, &probs, k, net.config().voxel_size, &options.config())?;
    Ok((refinement, network_s, t.elapsed().as_secs_f64()))
}

/// Which axis of an input points up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// `+x`.
    X,
    /// `+y`.
    Y,
    /// `+z` (no rotation).
    Z,
    /// `-x`.
    NegX,
    /// `-y`.
    NegY,
    /// `-z`.
    NegZ,
}

impl UpAxis {
    /// A proper rotation (determinant +1, no mirroring) taking this axis onto +z.
    pub fn to_z_up(self, p: Vec3) -> Vec3 {
        match self {
            Self::Z => p,
            Self::Y => Vec3::new(p.x, -p.z, p.y),
            Self::X => Vec3::new(-p.z, p.y, p.x),
            Self::NegZ => Vec3::new(p.x, -p.y, -p.z),
            Self::NegY => Vec3::new(p.x, p.z, -p.y),
            Self::NegX => Vec3::new(p.z, p.y, -p.x),
        }
    }
}

/// Where an input's up points: one of its axes, or any direction (a scan's estimated
/// gravity is seldom along an axis: 7-Scenes' is 25 degrees off its -y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Up {
    /// Along an axis (turned onto +z by a quarter or half turn).
    Axis(UpAxis),
    /// Along a unit direction (turned onto +z by the shortest rotation).
    Direction(Vec3),
}

impl Up {
    /// `p` turned so that this up becomes +z (a proper rotation: no mirroring).
    pub fn to_z_up(self, p: Vec3) -> Vec3 {
        match self {
            Self::Axis(a) => a.to_z_up(p),
            Self::Direction(d) => glam::Quat::from_rotation_arc(d, Vec3::Z) * p,
        }
    }
}

impl std::fmt::Display for Up {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Axis(a) => write!(f, "{a:?} axis"),
            Self::Direction(d) => write!(f, "{:.4},{:.4},{:.4}", d.x, d.y, d.z),
        }
    }
}

/// Parses `x|y|z|-x|-y|-z` (also `+x`, any case) or a direction `x,y,z` (not zero).
pub fn parse_up(s: &str) -> Result<Up, String> {
    let axis = match s.trim().to_ascii_lowercase().as_str() {
        "x" | "+x" => Some(UpAxis::X),
        "y" | "+y" => Some(UpAxis::Y),
        "z" | "+z" => Some(UpAxis::Z),
        "-x" => Some(UpAxis::NegX),
        "-y" => Some(UpAxis::NegY),
        "-z" => Some(UpAxis::NegZ),
        _ => None,
    };
    if let Some(a) = axis {
        return Ok(Up::Axis(a));
    }
    if !s.contains(',') {
        return Err(format!("`{s}`: expected one of x, y, z, -x, -y, -z or a direction x,y,z"));
    }
    let v = crate::cli_values::parse_vec3(s)?;
    v.try_normalize().map(Up::Direction).ok_or_else(|| format!("`{s}`: the up direction must not be zero"))
}

/// The network of `--model` (with `--config`), or the shipped one.
pub fn load_model(model: Option<&Path>, config: Option<&str>) -> anyhow::Result<Segmenter> {
    let config = config.map(NetConfig::from_name_or_file).transpose()?;
    Ok(match model {
        Some(path) => shipped::load(path, config.as_ref())?,
        None => {
            let net = shipped::load_default()?;
            if let Some(c) = &config {
                anyhow::ensure!(
                    net.config().same_shape(c),
                    "the shipped model is {}, not {} (pass --model)",
                    net.config().summary(),
                    c.summary()
                );
            }
            net
        }
    })
}

/// Most surface samples added to a mesh's vertices (the density drops beyond it).
const MAX_SURFACE_SAMPLES: f32 = 4_000_000.0;

/// Class of every vertex of `mesh` (in the network's z-up frame): the vertices and, for a
/// mesh, dense samples of its surface are voxelised together, and each vertex takes the class
/// of its voxel (after `options`' test-time augmentation and structure). Also returns what the
/// structure step found and the seconds of the network calls and of the structure step.
pub fn label_vertices(
    net: &mut Segmenter,
    mesh: &LabeledMesh,
    options: &StructureArgs,
    label_set: LabelSet,
) -> anyhow::Result<(Vec<u8>, Refinement, f64, f64)> {
    let n = mesh.positions.len();
    if n == 0 {
        return Ok((Vec::new(), Refinement::default(), 0.0, 0.0));
    }
    let mut points: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let mut colors = mesh.colors.clone();
    if !mesh.triangles.is_empty() {
        let voxel = net.config().voxel_size;
        let area = mesh.surface_area();
        let density = points_per_m2(voxel).min(MAX_SURFACE_SAMPLES / area.max(1e-6));
        let samples = sample_surface(mesh, density, 0);
        points.extend(samples.positions.iter().map(|p| p.to_array()));
        colors.extend_from_slice(&samples.colors);
    }
    let t = Instant::now();
    let (mut scores, home_head) = match label_set {
        LabelSet::S3dis => (net.segment_points_scores(&points, &colors)?, None),
        LabelSet::Home => {
            let head = net.home_head().cloned().with_context(|| {
                format!("--labels home: the model ({}) has no home head (the shipped model has one)", net.config().name)
            })?;
            (net.segment_points_with_features(&points, &colors)?, Some(head))
        }
    };
    let first_s = t.elapsed().as_secs_f64();
    let logits = if home_head.is_some() { scores.logits.clone() } else { std::mem::take(&mut scores.logits) };
    let (refinement, network_s, structure_s) =
        voxel_labels(net, &scores.coords, &scores.features, Some(logits), options)?;
    let network_s = first_s + network_s;
    let per_vertex =
        |voxel: &[u8]| -> Vec<u8> { scores.point_to_voxel[..n].iter().map(|&r| voxel[r as usize]).collect() };
    let (labels, structure_s) = match home_head {
        None => (per_vertex(&refinement.labels), structure_s),
        Some(head) => {
            let t = Instant::now();
            let (k, voxel) = (net.config().classes, net.config().voxel_size);
            let segment = (!refinement.segment.is_empty()).then_some(refinement.segment.as_slice());
            let home = semrecon_net::home_head::label_voxels(&head, &scores, &refinement.labels, segment, k, voxel)?;
            (per_vertex(&home), structure_s + t.elapsed().as_secs_f64())
        }
    };
    Ok((labels, refinement, network_s, structure_s))
}

/// Runs the command.
pub fn run(args: SegmentArgs) -> anyhow::Result<()> {
    let mut net = load_model(args.model.as_deref(), args.config.as_deref())?;
    net.set_device(args.device.network_device()?);
    let t_read = Instant::now();
    let mut ply = PlyFile::read(&args.input)?;
    let vertex = ply
        .element_mut("vertex")
        .with_context(|| format!("{}: the PLY file has no 'vertex' element", args.input.display()))?;
    // The old label (whatever its type) is replaced; take it out so that reading the
    // geometry does not judge it, and put the new one at its place.
    let label_at = vertex.properties.iter().position(|p| p.name == "label");
    if let Some(i) = label_at {
        vertex.properties.remove(i);
    }
    let has_color = ["red", "diffuse_red"].iter().any(|n| vertex.scalar(n).is_some());
    let mut mesh = mesh_from_ply(&ply, &args.input)?;
    let read_s = t_read.elapsed().as_secs_f64();
    if !has_color && !mesh.positions.is_empty() {
        eprintln!(
            "warning: {} has no red/green/blue vertex colours: the network sees uniform grey, labels will be poor",
            args.input.display()
        );
    }
    let up = match args.up {
        Some(up) => up,
        None => match semrecon_data::MeshGravity::of(&ply, &args.input)? {
            Some(g) => {
                println!("up: {} (recorded in {})", Up::Direction(g.up), args.input.display());
                Up::Direction(g.up)
            }
            None => Up::Axis(UpAxis::Z),
        },
    };
    for p in &mut mesh.positions {
        *p = up.to_z_up(*p);
    }
    let t = Instant::now();
    let (labels, refinement, network_s, structure_s) = label_vertices(&mut net, &mesh, &args.structure, args.labels)
        .with_context(|| format!("segmenting {} with {}", args.input.display(), net.config().summary()))?;
    let segment_s = t.elapsed().as_secs_f64();

    let vertex = ply
        .element_mut("vertex")
        .with_context(|| format!("{}: the PLY file has no 'vertex' element", args.input.display()))?;
    let property = Property { name: "label".into(), data: PropertyData::Scalar(Column::UChar(labels.clone())) };
    match label_at {
        Some(i) => vertex.properties.insert(i, property),
        None => vertex.set_property(property).map_err(|m| anyhow::anyhow!("{}: {m}", args.input.display()))?,
    }
    let encoding = if ply.format == PlyFormat::Ascii { PlyEncoding::Ascii } else { PlyEncoding::BinaryLittleEndian };
    ply.write(&args.out, encoding)?;

    let names: Vec<&str> = (0..args.labels.count() as u8).filter_map(|l| args.labels.class_name(l)).collect();
    let mut counts = vec![0usize; names.len()];
    for &l in &labels {
        if let Some(c) = counts.get_mut(l as usize) {
            *c += 1;
        }
    }
    let voxels = net.level_stats().first().map_or(0, |s| s.voxels);
    println!(
        "labelled {} vertices ({} voxels of {} m, model {}) in {:.0} ms (reading {:.0} ms); wrote {}",
        labels.len(),
        voxels,
        net.config().voxel_size,
        net.config().name,
        segment_s * 1e3,
        read_s * 1e3,
        args.out.display()
    );
    let summary: Vec<String> = names
        .iter()
        .zip(counts)
        .filter(|(_, n)| *n > 0)
        .map(|(c, n)| format!("{c} {:.1}%", 100.0 * n as f64 / labels.len().max(1) as f64))
        .collect();
    if !summary.is_empty() {
        println!("classes: {}", summary.join(", "));
    }
    let opts = &args.structure;
    let height = |z: Option<f32>| z.map_or_else(|| "none".to_string(), |z| format!("{z:.2} m"));
    println!(
        "network {:.0} ms (tta {} {}), structure {} {:.0} ms: {} segments, floor {}, ceiling {}, {} voxels changed ({} as beam faces)",
        network_s * 1e3,
        opts.tta,
        opts.tta_mean,
        opts.structure,
        structure_s * 1e3,
        refinement.segments,
        height(refinement.floor_z),
        height(refinement.ceiling_z),
        refinement.changed,
        refinement.beam_face_voxels
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn up_axes_rotate_onto_z_without_mirroring() {
        let cases =
            [("x", Vec3::X), ("y", Vec3::Y), ("z", Vec3::Z), ("-x", -Vec3::X), ("-y", -Vec3::Y), ("-Z", -Vec3::Z)];
        for (name, up) in cases {
            let axis = parse_up(name).unwrap_or(Up::Axis(UpAxis::Z));
            assert!(axis.to_z_up(up).abs_diff_eq(Vec3::Z, 0.0), "{name}");
            // A rotation: the images of x, y, z form a right-handed frame.
            let (x, y, z) = (axis.to_z_up(Vec3::X), axis.to_z_up(Vec3::Y), axis.to_z_up(Vec3::Z));
            assert!(x.cross(y).abs_diff_eq(z, 0.0), "{name}");
        }
        assert!(parse_up("w").is_err());
    }

    #[test]
    fn an_up_direction_turns_onto_z_without_mirroring() {
        // 7-Scenes' gravity frame: up about 25 degrees off -y.
        let up = Vec3::new(0.008874604, -0.9044256, -0.42653918).normalize();
        let turn = parse_up("0.008874604,-0.9044256,-0.42653918").expect("a direction");
        assert!(turn.to_z_up(up).abs_diff_eq(Vec3::Z, 1e-6));
        let (x, y, z) = (turn.to_z_up(Vec3::X), turn.to_z_up(Vec3::Y), turn.to_z_up(Vec3::Z));
        assert!(x.cross(y).abs_diff_eq(z, 1e-6));
        // A direction along an axis is that axis' turn up to a yaw; z itself is no turn.
        assert_eq!(parse_up("0,0,2").expect("a direction").to_z_up(Vec3::new(1.0, 2.0, 3.0)), Vec3::new(1.0, 2.0, 3.0));
        for bad in ["0,0,0", "1,2", "a,b,c", "1,nan,0"] {
            assert!(parse_up(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn tta_takes_one_two_four_or_eight_views() {
        for n in [1, 2, 4, 8] {
            assert_eq!(parse_tta(&n.to_string()), Ok(n));
        }
        for bad in ["0", "3", "5", "16", "-1", "four"] {
            let e = parse_tta(bad).expect_err("rejected");
            assert!(e.contains("1, 2, 4 or 8"), "{bad}: {e}");
        }
        assert_eq!(parse_tta_mean("logits"), Ok(TtaMean::Logits));
        assert!(parse_tta_mean("max").is_err());
    }
}
