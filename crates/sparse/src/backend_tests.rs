//! The shared test suite of every [`ConvBackend`]: each function runs one family of checks
//! against the plain [`reference`] kernels and panics with a message naming the case on the
//! first mismatch. [`backend_test_suite!`](crate::backend_test_suite) turns them into one
//! `#[test]` each for a backend, so the CPU engine (this crate's own tests) and the GPU engine
//! (crate `semrecon-gpu`) are held to exactly the same cases.
//!
//! Sizes stay at a few thousand voxels and at most 33 channels: the GPU suite runs in CI on
//! lavapipe, a software Vulkan driver at about 0.1 GFLOP/s. Voxel sets come from a seeded
//! generator of our own (no random-number dependency): random sets in a cube (both batch
//! indices, negative coordinates, shuffled rows) and surface sets (a voxelised sphere shell
//! over a floor, Z-ordered as the network sees them). Channel counts are odd on purpose, so
//! engines that tile channels must handle partial tiles.

use crate::backend::{apply_bn_relu, BnRelu, ConvBackend};
use crate::kernel_map::MapKind;
use crate::key::Coord;
use crate::morton::morton_order;
use crate::reference;

/// Largest allowed difference to the reference, relative to the reference's largest magnitude.
pub const TOLERANCE: f32 = 1e-4;

/// A small deterministic generator (SplitMix64).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, n)` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    /// Uniform in `[-1, 1)`.
    pub fn signed(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }

    /// `n` values uniform in `[-1, 1)`.
    pub fn values(&mut self, n: usize) -> Vec<f32> {
        (0..n).map(|_| self.signed()).collect()
    }
}

/// `n` distinct random voxels in a cube of side `extent` around the origin, both batch
/// indices, in random row order.
pub fn random_set(n: usize, extent: i32, seed: u64) -> Vec<Coord> {
    let mut rng = Rng::new(seed);
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::with_capacity(n);
    let cells = (extent as usize).pow(3) * 2;
    while out.len() < n.min(cells) {
        let mut c = [0i32; 4];
        for v in c.iter_mut().take(3) {
            *v = rng.below(extent as u64) as i32 - extent / 2;
        }
        c[3] = rng.below(2) as i32;
        if seen.insert(c) {
            out.push(c);
        }
    }
    out
}

/// A voxelised sphere shell of `radius` voxels above a square floor of side `2 radius`, in
/// Z-order: the continuous surfaces the chunked kernels are made for.
pub fn surface_set(radius: i32) -> Vec<Coord> {
    let mut set = std::collections::BTreeSet::new();
    let r = radius as f32;
    for x in -radius..=radius {
        for y in -radius..=radius {
            set.insert([x, y, -radius - 1, 0]);
            for z in -radius..=radius {
                let d = ((x * x + y * y + z * z) as f32).sqrt();
                if (d - r).abs() < 0.5 {
                    set.insert([x, y, z, 0]);
                }
            }
        }
    }
    let coords: Vec<Coord> = set.into_iter().collect();
    // morton_order never fails on these small coordinates; fall back to the sorted order.
    match morton_order(&coords) {
        Ok(order) => order.iter().map(|&r| coords[r as usize]).collect(),
        Err(_) => coords,
    }
}

/// Asserts `got` matches `want` to [`TOLERANCE`] of `want`'s largest magnitude.
///
/// # Panics
/// On a length mismatch or a larger difference, naming `what`.
pub fn assert_close(what: &str, got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len(), "{what}: {} values, the reference has {}", got.len(), want.len());
    let scale = want.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    let mut worst = (0.0f32, 0usize);
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        let d = (a - b).abs();
        // A NaN counts as the worst difference of all.
        let d = if d.is_nan() { f32::INFINITY } else { d };
        if d > worst.0 {
            worst = (d, i);
        }
    }
    assert!(
        worst.0 <= TOLERANCE * scale,
        "{what}: largest difference {} at index {} (got {}, reference {}), scale {scale}",
        worst.0,
        worst.1,
        got[worst.1],
        want[worst.1]
    );
}

