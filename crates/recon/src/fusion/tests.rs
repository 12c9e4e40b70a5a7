//! Fusion's kernels against a plain scalar specification of the per-voxel update (bit for bit,
//! colour band and colour cadence included), chunk selection against a reference, and the
//! slot bookkeeping.

use super::*;
use crate::map::{TsdfConfig, Voxel, CHUNK_VOXELS};
use glam::{IVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A noisy frame of a tilted plane with holes, NaNs and infinities.
fn noisy_frame(index: usize, rng: &mut ChaCha8Rng) -> Frame {
    let k = Intrinsics::new(64, 48, 50.0, 50.0, 31.5, 23.5).expect("valid camera");
    let n = k.pixel_count();
    let mut depth = Vec::with_capacity(n);
    for i in 0..n {
        let (u, v) = ((i % 64) as f32, (i / 64) as f32);
        let d = 0.5 + 0.002 * u + 0.001 * v + rng.random_range(-0.004..0.004);
        depth.push(match rng.random_range(0..20) {
            0 => 0.0,
            1 => f32::NAN,
            2 => f32::INFINITY,
            _ => d,
        });
    }
    let color = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
    Frame { index, timestamp: 0.0, depth, color, intrinsics: k, world_from_camera: None, labels: None }
}

/// The specification: per voxel, the same projection arithmetic and `Voxel::fuse`.
fn scalar_integrate(voxels: &mut [Voxel], key: IVec3, f: &FrameView) {
    let origin = (key * 8).as_vec3() * f.voxel_size;
    let base = f.rot[0] * origin.x + f.rot[1] * origin.y + f.rot[2] * origin.z + f.trans;
    let (dx, dy, dz) = (f.rot[0] * f.voxel_size, f.rot[1] * f.voxel_size, f.rot[2] * f.voxel_size);
    for (i, vox) in voxels.iter_mut().enumerate() {
        let (x, y, z) = ((i % 8) as f32, ((i / 8) % 8) as f32, (i / 64) as f32);
        let row = base + dy * y + dz * z;
        let pz = row.z + x * dx.z;
        let inv_z = 1.0 / pz;
        let u = f.k.fx * (row.x + x * dx.x) * inv_z + f.k.cx;
        let v = f.k.fy * (row.y + x * dx.y) * inv_z + f.k.cy;
        let inside = pz > 0.0 && u >= -0.5 && u < f.k.width as f32 - 0.5 && v >= -0.5 && v < f.k.height as f32 - 0.5;
        if !inside {
            continue;
        }
        let pix = ((v + 0.5) as i32 as f32 * f.k.width as f32 + (u + 0.5) as i32 as f32) as usize;
        let d = f.depth[pix];
        let sdf = (d - pz) * (1.0 / f.truncation);
        let mu = f.band.relative(d);
        if !(d >= f.min_depth && d <= f.max_depth && sdf >= -mu * f.behind) {
            continue;
        }
        let in_color_band = sdf < f.color_band && sdf >= -f.color_band;
        let color =
            (sdf < mu && in_color_band && (f.color_all || vox.color_count < COLOR_WARMUP)).then_some(f.color[pix]);
        vox.fuse(sdf.min(mu).max(-mu), depth_weight(d) * f.obs_weight, color, f.weight_cap);
    }
}

#[test]
fn simd_rows_equal_the_scalar_specification_bit_for_bit() {
    // A depth-dependent band (about 5 voxels at these depths, changing with depth).
    let config = depth_band_config();
    assert!(config.band(0.5) < config.band(0.7) && config.band(0.7) < config.truncation());
    check_simd_against_scalar(config);
}

#[test]
fn colour_on_every_frame_or_every_third_equals_the_scalar_specification() {
    // Twenty frames (past the colour warm-up of 16 observations): with `color_every` 3,
    // every third frame colours every voxel near the surface, the others only voxels
    // still warming up.
    for color_every in [1, 3] {
        let config = TsdfConfig { max_weight: 3.0, color_every, ..TsdfConfig::default() };
        for kernel in kernels() {
            check_kernel_against_scalar(kernel, config, 20);
        }
    }
}

#[test]
fn observations_behind_the_band_clamped_equal_the_scalar_specification() {
    // Both sides of the band alike (`behind_band` above 1), with a depth-dependent band.
    let base = depth_band_config();
    for behind_band in [1.5, 3.0] {
        let config = TsdfConfig { behind_band, ..base };
        for kernel in kernels() {
            check_kernel_against_scalar(kernel, config, 8);
        }
    }
}

#[test]
fn colour_band_settings_equal_the_scalar_specification() {
    // Colour over the whole band (as before issue 20), a colour band wider than the
    // narrowest band and one narrower, with a depth-dependent band.
    let base = depth_band_config();
    for color_band_voxels in [64.0, 3.0, 1.0] {
        let config = TsdfConfig { color_band_voxels, ..base };
        for kernel in kernels() {
            check_kernel_against_scalar(kernel, config, 8);
        }
    }
}

#[test]
fn colour_stays_within_the_colour_band() {
    // One frame of a wall 0.51 m away: voxels further from it than the colour band take no
    // colour; with the band as wide as the truncation, voxels outside the colour band do.
    let k = Intrinsics::new(64, 48, 50.0, 50.0, 31.5, 23.5).expect("valid camera");
    let frame = Frame {
        index: 0,
        timestamp: 0.0,
        depth: vec![0.51; k.pixel_count()],
        color: vec![[200, 100, 50]; k.pixel_count()],
        intrinsics: k,
        world_from_camera: None,
        labels: None,
    };
    let coloured_outside = |color_band_voxels: f32| {
        let config = TsdfConfig { color_band_voxels, ..TsdfConfig::default() };
        let mut map = TsdfMap::new(config).expect("valid");
        map.integrate(&frame, Affine3A::IDENTITY).expect("fusion");
        let limit = 2.0 * config.voxel_size + 1e-4;
        let mut n = 0;
        for c in map.chunks() {
            for (i, v) in c.voxels().enumerate() {
                let z = (c.key().z * 8 + (i / 64) as i32) as f32 * config.voxel_size;
                n += (v.color_count > 0 && (0.51 - z).abs() > limit) as usize;
            }
        }
        n
    };
    assert_eq!(coloured_outside(2.0), 0);
    assert!(coloured_outside(64.0) > 0);
}

#[test]
fn fixed_band_kernel_equals_the_scalar_specification_bit_for_bit() {
    let config = TsdfConfig { max_weight: 3.0, truncation_noise_factor: 0.0, ..TsdfConfig::default() };
    check_simd_against_scalar(config);
}

/// A depth-dependent band (about 5 voxels at the test frames' depths, changing with depth)
/// and a low weight cap, so that the cap is reached within a few frames.
fn depth_band_config() -> TsdfConfig {
    TsdfConfig {
        max_weight: 3.0,
        truncation_voxels: 8.0,
        min_truncation_voxels: 2.0,
        truncation_noise_factor: 20.0,
        ..TsdfConfig::default()
    }
}

/// The kernels this machine can run.
fn kernels() -> Vec<Kernel> {
    let mut kernels = vec![Kernel::Portable];
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
        kernels.push(Kernel::Avx2);
        if is_x86_feature_detected!("avx512f") {
            kernels.push(Kernel::Avx512);
        } else {
            eprintln!("no AVX-512F on this machine: the AVX-512 kernel is not tested");
        }
    } else {
        eprintln!("no AVX2/FMA on this machine: only the portable kernel is tested");
    }
    kernels
}

