//! `semrecon snapshot`: renders a mesh or a point cloud to a PNG from a bird's-eye corner
//! view (or any viewpoint), shaded, in its own colours or in class colours — the quickest way
//! to look at what the pipeline made. Meshes go through the same rasteriser as the synthetic
//! data; point clouds (PLY files without faces) are drawn as small oriented discs
//! ([`points`]).

mod points;

use std::path::PathBuf;

use anyhow::{bail, Context};
use glam::{Affine3A, Mat3A, Quat, Vec3};
use semrecon_data::class::UNLABELED;
use semrecon_data::depth_image::write_color_png;
use semrecon_data::{read_ply_with_gravity, Intrinsics, LabelSet, LabeledMesh, PreparedMesh, Renderer};

/// Arguments of `semrecon snapshot`.
#[derive(clap::Args)]
pub struct SnapshotArgs {
    /// Mesh or point cloud to render (PLY; a file without faces is drawn as points).
    mesh: PathBuf,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// Colour by semantic class (the `label` property) instead of vertex colour.
    #[arg(long)]
    classes: bool,
    /// Label set of the `label` property with `--classes`: s3dis, or home (`segment --labels
    /// home`: ScanNet's 20 classes and the ceiling, in ScanNet's colours).
    #[arg(long, default_value = "s3dis", value_parser = crate::commands::segment::parse_label_set)]
    labels: LabelSet,
    /// Drop everything above this height (z, metres) — e.g. the ceiling — to see inside a room.
    #[arg(long, allow_hyphen_values = true)]
    cut_above: Option<f32>,
    /// Camera position x,y,z (default: above a corner of the bounding box, outside it).
    #[arg(long, value_parser = crate::cli_values::parse_vec3, allow_hyphen_values = true)]
    eye: Option<Vec3>,
    /// Point looked at x,y,z (default: the centre of the bounding box's lower half).
    #[arg(long, value_parser = crate::cli_values::parse_vec3, allow_hyphen_values = true)]
    at: Option<Vec3>,
    /// Image width in pixels (height is 3/4 of it).
    #[arg(long, default_value_t = 1024)]
    width: u32,
    /// The scene's up direction x,y,z: the scene is first turned so that it points along +z.
    /// Default: the up direction the file records (meshes of `semrecon run`, `live` and
    /// `demo` do: their map frame is the dataset's or the first camera's), else 0,0,1.
    #[arg(long, value_parser = crate::cli_values::parse_vec3, allow_hyphen_values = true)]
    up: Option<Vec3>,
}

/// `world_from_camera` of a camera at `eye` looking at `at` with world z up (camera x right,
/// y down, z forward).
pub fn look_at(eye: Vec3, at: Vec3) -> anyhow::Result<Affine3A> {
    let forward = (at - eye).normalize_or_zero();
    let right = forward.cross(Vec3::Z).normalize_or_zero();
    if forward == Vec3::ZERO || right == Vec3::ZERO {
        bail!("cannot look from {eye} at {at}: same point, or straight up or down");
    }
    let down = forward.cross(right);
    Ok(Affine3A::from_mat3_translation(Mat3A::from_cols(right.into(), down.into(), forward.into()).into(), eye))
}