fn unwrap<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> T {
    match r {
        Ok(v) => v,
        Err(e) => panic!("{what}: {e}"),
    }
}

/// Forward, input gradient and weight gradient of one layer against the reference.
#[allow(clippy::too_many_arguments)]
fn check_layer<B: ConvBackend>(
    b: &B,
    what: &str,
    layer: &B::Layer,
    kind: MapKind,
    kv: usize,
    in_coords: &[Coord],
    out_coords: &[Coord],
    c_in: usize,
    c_out: usize,
    seed: u64,
    gradients: bool,
) {
    let what = format!("{} {what} c_in {c_in} c_out {c_out}", b.name());
    let mut rng = Rng::new(seed);
    let x = rng.values(in_coords.len() * c_in);
    let w = rng.values(kv * c_in * c_out);
    let dy = rng.values(out_coords.len() * c_out);
    assert_eq!(b.layer_rows(layer), (in_coords.len(), out_coords.len()), "{what}: layer rows");
    let y = unwrap(&what, b.forward(layer, &x, c_in, &w, c_out));
    let want = unwrap("reference", reference::forward(kind, in_coords, out_coords, &x, c_in, &w, c_out));
    assert_close(&format!("{what} forward"), &y, &want);
    if gradients {
        let dx = unwrap(&what, b.backward_input(layer, &dy, c_out, &w, c_in));
        let want = unwrap("reference", reference::backward_input(kind, in_coords, out_coords, &dy, c_out, &w, c_in));
        assert_close(&format!("{what} input gradient"), &dx, &want);
        let dw = unwrap(&what, b.backward_weight(layer, &x, c_in, &dy, c_out));
        let want = unwrap("reference", reference::backward_weight(kind, in_coords, out_coords, &x, c_in, &dy, c_out));
        assert_close(&format!("{what} weight gradient"), &dw, &want);
    }
}

/// Submanifold layers (K = 3, 1, 5) on random sets, odd channel counts, all three passes.
pub fn submanifold_random<B: ConvBackend>(b: &B) {
    for (n, extent, k, c_in, c_out, seed) in [
        (1500, 16, 3, 3, 5, 1),
        (900, 12, 3, 16, 16, 2),
        (700, 14, 3, 7, 33, 3),
        (500, 10, 1, 9, 4, 4),
        (300, 10, 5, 3, 2, 5),
    ] {
        let coords = random_set(n, extent, seed);
        let layer = unwrap("submanifold", b.submanifold(&coords, k));
        let kind = MapKind::Submanifold { kernel_size: k };
        let what = format!("submanifold K={k} random n={n}");
        check_layer(b, &what, &layer, kind, k.pow(3), &coords, &coords, c_in, c_out, seed + 10, true);
    }
}

/// Submanifold layers on a surface set (the network's case), forward and gradients.
pub fn submanifold_surface<B: ConvBackend>(b: &B) {
    let coords = surface_set(9);
    let layer = unwrap("submanifold", b.submanifold(&coords, 3));
    let kind = MapKind::Submanifold { kernel_size: 3 };
    let what = format!("submanifold surface n={}", coords.len());
    check_layer(b, &what, &layer, kind, 27, &coords, &coords, 13, 24, 21, true);
    check_layer(b, &what, &layer, kind, 27, &coords, &coords, 32, 32, 22, false);
}

/// Strided (down) and transposed (up) layers on random and surface sets.
pub fn strided_and_transposed<B: ConvBackend>(b: &B) {
    for (fine, c_in, c_out, seed) in
        [(random_set(1200, 14, 31), 5, 7, 31u64), (surface_set(9), 16, 31, 32), (surface_set(6), 33, 3, 33)]
    {
        let (coarse, down) = unwrap("downsample", b.downsample(&fine));
        let what = format!("down n={}", fine.len());
        check_layer(b, &what, &down, MapKind::Down, 8, &fine, &coarse, c_in, c_out, seed, true);
        let up = unwrap("upsample", b.upsample(&coarse, &fine));
        let what = format!("up n={}", coarse.len());
        check_layer(b, &what, &up, MapKind::Up, 8, &coarse, &fine, c_out, c_in, seed + 1, true);
    }
}