fn check_simd_against_scalar(config: TsdfConfig) {
    for kernel in kernels() {
        check_kernel_against_scalar(kernel, config, 6);
    }
}

/// Fuses `frames` noisy frames with `kernel` and with the scalar specification.
fn check_kernel_against_scalar(kernel: Kernel, config: TsdfConfig, frames: usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut map = TsdfMap::new(config).expect("valid");
    let mut spec: Vec<(IVec3, Vec<Voxel>)> = Vec::new();
    for index in 0..frames {
        let frame = noisy_frame(index, &mut rng);
        let yaw = rng.random_range(-0.05..0.05);
        let pose = Affine3A::from_rotation_translation(
            glam::Quat::from_rotation_y(yaw),
            Vec3::new(rng.random_range(-0.01..0.01), 0.0, 0.0),
        );
        let keys = map.select_chunks(&frame, pose).expect("select");
        // Every third frame stands for 3 (loop closure's subsampled re-fusion).
        let obs_weight = if index % 3 == 2 { 3.0 } else { 1.0 };
        let view = FrameView::new(&frame, pose, &config, obs_weight);
        for &key in &keys {
            let entry = match spec.iter().position(|(k, _)| *k == key) {
                Some(i) => i,
                None => {
                    spec.push((key, vec![Voxel::default(); CHUNK_VOXELS]));
                    spec.len() - 1
                }
            };
            scalar_integrate(&mut spec[entry].1, key, &view);
        }
        let id = frame_id(frame.index);
        map.integrate_chunks_with(kernel, &frame, pose, &keys, obs_weight, (id, id)).expect("fusion");
        // The map frees new chunks that got nothing within the band; so does the spec.
        spec.retain(|(k, _)| map.chunk(*k).is_some());
    }
    let mut compared = 0;
    assert_eq!(spec.len(), map.chunk_count());
    for (key, voxels) in &spec {
        let chunk = map.chunk(*key).expect("kept");
        for (i, v) in voxels.iter().enumerate() {
            assert_eq!(chunk.voxel(i), *v, "{kernel:?}: chunk {key} voxel {i}");
            compared += v.is_observed() as usize;
        }
    }
    assert!(compared > 1000, "{compared} observed voxels compared");
    for chunk in map.chunks() {
        assert_eq!(chunk.signs, chunk.voxels.signs(), "{kernel:?}: sign summary of chunk {}", chunk.key);
    }
}

