//! The rasteriser against two references: a slow per-pixel ray caster written here (small
//! random scenes) and the depth images of the Replica dataset, rendered by someone else's
//! renderer from the same mesh and poses.

use std::path::{Path, PathBuf};

use glam::{Affine3A, Mat3, Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::{read_ply, Intrinsics, LabeledMesh, PreparedMesh, RenderOutput, Renderer, ScanPlan, SensorModel};

const Z_NEAR: f32 = 0.05;

/// Per-pixel nearest hit (Moller-Trumbore in f64) of the camera-frame mesh: depth and
/// label, keeping only hits at z >= `Z_NEAR` (what near-plane clipping leaves) and the
/// lowest triangle index on ties.
fn ray_cast(mesh: &LabeledMesh, k: &Intrinsics, world_from_camera: Affine3A) -> (Vec<f64>, Vec<u8>, Vec<[f64; 3]>) {
    let camera_from_world = world_from_camera.inverse();
    let p: Vec<[f64; 3]> = mesh
        .positions
        .iter()
        .map(|&q| {
            let c = camera_from_world.transform_point3(q);
            [c.x as f64, c.y as f64, c.z as f64]
        })
        .collect();
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross =
        |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let n = k.pixel_count();
    let mut depth = vec![0.0; n];
    let mut labels = vec![255u8; n];
    let mut colors = vec![[0.0; 3]; n];
    for v in 0..k.height {
        for u in 0..k.width {
            let d = [(u as f64 - k.cx as f64) / k.fx as f64, (v as f64 - k.cy as f64) / k.fy as f64, 1.0];
            let mut best = f64::INFINITY;
            let mut label = 255;
            let mut color = [0.0; 3];
            for (t, tri) in mesh.triangles.iter().enumerate() {
                let [a, b, c] = tri.map(|i| p[i as usize]);
                let e1 = sub(b, a);
                let e2 = sub(c, a);
                let h = cross(d, e2);
                let det = dot(e1, h);
                if det.abs() < 1e-15 {
                    continue;
                }
                let s = sub([0.0; 3], a);
                let bu = dot(s, h) / det;
                let q = cross(s, e1);
                let bv = dot(d, q) / det;
                if bu < 0.0 || bv < 0.0 || bu + bv > 1.0 {
                    continue;
                }
                let z = dot(e2, q) / det; // ray parameter = z, as d.z = 1
                if z >= Z_NEAR as f64 && z < best {
                    best = z;
                    label = mesh.triangle_labels[t];
                    let [c0, c1, c2] = tri.map(|i| mesh.colors[i as usize]);
                    color =
                        [0, 1, 2].map(|ch| (1.0 - bu - bv) * c0[ch] as f64 + bu * c1[ch] as f64 + bv * c2[ch] as f64);
                }
            }
            let i = (v * k.width + u) as usize;
            if best.is_finite() {
                depth[i] = best;
                labels[i] = label;
                colors[i] = color;
            }
        }
    }
    (depth, labels, colors)
}

/// Fraction of pixels where both agree (both empty, or depths within 1e-4 relative), and
/// the fraction of those hits whose labels agree and whose colours are within 1.5 levels.
fn agreement(out: &RenderOutput, depth: &[f64], labels: &[u8], colors: &[[f64; 3]]) -> (f64, f64) {
    let mut agree = 0usize;
    let mut hits = 0usize;
    let mut same_label = 0usize;
    for i in 0..depth.len() {
        let (a, b) = (out.depth[i] as f64, depth[i]);
        if a == 0.0 && b == 0.0 {
            agree += 1;
        } else if a > 0.0 && b > 0.0 && (a - b).abs() <= 1e-4 * b {
            agree += 1;
            hits += 1;
            let color_ok = (0..3).all(|ch| (out.color[i][ch] as f64 - colors[i][ch]).abs() <= 1.5);
            same_label += usize::from(out.labels[i] == labels[i] && color_ok);
        }
    }
    (agree as f64 / depth.len() as f64, same_label as f64 / hits.max(1) as f64)
}

fn random_scene(rng: &mut ChaCha8Rng, n: usize) -> LabeledMesh {
    let mut mesh = LabeledMesh::default();
    for t in 0..n {
        let centre = Vec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(-1.0..4.0));
        for _ in 0..3 {
            let off = Vec3::new(rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5));
            mesh.positions.push(centre + off);
            mesh.colors.push([rng.random(), rng.random(), rng.random()]);
        }
        let b = 3 * t as u32;
        mesh.triangles.push([b, b + 1, b + 2]);
        mesh.triangle_labels.push((t % 200) as u8);
    }
    mesh
}