/// A named layer with its kind, kernel volume and input and output voxels.
type Case<'a, B> = (&'a str, &'a <B as ConvBackend>::Layer, MapKind, usize, &'a [Coord], &'a [Coord]);

/// The fused batch norm + ReLU on the input and the residual accumulation into the output,
/// for every layer kind.
pub fn fused_bn_relu_and_residual<B: ConvBackend>(b: &B) {
    let fine = surface_set(7);
    let sub = unwrap("submanifold", b.submanifold(&fine, 3));
    let (coarse, down) = unwrap("downsample", b.downsample(&fine));
    let up = unwrap("upsample", b.upsample(&coarse, &fine));
    let cases: [Case<'_, B>; 3] = [
        ("submanifold", &sub, MapKind::Submanifold { kernel_size: 3 }, 27, &fine, &fine),
        ("down", &down, MapKind::Down, 8, &fine, &coarse),
        ("up", &up, MapKind::Up, 8, &coarse, &fine),
    ];
    for (i, (name, layer, kind, kv, ins, outs)) in cases.into_iter().enumerate() {
        let (c_in, c_out) = (11, 19);
        let mut rng = Rng::new(40 + i as u64);
        let x = rng.values(ins.len() * c_in);
        let w = rng.values(kv * c_in * c_out);
        let scale = rng.values(c_in);
        let shift = rng.values(c_in);
        let bn = BnRelu { scale: &scale, shift: &shift };
        let y0 = rng.values(outs.len() * c_out);
        let normalised = apply_bn_relu(&x, bn);
        let conv = unwrap("reference", reference::forward(kind, ins, outs, &normalised, c_in, &w, c_out));
        let what = format!("{} {name} bn+relu", b.name());
        let mut y = y0.clone();
        unwrap(&what, b.forward_into(layer, &x, c_in, Some(bn), &w, c_out, &mut y, false));
        assert_close(&what, &y, &conv);
        let mut y = y0.clone();
        unwrap(&what, b.forward_into(layer, &x, c_in, Some(bn), &w, c_out, &mut y, true));
        let want: Vec<f32> = y0.iter().zip(&conv).map(|(a, c)| a + c).collect();
        assert_close(&format!("{what} residual"), &y, &want);
        let mut y = y0.clone();
        unwrap(&what, b.forward_into(layer, &x, c_in, None, &w, c_out, &mut y, true));
        let plain = unwrap("reference", reference::forward(kind, ins, outs, &x, c_in, &w, c_out));
        let want: Vec<f32> = y0.iter().zip(&plain).map(|(a, c)| a + c).collect();
        assert_close(&format!("{what} residual without bn"), &y, &want);
    }
}

/// Empty voxel sets give empty layers and empty results for every kind and pass.
pub fn empty_input<B: ConvBackend>(b: &B) {
    let sub = unwrap("submanifold", b.submanifold(&[], 3));
    assert_eq!(b.layer_rows(&sub), (0, 0));
    let y = unwrap("forward", b.forward(&sub, &[], 4, &vec![0.5; 27 * 4 * 6], 6));
    assert!(y.is_empty());
    let dw = unwrap("weight gradient", b.backward_weight(&sub, &[], 4, &[], 6));
    assert_eq!(dw, vec![0.0; 27 * 4 * 6]);
    let (coarse, down) = unwrap("downsample", b.downsample(&[]));
    assert!(coarse.is_empty());
    assert!(unwrap("forward", b.forward(&down, &[], 3, &[1.0; 8 * 3 * 2], 2)).is_empty());
    let up = unwrap("upsample", b.upsample(&[], &[]));
    assert!(unwrap("input gradient", b.backward_input(&up, &[], 2, &[1.0; 8 * 3 * 2], 3)).is_empty());
}

