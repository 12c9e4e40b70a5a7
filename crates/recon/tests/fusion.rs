//! Hashed fusion against a plain dense-grid TSDF, determinism over thread counts, and bad
//! frames.

#[path = "common/scene.rs"]
mod scene;

use glam::{Affine3A, IVec3, Vec3};
use semrecon_data::{Frame, Intrinsics};
use semrecon_recon::map::{TSDF_SCALE, WEIGHT_SCALE};
use semrecon_recon::{depth_weight, extract_mesh, IncrementalMesher, TsdfConfig, TsdfMap};

fn small_camera() -> Intrinsics {
    Intrinsics::new(160, 120, 140.0, 140.0, 79.5, 59.5).expect("valid camera")
}

/// The obviously-correct reference: every voxel of a dense box, projected into every frame.
struct DenseTsdf {
    min: IVec3,
    dims: IVec3,
    tsdf: Vec<f32>,
    weight: Vec<f32>,
}

impl DenseTsdf {
    fn new(min: IVec3, max: IVec3) -> Self {
        let dims = max - min + IVec3::ONE;
        let n = (dims.x * dims.y * dims.z) as usize;
        Self { min, dims, tsdf: vec![0.0; n], weight: vec![0.0; n] }
    }

    fn index(&self, v: IVec3) -> Option<usize> {
        let l = v - self.min;
        if l.cmplt(IVec3::ZERO).any() || l.cmpge(self.dims).any() {
            return None;
        }
        Some((l.x + self.dims.x * (l.y + self.dims.y * l.z)) as usize)
    }

    /// Fuses the frame into the voxels that `fuse_here` accepts; returns every voxel (accepted
    /// or not) within the frame's truncation band.
    fn integrate(
        &mut self,
        c: &TsdfConfig,
        frame: &Frame,
        world_from_camera: Affine3A,
        fuse_here: impl Fn(IVec3) -> bool,
    ) -> Vec<IVec3> {
        let mut band = Vec::new();
        let k = frame.intrinsics;
        let camera_from_world = world_from_camera.inverse();
        let trunc = c.voxel_size * c.truncation_voxels;
        for z in 0..self.dims.z {
            for y in 0..self.dims.y {
                for x in 0..self.dims.x {
                    let v = self.min + IVec3::new(x, y, z);
                    let p = camera_from_world.transform_point3(v.as_vec3() * c.voxel_size);
                    if p.z <= 0.0 {
                        continue;
                    }
                    let uv = k.project(p);
                    let (u, vv) = (uv.x.round(), uv.y.round());
                    if u < 0.0 || vv < 0.0 || u >= k.width as f32 || vv >= k.height as f32 {
                        continue;
                    }
                    let d = frame.depth[vv as usize * k.width as usize + u as usize];
                    if !(d >= c.min_depth && d <= c.max_depth) {
                        continue;
                    }
                    let sdf = d - p.z;
                    // The band of this observation (the full truncation unless depth-dependent).
                    let mu = c.band(d);
                    // Up to `behind_band` bands behind, clamped to one band behind.
                    if sdf < -mu * c.behind_band {
                        continue;
                    }
                    // The band itself (what chunk selection must allocate) is one band each side.
                    if sdf < mu && sdf >= -mu {
                        band.push(v);
                    }
                    if !fuse_here(v) {
                        continue;
                    }
                    let i = self.index(v).expect("inside");
                    let w = depth_weight(d);
                    let t = (sdf / trunc).min(mu / trunc).max(-mu / trunc);
                    // Stored as the map stores them: the distance in steps of 1 / TSDF_SCALE,
                    // the weight in steps of 1 / WEIGHT_SCALE (at least one step, capped).
                    let mean = (self.tsdf[i] * self.weight[i] + t * w) / (self.weight[i] + w);
                    self.tsdf[i] = (mean * TSDF_SCALE).round() / TSDF_SCALE;
                    let w_q = ((self.weight[i] + w) * WEIGHT_SCALE).round().max(1.0);
                    self.weight[i] = w_q.min((c.max_weight * WEIGHT_SCALE).round()) / WEIGHT_SCALE;
                }
            }
        }
        band
    }
}