fn random_pose(rng: &mut ChaCha8Rng) -> Affine3A {
    let axis = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
        .normalize_or(Vec3::Z);
    let angle = rng.random_range(-0.4..0.4);
    let t = Vec3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), rng.random_range(-0.5..0.5));
    Affine3A::from_mat3_translation(Mat3::from_axis_angle(axis, angle), t)
}

#[test]
fn rasteriser_matches_a_ray_caster_on_random_scenes() {
    let k = Intrinsics::new(64, 48, 50.0, 52.0, 31.7, 23.2).expect("valid");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut renderer = Renderer::new(k).expect("renderer");
    for scene in 0..8 {
        let mesh = random_scene(&mut rng, 30);
        let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
        let pose = random_pose(&mut rng);
        let out = renderer.render(&prepared, pose);
        let (depth, labels, colors) = ray_cast(&mesh, &k, pose);
        let (agree, label_agree) = agreement(out, &depth, &labels, &colors);
        println!("scene {scene}: {:.2}% pixels agree, labels+colours {:.2}%", 100.0 * agree, 100.0 * label_agree);
        assert!(agree >= 0.99, "scene {scene}: only {:.2}% of pixels agree", 100.0 * agree);
        assert!(label_agree >= 0.995, "scene {scene}: labels and colours agree on {:.2}% of hits", 100.0 * label_agree);
    }
}

#[test]
fn a_finely_tessellated_wall_is_watertight() {
    // 120 x 120 quads with alternating diagonals, seen at a slant: shared edges must leave
    // no pixel uncovered (fill rule and exact fixed-point edges).
    let n = 120u32;
    let mut mesh = LabeledMesh::default();
    for j in 0..=n {
        for i in 0..=n {
            mesh.positions.push(Vec3::new(-8.0 + 16.0 * i as f32 / n as f32, -6.0 + 12.0 * j as f32 / n as f32, 3.0));
            mesh.colors.push([128; 3]);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            if (i + j) % 2 == 0 {
                mesh.triangles.extend([[a, b, d], [a, d, c]]);
            } else {
                mesh.triangles.extend([[a, b, c], [b, d, c]]);
            }
            mesh.triangle_labels.extend([2, 2]);
        }
    }
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let k = Intrinsics::new(320, 240, 260.0, 260.0, 159.3, 119.7).expect("valid");
    let mut renderer = Renderer::new(k).expect("renderer");
    let pose = Affine3A::from_mat3_translation(
        Mat3::from_rotation_y(0.4) * Mat3::from_rotation_x(-0.2),
        Vec3::new(0.3, 0.1, 0.0),
    );
    let out = renderer.render(&prepared, pose);
    let holes = out.depth.iter().filter(|&&d| d == 0.0).count();
    assert_eq!(holes, 0, "{holes} pixels not covered");
    // The wall is the plane z = 3: depth along the optical axis is where the pixel ray meets it.
    let mut close = 0;
    for v in 0..k.height {
        for u in 0..k.width {
            let d = pose.transform_vector3(k.unproject(u as f32, v as f32, 1.0));
            let z = (3.0 - pose.translation.z) / d.z;
            close += usize::from((out.depth[(v * k.width + u) as usize] - z).abs() <= 1e-4 * z);
        }
    }
    assert!(close as f64 >= 0.999 * k.pixel_count() as f64, "{close} of {} depths agree", k.pixel_count());
}