/// A single voxel and a layer with no neighbours at all (isolated voxels).
pub fn isolated_voxels<B: ConvBackend>(b: &B) {
    let coords: Vec<Coord> = (0..50).map(|i| [i * 3, -i * 3, i * 5, i % 2]).collect();
    let layer = unwrap("submanifold", b.submanifold(&coords, 3));
    let kind = MapKind::Submanifold { kernel_size: 3 };
    check_layer(b, "isolated", &layer, kind, 27, &coords, &coords, 5, 3, 50, true);
    let one = [[7, -7, 7, 1]];
    let layer = unwrap("submanifold", b.submanifold(&one, 3));
    check_layer(b, "one voxel", &layer, kind, 27, &one, &one, 2, 3, 51, true);
}

/// Bad calls are errors, never panics or wrong results.
pub fn bad_input_is_an_error<B: ConvBackend>(b: &B) {
    let coords = random_set(100, 8, 60);
    assert!(b.submanifold(&coords, 2).is_err(), "even kernel size");
    assert!(b.submanifold(&[[0, 0, 0, 0], [0, 0, 0, 0]], 3).is_err(), "duplicate coordinates");
    assert!(b.submanifold(&[[1 << 22, 0, 0, 0]], 3).is_err(), "coordinate out of range");
    assert!(b.upsample(&[[0, 0, 0, 0]], &[[4, 4, 4, 0]]).is_err(), "missing parent");
    let layer = unwrap("submanifold", b.submanifold(&coords, 3));
    let w = vec![0.1; 27 * 4 * 4];
    assert!(b.forward(&layer, &vec![0.0; 99 * 4], 4, &w, 4).is_err(), "short x");
    assert!(b.forward(&layer, &vec![0.0; 100 * 4], 4, &w[1..], 4).is_err(), "short w");
    let mut y = vec![0.0; 99 * 4];
    assert!(b.forward_into(&layer, &vec![0.0; 400], 4, None, &w, 4, &mut y, false).is_err(), "short y");
    let bad = [1.0f32; 3];
    let bn = BnRelu { scale: &bad, shift: &bad };
    let mut y = vec![0.0; 400];
    assert!(b.forward_into(&layer, &vec![0.0; 400], 4, Some(bn), &w, 4, &mut y, false).is_err(), "short bn");
    assert!(b.backward_input(&layer, &[0.0; 4], 4, &w, 4).is_err(), "short dy");
    assert!(b.backward_weight(&layer, &vec![0.0; 400], 4, &[0.0; 4], 4).is_err(), "short dy");
}

/// Two runs of the same call give the same bits, and a layer is reusable with other channel
/// counts and weights.
pub fn repeatable_and_reusable<B: ConvBackend>(b: &B) {
    let coords = surface_set(6);
    let layer = unwrap("submanifold", b.submanifold(&coords, 3));
    let mut rng = Rng::new(70);
    let x = rng.values(coords.len() * 6);
    let w = rng.values(27 * 6 * 10);
    let a = unwrap("forward", b.forward(&layer, &x, 6, &w, 10));
    let a2 = unwrap("forward", b.forward(&layer, &x, 6, &w, 10));
    assert!(a.iter().zip(&a2).all(|(p, q)| p.to_bits() == q.to_bits()), "{}: two runs differ", b.name());
    let kind = MapKind::Submanifold { kernel_size: 3 };
    check_layer(b, "reused", &layer, kind, 27, &coords, &coords, 10, 6, 71, false);
}

/// One `#[test]` per function of [`backend_tests`](crate::backend_tests) for a backend.
///
/// `$make` is an expression giving `Option<backend>`: `None` skips the test (the backend
/// prints why, e.g. no GPU adapter). Invoke it inside a test module:
///
/// ```ignore
/// mod suite {
///     semrecon_sparse::backend_test_suite!(Some(semrecon_sparse::CpuEngine::default()));
/// }
/// ```
#[macro_export]
macro_rules! backend_test_suite {
    ($make:expr) => {
        $crate::backend_test_suite!(@tests $make;
            submanifold_random, submanifold_surface, strided_and_transposed,
            fused_bn_relu_and_residual, empty_input, isolated_voxels, bad_input_is_an_error,
            repeatable_and_reusable);
    };
    (@tests $make:expr; $($name:ident),*) => {
        $(
            #[test]
            fn $name() {
                if let Some(backend) = $make {
                    $crate::backend_tests::$name(&backend);
                }
            }
        )*
    };
}