/// Fuses the same frames into the hashed map and the dense reference. The reference fuses
/// the voxels of the chunks the map kept for each frame (chunks outside the band are by
/// design never visited); that every voxel in the band is kept is checked per frame, and
/// the number of band voxels not allocated is returned with the total.
fn fuse_both(config: TsdfConfig, frames: usize) -> (TsdfMap, DenseTsdf, usize, usize) {
    let k = small_camera();
    let mut map = TsdfMap::new(config).expect("valid config");
    let vs = config.voxel_size;
    let lo = (Vec3::new(-3.0, -0.5, -0.5) / vs).floor().as_ivec3();
    let hi = (Vec3::new(3.0, 2.5, 3.0) / vs).ceil().as_ivec3();
    let mut dense = DenseTsdf::new(lo, hi);
    let (mut band_total, mut missing) = (0, 0);
    for (i, pose) in scene::trajectory(frames).into_iter().enumerate() {
        let frame = scene::render(k, pose, i);
        map.integrate(&frame, pose).expect("fusion");
        let kept: std::collections::HashSet<IVec3> = map.chunks_touched_by(i as u32).into_iter().collect();
        let band = dense.integrate(&config, &frame, pose, |v| kept.contains(&v.div_euclid(IVec3::splat(8))));
        band_total += band.len();
        missing += band.iter().filter(|v| map.voxel(**v).is_none()).count();
    }
    (map, dense, band_total, missing)
}

#[test]
fn hashed_fusion_matches_a_dense_reference() {
    let fixed = TsdfConfig { voxel_size: 0.02, ..TsdfConfig::default() };
    check_against_dense_reference(fixed);
}

/// A band from 1 voxel near to 8 far: selection must still cover every voxel of each
/// pixel's band, and integration must clip each observation to its own band.
#[test]
fn depth_dependent_band_matches_a_dense_reference() {
    let config = TsdfConfig {
        voxel_size: 0.02,
        truncation_voxels: 8.0,
        min_truncation_voxels: 1.0,
        truncation_noise_factor: 6.0,
        ..TsdfConfig::default()
    };
    let (near, far) = (config.band(1.0) / config.voxel_size, config.band(4.0) / config.voxel_size);
    assert!(near == 1.0 && far > 7.0 && far <= 8.0, "band {near} .. {far} voxels");
    check_against_dense_reference(config);
    // Observations up to 1.5 bands behind clamped to one band behind.
    check_against_dense_reference(TsdfConfig { behind_band: 1.5, ..config });
}

fn check_against_dense_reference(base: TsdfConfig) {
    for stride in [1, 2] {
        let config = TsdfConfig { selection_stride: stride, ..base };
        let (map, dense, band, missing) = fuse_both(config, 3);
        assert!(map.chunk_count() > 50, "{} chunks", map.chunk_count());
        // Every allocated voxel agrees with the reference.
        let (mut compared, mut off, mut max_err) = (0, 0, 0.0f32);
        for chunk in map.chunks() {
            for (i, vox) in chunk.voxels().enumerate() {
                let local = IVec3::new((i % 8) as i32, ((i / 8) % 8) as i32, (i / 64) as i32);
                let v = chunk.key() * 8 + local;
                let j = dense.index(v).expect("allocated voxel inside the reference box");
                // The same steps; a sum on the edge of a step may round the other way.
                assert!((vox.weight() - dense.weight[j]).abs() <= 1.0 / WEIGHT_SCALE, "weight at {v}");
                if dense.weight[j] > 0.0 {
                    let e = (vox.tsdf() - dense.tsdf[j]).abs();
                    max_err = max_err.max(e);
                    off += (e > 1e-3) as usize;
                    compared += 1;
                }
            }
        }
        println!("stride {stride}: {compared} voxels compared, {off} differ by more than 1e-3, max {max_err}");
        assert!(compared > 10_000, "{compared} voxels compared");
        // The map steps voxel centres incrementally, the reference transforms each one, so a
        // centre that projects within float rounding of a pixel border may read the
        // neighbouring pixel: a handful of voxels may differ by a fraction of the slope.
        assert!(off * 1000 <= compared && max_err < 0.01, "{off} voxels off, max {max_err}");
        println!("stride {stride}: {} chunks, {band} band voxels, {missing} not allocated", map.chunk_count());
        assert!(missing * 1000 <= band, "stride {stride}: {missing} of {band} band voxels not allocated");
        if stride == 1 {
            assert_eq!(missing, 0);
        }
    }
}