#[test]
fn triangles_crossing_the_near_plane_are_clipped_not_dropped() {
    let k = Intrinsics::new(64, 48, 40.0, 40.0, 31.5, 23.5).expect("valid");
    // A floor 1 m below the camera reaching behind it, and a wall whose corner pokes through
    // the near plane: the part nearer than z_near must vanish and show the floor behind.
    let mesh = LabeledMesh {
        positions: vec![
            Vec3::new(-10.0, 1.0, -5.0),
            Vec3::new(10.0, 1.0, -5.0),
            Vec3::new(0.0, 1.0, 30.0),
            Vec3::new(-0.3, -2.0, 0.01),
            Vec3::new(-0.3, 0.5, 0.01),
            Vec3::new(1.5, -0.5, 3.0),
        ],
        colors: vec![[100; 3]; 6],
        triangles: vec![[0, 1, 2], [3, 4, 5]],
        triangle_labels: vec![1, 2],
        ..Default::default()
    };
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let mut renderer = Renderer::new(k).expect("renderer").with_near(Z_NEAR).expect("valid near");
    let out = renderer.render(&prepared, Affine3A::IDENTITY);
    let (depth, labels, colors) = ray_cast(&mesh, &k, Affine3A::IDENTITY);
    let (agree, label_agree) = agreement(out, &depth, &labels, &colors);
    assert!(agree >= 0.99 && label_agree >= 0.995, "agree {agree}, labels {label_agree}");
    let floor = out.labels.iter().filter(|&&l| l == 1).count();
    let wall = out.labels.iter().filter(|&&l| l == 2).count();
    assert!(floor > 300 && wall > 300, "floor {floor} and wall {wall} pixels");
    // Floor depth is 1 / y' exactly.
    for v in 30..48u32 {
        let i = (v * 64 + 40) as usize;
        if out.labels[i] == 1 {
            let z = 1.0 / ((v as f32 - 23.5) / 40.0);
            assert!((out.depth[i] - z).abs() < 1e-4 * z, "row {v}: {} vs {z}", out.depth[i]);
        }
    }
}

#[test]
fn huge_triangles_beyond_the_guard_band_are_clipped_exactly() {
    let k = Intrinsics::new(48, 40, 40.0, 40.0, 23.5, 19.5).expect("valid");
    // Vertices that project tens of thousands of pixels off-screen, and one behind the
    // camera: the fixed-point rasteriser must clip them in the camera frame first.
    let mesh = LabeledMesh {
        positions: vec![
            Vec3::new(-500.0, 1.0, 0.06),
            Vec3::new(400.0, 1.2, 0.07),
            Vec3::new(0.0, 0.2, 50.0),
            Vec3::new(-3.0, -900.0, 0.055),
            Vec3::new(2.0, -0.5, 3.0),
            Vec3::new(1.0, 0.3, -1.0),
        ],
        colors: vec![[10, 200, 30]; 6],
        triangles: vec![[0, 1, 2], [3, 4, 5]],
        triangle_labels: vec![1, 2],
        ..Default::default()
    };
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // Also with the principal point far outside the image (a crop of a larger sensor).
    let shifted = Intrinsics::new(48, 40, 40.0, 40.0, -2000.0, 3000.0).expect("valid");
    for k in [k, shifted] {
        let mut renderer = Renderer::new(k).expect("renderer");
        // Turn the image centre's ray towards a point inside the first triangle.
        let centre_ray = k.unproject(24.0, 20.0, 1.0).normalize();
        let target = Vec3::new(-30.0, 0.74, 20.04).normalize();
        let aim = Affine3A::from_quat(Quat::from_rotation_arc(centre_ray, target));
        for _ in 0..4 {
            // The shifted camera sees a sliver of about a degree: only move it, then.
            let wobble = random_pose(&mut rng);
            let wobble = if k.cx < 0.0 { Affine3A::from_translation(wobble.translation.into()) } else { wobble };
            let pose = wobble * aim;
            let out = renderer.render(&prepared, pose);
            let (depth, labels, colors) = ray_cast(&mesh, &k, pose);
            let (agree, label_agree) = agreement(out, &depth, &labels, &colors);
            assert!(agree >= 0.99 && label_agree >= 0.995, "agree {agree}, labels {label_agree}");
            assert!(out.depth.iter().filter(|&&d| d > 0.0).count() > 300, "too little seen");
        }
    }
}

#[test]
fn output_is_identical_for_any_thread_count() {
    let k = Intrinsics::new(320, 240, 250.0, 250.0, 159.5, 119.5).expect("valid");
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mesh = random_scene(&mut rng, 3000);
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let pose = random_pose(&mut rng);
    let render_with = |threads: usize| -> RenderOutput {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        pool.install(|| Renderer::new(k).expect("renderer").render(&prepared, pose).clone())
    };
    let one = render_with(1);
    let two = render_with(2);
    let three = render_with(3);
    assert!(one.depth.iter().filter(|&&d| d > 0.0).count() > 1000);
    assert!(one == two && one == three, "outputs differ between thread counts");
}