/// Runs the command.
pub fn run(args: SnapshotArgs) -> anyhow::Result<()> {
    let (mut mesh, gravity) = read_ply_with_gravity(&args.mesh)?;
    if args.classes {
        let labels = mesh.vertex_labels_or_from_triangles();
        if labels.iter().all(|&l| l == UNLABELED) {
            bail!("{}: the mesh has no `label` property to colour by", args.mesh.display());
        }
        let set = args.labels;
        mesh.colors =
            labels.iter().map(|&l| if (l as usize) < set.count() { set.color(l) } else { [0, 0, 0] }).collect();
        println!("classes (share of vertices): {}", class_shares(&labels, set));
    }
    if let Some(up) = args.up.or(gravity.map(|g| g.up)) {
        let up = up.normalize_or_zero();
        if up == Vec3::ZERO {
            bail!("--up must not be the zero vector");
        }
        let turn = Quat::from_rotation_arc(up, Vec3::Z);
        mesh.positions.iter_mut().for_each(|p| *p = turn * *p);
        mesh.normals.iter_mut().for_each(|n| *n = turn * *n);
    }
    let (lo, hi) = mesh.bounds().with_context(|| format!("{}: the mesh is empty", args.mesh.display()))?;
    let at = args.at.unwrap_or(Vec3::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0, lo.z + (hi.z - lo.z) * 0.25));
    let size = hi - lo;
    let eye = args.eye.unwrap_or_else(|| {
        // From above a corner, the long side across the picture, far enough back that the
        // bounding sphere fits the vertical field of view (half-angle ~22.6 degrees).
        let from = if size.x >= size.y { Vec3::new(-0.3, -1.0, 1.1) } else { Vec3::new(-1.0, -0.3, 1.1) };
        at + from.normalize() * (0.5 * size.length() / 0.384 * 0.9)
    });
    let world_from_camera = look_at(eye, at)?;
    let (w, h) = (args.width.clamp(16, 8192), args.width.clamp(16, 8192) * 3 / 4);
    let k = Intrinsics::new(w, h, w as f32 * 0.9, w as f32 * 0.9, (w as f32 - 1.0) / 2.0, (h as f32 - 1.0) / 2.0)?;

    if mesh.triangles.is_empty() {
        let (radius, normals) = points::point_discs(&mesh);
        let keep = points::visible_points(&mesh, &normals, eye, args.cut_above);
        let drawn = keep.iter().filter(|&&k| k).count();
        if drawn == 0 {
            bail!("{}: nothing left to draw (everything cut away)", args.mesh.display());
        }
        // Framed to what is drawn, unless the camera was placed by hand.
        let k = if args.eye.is_none() && args.at.is_none() {
            points::fit_to_points(&mesh, &keep, world_from_camera, k, 0.92)
        } else {
            k
        };
        let pixels = points::render_points(&mesh, &radius, &normals, &keep, world_from_camera, k);
        write_color_png(&args.out, w, h, &pixels)?;
        println!("wrote {} ({w}x{h}, {drawn} points drawn)", args.out.display());
        return Ok(());
    }

    keep_visible_side(&mut mesh, eye, args.cut_above);
    if mesh.triangles.is_empty() {
        bail!("{}: nothing left to draw (everything cut away or facing away)", args.mesh.display());
    }
    let mut renderer = Renderer::new(k)?;
    let out = renderer.render(&PreparedMesh::new(&mesh)?, world_from_camera);
    let pixels: Vec<[u8; 3]> = (0..out.depth.len())
        .map(|i| {
            if out.depth[i] > 0.0 {
                // Headlight shading keeps shapes readable where colours are flat.
                let shade = 0.35 + 0.65 * out.incidence[i];
                out.color[i].map(|c| (c as f32 * shade).round() as u8)
            } else {
                [255, 255, 255]
            }
        })
        .collect();
    write_color_png(&args.out, w, h, &pixels)?;
    println!("wrote {} ({w}x{h}, {} triangles drawn)", args.out.display(), mesh.triangle_count());
    Ok(())
}

/// `name share%` of every class present, largest first, then the unlabelled share.
fn class_shares(labels: &[u8], set: LabelSet) -> String {
    let mut counts = [0usize; 256];
    for &l in labels {
        counts[l as usize] += 1;
    }
    let total = labels.len().max(1) as f64;
    let mut present: Vec<(usize, u8, &str)> = (0..set.count() as u8)
        .filter_map(|l| set.class_name(l).map(|name| (counts[l as usize], l, name)))
        .filter(|(n, _, _)| *n > 0)
        .collect();
    present.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut parts: Vec<String> =
        present.iter().map(|(n, _, name)| format!("{name} {:.1}%", 100.0 * *n as f64 / total)).collect();
    let other = labels.len() - present.iter().map(|(n, _, _)| n).sum::<usize>();
    if other > 0 {
        parts.push(format!("unlabelled {:.1}%", 100.0 * other as f64 / total));
    }
    parts.join(", ")
}

/// Drops triangles above `cut_above` and those whose front (vertex normals, else the
/// counter-clockwise side) faces away from `eye`: the walls nearest the camera then vanish and the room opens up like a
/// doll's house. Meshes with inconsistent winding lose some faces; that is acceptable for a
/// preview.
fn keep_visible_side(mesh: &mut LabeledMesh, eye: Vec3, cut_above: Option<f32>) {
    let keep: Vec<bool> = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let above = cut_above.is_some_and(|z| a.z.max(b.z).max(c.z) > z);
            // Smooth vertex normals where the mesh has them: face normals of a noisy scan flip
            // at random and would punch holes into the picture.
            let normal = if mesh.normals.is_empty() {
                (b - a).cross(c - a)
            } else {
                t.iter().map(|&i| mesh.normals[i as usize]).sum::<Vec3>()
            };
            let facing = normal.dot(eye - a) > 0.0;
            !above && facing
        })
        .collect();
    let mut i = 0;
    mesh.triangles.retain(|_| {
        i += 1;
        keep[i - 1]
    });
    if !mesh.triangle_labels.is_empty() {
        let mut i = 0;
        mesh.triangle_labels.retain(|_| {
            i += 1;
            keep[i - 1]
        });
    }
}