/// The plain band walk: every sample of every sampled pixel into an ordered set.
fn reference_selection(config: &TsdfConfig, frame: &Frame, pose: Affine3A) -> Vec<ChunkKey> {
    let view = SelectionView::new(config, frame, pose);
    let mut set = std::collections::BTreeSet::new();
    for v in (0..view.height).step_by(view.stride) {
        for u in (0..view.width).step_by(view.stride) {
            let d = frame.depth[v * view.width + u];
            if !(d >= config.min_depth && d <= config.max_depth) {
                continue;
            }
            let (p_near, step, steps) = view.band_walk(view.row_ray(v), u, d);
            for s in 0..=steps {
                let p = p_near + step * s as f32;
                if p.cmpge(Vec3A::ZERO).all() && p.cmplt(Vec3A::splat(2.0 * SELECTION_OFFSET)).all() {
                    let key = p.as_ivec3() - IVec3::splat(SELECTION_OFFSET as i32);
                    set.insert(key_order(key));
                }
            }
        }
    }
    set.into_iter().map(|(z, y, x)| IVec3::new(x, y, z)).collect()
}

#[test]
fn every_selection_kernel_selects_the_reference_chunks() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (i, config) in [
        TsdfConfig::default(),
        TsdfConfig { selection_stride: 1, truncation_voxels: 10.0, ..TsdfConfig::default() },
        TsdfConfig { voxel_size: 0.002, truncation_voxels: 12.0, min_truncation_voxels: 2.0, ..TsdfConfig::default() },
    ]
    .into_iter()
    .enumerate()
    {
        let frame = noisy_frame(i, &mut rng);
        let pose = Affine3A::from_rotation_translation(
            glam::Quat::from_euler(glam::EulerRot::XYZ, rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), 0.3),
            Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)),
        );
        let expected = reference_selection(&config, &frame, pose);
        assert!(expected.len() > 20, "{} chunks", expected.len());
        let map = TsdfMap::new(config).expect("valid");
        for kernel in kernels() {
            let view = SelectionView::new(&config, &frame, pose);
            let blocks: Vec<Vec<ChunkKey>> = (0..view.height)
                .step_by(view.stride)
                .map(|v| {
                    let mut out = Candidates::new(view.max_steps);
                    select_row_with(kernel, &view, v, &mut out);
                    out.keys
                })
                .collect();
            assert_eq!(sorted_unique(blocks), expected, "{kernel:?}, config {i}");
        }
        assert_eq!(map.select_chunks(&frame, pose).expect("select"), expected);
    }
}