fn shared_data() -> Option<PathBuf> {
    semrecon_data::shared_data::shared_data_path("")
}

fn read_traj(path: &Path, n: usize) -> Vec<Affine3A> {
    let text = std::fs::read_to_string(path).expect("read traj");
    text.lines()
        .take(n)
        .map(|line| {
            let m: Vec<f32> = line.split_whitespace().map(|v| v.parse().expect("float")).collect();
            assert_eq!(m.len(), 16);
            // Row-major camera-to-world.
            Affine3A::from_cols_array(&[m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10], m[3], m[7], m[11]])
        })
        .collect()
}

#[test]
fn replica_office0_depth_matches_the_dataset_renderer() {
    let Some(data) = shared_data() else { return };
    let dir = data.join("replica-office0");
    let mesh = read_ply(dir.join("office0_mesh.ply")).expect("office0 mesh");
    assert_eq!((mesh.positions.len(), mesh.triangles.len()), (25_149, 50_000));
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let k = Intrinsics::new(1200, 680, 600.0, 600.0, 599.5, 339.5).expect("valid");
    let mut renderer = Renderer::new(k).expect("renderer");
    for (i, pose) in read_traj(&dir.join("office0/traj.txt"), 4).into_iter().enumerate() {
        let png = dir.join(format!("office0/results/depth{i:06}.png"));
        let reference = image::open(&png).expect("depth png").into_luma16();
        assert_eq!(reference.dimensions(), (1200, 680));
        let out = renderer.render(&prepared, pose);
        let mut diffs = Vec::new();
        let mut valid_ref = 0usize;
        for (j, r) in reference.as_raw().iter().enumerate() {
            let zr = *r as f32 / 6553.5;
            valid_ref += usize::from(*r > 0);
            if *r > 0 && out.depth[j] > 0.0 {
                diffs.push((out.depth[j] - zr).abs());
            }
        }
        diffs.sort_by(f32::total_cmp);
        let median = diffs.get(diffs.len() / 2).copied().unwrap_or(f32::INFINITY);
        let both = diffs.len() as f64 / out.depth.len() as f64;
        let within_1cm = diffs.iter().filter(|&&d| d < 0.01).count() as f64 / diffs.len().max(1) as f64;
        println!(
            "replica frame {i}: valid in both {:.1}% (reference {:.1}%), median |diff| {:.2} mm, {:.1}% within 1 cm",
            100.0 * both,
            100.0 * valid_ref as f64 / out.depth.len() as f64,
            1000.0 * median,
            100.0 * within_1cm
        );
        assert!(both > 0.5, "frame {i}: only {:.1}% valid in both", 100.0 * both);
        assert!(median <= 0.005, "frame {i}: median difference {median} m");
    }
}

#[test]
fn replica_office0_scan_plan_renders_plausible_frames() {
    let Some(data) = shared_data() else { return };
    let mesh = read_ply(data.join("replica-office0/office0_mesh.ply")).expect("office0 mesh");
    let prepared = PreparedMesh::new(&mesh).expect("valid mesh");
    let plan = ScanPlan::from_mesh_bounds(&mesh, 0).expect("plan");
    let poses = plan.poses(300).expect("poses");
    let k = Intrinsics::new(160, 120, 131.25, 131.25, 79.5, 59.5).expect("valid");
    let mut renderer = Renderer::new(k).expect("renderer");
    let sensor = SensorModel::kinect();
    let mut valid = 0.0;
    for (i, pose) in poses.iter().enumerate().step_by(10) {
        let mut out = renderer.render(&prepared, *pose).clone();
        let seen = out.depth.iter().filter(|&&d| d > 0.0).count() as f64 / out.depth.len() as f64;
        let mut sorted: Vec<f32> = out.depth.iter().copied().filter(|&d| d > 0.0).collect();
        sorted.sort_by(f32::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        assert!(seen > 0.9 && median > 0.5, "frame {i}: {:.0}% seen, median depth {median} m", 100.0 * seen);
        sensor.apply(&mut out, i);
        valid += out.depth.iter().filter(|&&d| d > 0.0).count() as f64 / out.depth.len() as f64;
    }
    let valid = valid / 30.0;
    println!("office0 scan plan: {:.1}% of pixels keep depth after the Kinect model", 100.0 * valid);
    assert!(valid > 0.6 && valid < 0.995, "{valid}");
}