#[test]
fn same_bits_for_one_two_and_four_threads() {
    // Twenty frames, past the colour warm-up: colour frames and frames that colour only the
    // voxels still warming up.
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let config = TsdfConfig { voxel_size: 0.01, color_every: 3, ..TsdfConfig::default() };
            let k = small_camera();
            let mut map = TsdfMap::new(config).expect("valid");
            for (i, pose) in scene::trajectory(20).into_iter().enumerate() {
                map.integrate(&scene::render(k, pose, i), pose).expect("fusion");
            }
            let keys = map.sorted_keys();
            let voxels: Vec<Vec<_>> =
                keys.iter().map(|&k| map.chunk(k).expect("allocated").voxels().collect()).collect();
            (keys, voxels, extract_mesh(&map))
        })
    };
    let (k1, v1, m1) = run(1);
    assert!(m1.triangle_count() > 1000);
    for threads in [2, 4] {
        let (k, v, m) = run(threads);
        assert_eq!(k1, k, "{threads} threads");
        assert!(v1 == v, "{threads} threads");
        assert_eq!(m1, m, "{threads} threads");
    }
}

#[test]
fn empty_and_invalid_frames_change_nothing() {
    let k = small_camera();
    let config = TsdfConfig { voxel_size: 0.02, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let pose = scene::trajectory(1)[0];
    map.integrate(&scene::render(k, pose, 0), pose).expect("fusion");
    let before = map.clone();
    let mut mesher = IncrementalMesher::new();
    mesher.update(&map);
    let mesh_before = mesher.mesh();
    for bad in [0.0, f32::NAN, f32::INFINITY, -1.0, 100.0] {
        let mut f = scene::render(k, pose, 1);
        f.depth.iter_mut().for_each(|d| *d = bad);
        let stats = map.integrate(&f, pose).expect("bad depth is skipped, not an error");
        assert_eq!(stats.updated_voxels, 0);
        assert_eq!(stats.visited_chunks, 0);
    }
    // A frame with NaNs sprinkled in behaves like one with those pixels missing.
    assert_eq!(map.sorted_keys(), before.sorted_keys());
    for key in map.sorted_keys() {
        let (a, b) = (map.chunk(key).expect("a"), before.chunk(key).expect("b"));
        assert!(a.voxels().eq(b.voxels()) && a.revision() == b.revision());
    }
    let stats = mesher.update(&map);
    assert_eq!(stats.remeshed_chunks, 0);
    assert_eq!(mesher.mesh(), mesh_before);
    // Buffers that do not match the camera, and non-finite poses, are errors.
    let mut f = scene::render(k, pose, 2);
    f.depth.pop();
    assert!(map.integrate(&f, pose).is_err());
    let f = scene::render(k, pose, 3);
    let mut bad_pose = pose;
    bad_pose.translation.x = f32::NAN;
    assert!(map.integrate(&f, bad_pose).is_err());
    // An empty camera image is fine.
    let empty = Frame { depth: vec![], color: vec![], ..scene::render(k, pose, 4) };
    assert!(map.integrate(&empty, pose).is_err());
}

#[test]
fn nan_pixels_are_skipped() {
    let k = small_camera();
    let config = TsdfConfig { voxel_size: 0.02, ..TsdfConfig::default() };
    let pose = scene::trajectory(1)[0];
    let clean = scene::render(k, pose, 0);
    let mut noisy = clean.clone();
    let mut holed = clean.clone();
    for i in (0..noisy.depth.len()).step_by(7) {
        noisy.depth[i] = f32::NAN;
        holed.depth[i] = 0.0;
    }
    let mut a = TsdfMap::new(config).expect("valid");
    let mut b = TsdfMap::new(config).expect("valid");
    a.integrate(&noisy, pose).expect("fusion");
    b.integrate(&holed, pose).expect("fusion");
    assert_eq!(a.sorted_keys(), b.sorted_keys());
    for key in a.sorted_keys() {
        assert!(a.chunk(key).expect("a").voxels().eq(b.chunk(key).expect("b").voxels()));
    }
}

#[test]
fn incremental_meshing_equals_full_meshing() {
    let k = small_camera();
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let mut mesher = IncrementalMesher::new();
    let poses = scene::trajectory(6);
    for (i, &pose) in poses.iter().enumerate() {
        map.integrate(&scene::render(k, pose, i), pose).expect("fusion");
        if i % 2 == 1 {
            let stats = mesher.update(&map);
            assert!(stats.remeshed_chunks > 0);
            assert_eq!(mesher.mesh(), extract_mesh(&map), "after frame {i}");
        }
    }
    assert_eq!(mesher.remeshed_since(0).count(), mesher.chunk_count());
    // Nothing changed: nothing re-meshed.
    let seen = mesher.generation();
    assert_eq!(mesher.update(&map).remeshed_chunks, 0);
    assert_eq!(mesher.remeshed_since(seen).count(), 0);
    // A frame that sees only part of the scene re-meshes only part of it, and
    // `remeshed_since` names exactly those chunks with their new meshes.
    let close = scene::camera_pose(Vec3::new(0.1, 0.8, 0.6), 0.0);
    map.integrate(&scene::render(k, close, 10), close).expect("fusion");
    let stats = mesher.update(&map);
    assert!(stats.remeshed_chunks < map.chunk_count(), "{stats:?}");
    assert_eq!(mesher.remeshed_since(seen).count(), stats.remeshed_chunks);
    for (key, mesh) in mesher.remeshed_since(seen) {
        assert_eq!(Some(mesh), mesher.chunk_mesh(key));
    }
    let mesh = mesher.mesh();
    assert_eq!(mesh, extract_mesh(&map));
    mesh.validate().expect("valid mesh");
    assert!(!map.chunks_touched_by(10).is_empty());
    assert!(map.chunks_touched_by(99).is_empty());
}

#[path = "common/seven_scenes.rs"]
mod seven_scenes;

#[test]
fn real_kinect_frames_fuse_into_a_plausible_mesh() {
    let Some(dir) = seven_scenes::redkitchen() else {
        println!("skipping: ../shared/data not found");
        return;
    };
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let mut mesher = IncrementalMesher::new();
    for i in 0..5 {
        let (frame, pose) = seven_scenes::read_frame(&dir, i * 5).expect("7-Scenes frame");
        let stats = map.integrate(&frame, pose).expect("fusion");
        assert!(stats.updated_voxels > 100_000, "frame {i}: {stats:?}");
    }
    mesher.update(&map);
    let mesh = mesher.mesh();
    mesh.validate().expect("valid mesh");
    assert!(mesh.triangle_count() > 50_000, "{} triangles", mesh.triangle_count());
    // The kitchen is a few metres across; the Kinect sees at most about 4 m.
    let (lo, hi) = mesh.bounds().expect("non-empty");
    assert!((hi - lo).max_element() < 8.0, "bounds {lo} .. {hi}");
    assert_eq!(mesh, extract_mesh(&map));
}

#[test]
fn memory_follows_the_surface_not_the_frame_count() {
    let k = small_camera();
    let config = TsdfConfig { voxel_size: 0.02, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let poses = scene::trajectory(4);
    let frames: Vec<_> = poses.iter().enumerate().map(|(i, &p)| scene::render(k, p, i)).collect();
    for (f, &p) in frames.iter().zip(&poses) {
        map.integrate(f, p).expect("fusion");
    }
    let (chunks, bytes) = (map.chunk_count(), map.memory_bytes());
    // Revisit the same views 20 more times, as a long scan does: frame indices jump ahead, so
    // every visit starts a new run of frames in every chunk it touches.
    let revisit = |map: &mut TsdfMap, rounds: std::ops::Range<usize>| {
        for round in rounds {
            for (i, (f, &p)) in frames.iter().zip(&poses).enumerate() {
                let mut f = f.clone();
                f.index = round * 100 + i;
                map.integrate(&f, p).expect("fusion");
            }
        }
    };
    revisit(&mut map, 1..21);
    assert_eq!(map.chunk_count(), chunks);
    // Only the frame records (capped per chunk) and the slab's spare capacity (chunks
    // allocated for a frame and freed again) grow.
    let growth = map.memory_bytes() - bytes;
    println!("{chunks} chunks, {bytes} bytes, +{growth} bytes after 80 more frames");
    assert!(growth * 20 < bytes, "{growth} bytes of growth on {bytes}");
    // Once the records are full, revisits cost nothing at all.
    let full = map.memory_bytes();
    revisit(&mut map, 21..41);
    assert_eq!((map.chunk_count(), map.memory_bytes()), (chunks, full));
}

/// Far surfaces fused from groups of frames (`GroupedFusion`): the same bits for any thread
/// count, and on noise-free depth the same surface as fusing every frame whole (the average
/// of three observations of one surface is that surface, up to the warp's interpolation).
#[test]
fn grouped_fusion_is_deterministic_and_keeps_the_surface() {
    let k = small_camera();
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let frames: Vec<(Frame, Affine3A)> =
        scene::trajectory(20).into_iter().enumerate().map(|(i, p)| (scene::render(k, p, i), p)).collect();
    let grouped = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let mut map = TsdfMap::new(config).expect("valid");
            // Beyond 1 m: most of the analytic scene is far.
            let mut fusion = semrecon_recon::GroupedFusion::new(1.0, 3);
            for (f, pose) in &frames {
                fusion.integrate(&mut map, f, *pose).expect("fusion");
            }
            fusion.flush(&mut map).expect("flush");
            assert!(fusion.stats().groups >= 6, "{:?}", fusion.stats());
            map
        })
    };
    let voxels = |map: &TsdfMap| -> Vec<(semrecon_recon::ChunkKey, Vec<(f32, f32)>)> {
        map.sorted_keys()
            .into_iter()
            .map(|key| (key, map.chunk(key).expect("allocated").voxels().map(|v| (v.tsdf(), v.weight())).collect()))
            .collect()
    };
    let one = grouped(1);
    for threads in [2, 4] {
        assert!(voxels(&one) == voxels(&grouped(threads)), "{threads} threads");
    }
    let mut whole = TsdfMap::new(config).expect("valid");
    for (f, pose) in &frames {
        whole.integrate(f, *pose).expect("fusion");
    }
    // Every vertex of the grouped mesh lies on the whole-frame map's surface: the whole map's
    // distance, interpolated at the vertex, is within a fraction of a voxel of zero.
    let mesh = extract_mesh(&one);
    assert!(mesh.triangle_count() > 1000);
    let reference = extract_mesh(&whole);
    let near = |p: Vec3| reference.positions.iter().map(|q| q.distance_squared(p)).fold(f32::MAX, f32::min).sqrt();
    let step = (mesh.positions.len() / 400).max(1);
    let mut worst = 0.0f32;
    for p in mesh.positions.iter().step_by(step) {
        worst = worst.max(near(*p));
    }
    assert!(worst < 0.5 * config.voxel_size, "a grouped vertex {worst} m from the whole-frame surface");
}