#[test]
fn selected_slots_are_handed_out_sorted_once_each() {
    let sorted = sorted_unique_slots(&[70, 3, 64, 3, 0, 129, 70], 130);
    assert_eq!(sorted, vec![0, 3, 64, 70, 129]);
    assert!(sorted_unique_slots(&[], 0).is_empty());
    let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
    for x in 0..130 {
        map.allocate(IVec3::new(x, 0, 0));
    }
    let keys: Vec<i32> = select_mut(&mut map.chunks, &sorted).iter().map(|c| c.key.x).collect();
    assert_eq!(keys, vec![0, 3, 64, 70, 129]);
}

#[test]
fn keys_far_apart_are_merged_by_sorting() {
    let far = vec![IVec3::new(5000, 0, 0), IVec3::new(-5000, 3, 0)];
    let near = vec![IVec3::new(1, 2, 3), IVec3::new(5000, 0, 0), IVec3::new(0, 0, 3), IVec3::new(0, 0, -7000)];
    let expected = vec![
        IVec3::new(0, 0, -7000),
        IVec3::new(5000, 0, 0),
        IVec3::new(-5000, 3, 0),
        IVec3::new(0, 0, 3),
        IVec3::new(1, 2, 3),
    ];
    assert_eq!(sorted_unique(vec![far, near]), expected);
    let small = vec![vec![IVec3::new(2, 1, 0), IVec3::new(-1, 1, 0)], vec![IVec3::new(-1, 1, 0), IVec3::new(0, 0, 1)]];
    assert_eq!(sorted_unique(small), vec![IVec3::new(-1, 1, 0), IVec3::new(2, 1, 0), IVec3::new(0, 0, 1)]);
    assert!(sorted_unique(vec![vec![], vec![]]).is_empty());
}

/// Colour pixels are 3 bytes and the AVX2 kernel gathers 4: the last pixel of the image
/// must be read without passing the end, and give the same colour as the portable kernel.
#[test]
fn last_pixel_colour_is_fused_by_every_kernel() {
    let k = Intrinsics::new(16, 12, 20.0, 20.0, 7.5, 5.5).expect("valid camera");
    let n = k.pixel_count();
    let mut depth = vec![0.0; n];
    depth[n - 1] = 0.6;
    let mut color = vec![[10, 20, 30]; n];
    color[n - 1] = [200, 150, 100];
    let frame = Frame { index: 0, timestamp: 0.0, depth, color, intrinsics: k, world_from_camera: None, labels: None };
    let mut colours = Vec::new();
    for kernel in kernels() {
        // Stride 1: the default stride of 2 would not sample the last (odd) pixel.
        let mut map = TsdfMap::new(TsdfConfig { selection_stride: 1, ..TsdfConfig::default() }).expect("valid");
        let keys = map.select_chunks(&frame, Affine3A::IDENTITY).expect("select");
        map.integrate_chunks_with(kernel, &frame, Affine3A::IDENTITY, &keys, 1.0, (0, 0)).expect("fusion");
        let mut seen: Vec<[u8; 3]> =
            map.chunks().flat_map(|c| c.voxels()).filter(|v| v.color_count > 0).map(|v| v.color()).collect();
        assert!(!seen.is_empty(), "{kernel:?}: no voxel took a colour");
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen, vec![[200, 150, 100]], "{kernel:?}");
        colours.push(map.chunks().map(|c| (c.key, c.voxels().collect::<Vec<_>>())).collect::<Vec<_>>());
    }
    assert!(colours.windows(2).all(|w| w[0] == w[1]), "kernels disagree");
}
