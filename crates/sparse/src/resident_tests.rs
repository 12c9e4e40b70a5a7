//! The shared test suite of every [`ResidentBackend`]: engine-owned tensors against the host
//! path. Convolutions on resident tensors must match [`ConvBackend::forward_into`] on host
//! slices, and each element-wise operation (gate, weighted gather, bias, argmax) a plain loop
//! written here, on random inputs with odd channel counts, on empty inputs and on tensors
//! longer than their shapes (workspaces only grow). Short tensors are errors.
//! [`resident_test_suite!`](crate::resident_test_suite) makes one `#[test]` of each function.
//!
//! Sizes stay small (a few hundred rows): the GPU engine runs this on lavapipe in CI.

use crate::backend::BnRelu;
use crate::backend_tests::{assert_close, surface_set, Rng};
use crate::elementwise::GatherTable;
use crate::resident::ResidentBackend;

fn unwrap<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> T {
    match r {
        Ok(v) => v,
        Err(e) => panic!("{what}: {e}"),
    }
}

/// A tensor of `data` followed by `extra` values of garbage, as a grown workspace has.
fn padded<B: ResidentBackend>(b: &B, data: &[f32], extra: usize) -> B::Tensor {
    let mut v = data.to_vec();
    v.extend((0..extra).map(|i| 1e3 + i as f32));
    unwrap("upload", b.upload(&v))
}

fn download<B: ResidentBackend>(b: &B, t: &B::Tensor, len: usize) -> Vec<f32> {
    unwrap("download", b.download(t, len))
}

/// Upload, download and growth keep what they should.
pub fn tensors_round_trip<B: ResidentBackend>(b: &B) {
    let data = Rng::new(1).values(37);
    let mut t = unwrap("upload", b.upload(&data));
    assert_eq!(b.tensor_len(&t), 37);
    assert_eq!(download(b, &t, 37), data, "{}: round trip", b.name());
    assert_eq!(download(b, &t, 5), data[..5], "{}: a prefix", b.name());
    assert!(b.download(&t, 38).is_err(), "{}: reading past the end", b.name());
    unwrap("reserve", b.reserve(&mut t, 10));
    assert!(b.tensor_len(&t) >= 37, "{}: reserve never shrinks", b.name());
    unwrap("reserve", b.reserve(&mut t, 1000));
    assert!(b.tensor_len(&t) >= 1000, "{}: reserve grows", b.name());
    let empty = unwrap("upload", b.upload(&[]));
    assert!(download(b, &empty, 0).is_empty());
}

/// Convolutions on resident tensors (with and without batch norm and residual sum, on
/// submanifold, strided and transposed layers) against the host path.
pub fn conv_matches_the_host_path<B: ResidentBackend>(b: &B) {
    let fine = surface_set(5);
    let sub = unwrap("submanifold", b.submanifold(&fine, 3));
    let (coarse, down) = unwrap("downsample", b.downsample(&fine));
    let up = unwrap("upsample", b.upsample(&coarse, &fine));
    let mut rng = Rng::new(2);
    for (name, layer, kv, c_in, c_out) in
        [("submanifold", &sub, 27, 5, 7), ("strided", &down, 8, 3, 9), ("transposed", &up, 8, 9, 1)]
    {
        let (n_in, n_out) = b.layer_rows(layer);
        let x = rng.values(n_in * c_in);
        let w = rng.values(kv * c_in * c_out);
        let bn = rng.values(2 * c_in);
        let y0 = rng.values(n_out * c_out);
        for (with_bn, accumulate) in [(false, false), (true, false), (false, true), (true, true)] {
            let what = format!("{} {name} c_in {c_in} c_out {c_out} bn {with_bn} accumulate {accumulate}", b.name());
            let mut want = y0.clone();
            let host_bn = BnRelu { scale: &bn[..c_in], shift: &bn[c_in..] };
            let host_bn = with_bn.then_some(host_bn);
            unwrap(&what, b.forward_into(layer, &x, c_in, host_bn, &w, c_out, &mut want, accumulate));
            let (xt, wt, bnt) = (padded(b, &x, 3), padded(b, &w, 1), padded(b, &bn, 2));
            let mut yt = padded(b, &y0, 5);
            unwrap(&what, b.conv(layer, &xt, c_in, with_bn.then_some(&bnt), &wt, c_out, &mut yt, accumulate));
            assert_close(&what, &download(b, &yt, n_out * c_out), &want);
        }
    }
}

/// Plain gate: `g[r, ..c] *= 1 / (1 + exp(-g[r, c]))`.
fn gate_reference(g: &mut [f32], c: usize) {
    for row in g.chunks_exact_mut(c + 1) {
        let s = 1.0 / (1.0 + (-row[c]).exp());
        for v in &mut row[..c] {
            *v *= s;
        }
    }
}

/// The attention gate against a plain loop (odd channel counts, one channel, no channel).
pub fn gate_matches_a_plain_loop<B: ResidentBackend>(b: &B) {
    let mut rng = Rng::new(3);
    for (rows, c) in [(301, 5), (64, 1), (17, 0), (129, 33)] {
        let data: Vec<f32> = rng.values(rows * (c + 1)).iter().map(|v| v * 6.0).collect();
        let mut want = data.clone();
        gate_reference(&mut want, c);
        let mut t = padded(b, &data, 7);
        unwrap("gate", b.gate(&mut t, rows, c));
        assert_close(&format!("{} gate rows {rows} c {c}", b.name()), &download(b, &t, data.len()), &want);
    }
}

/// A random gather table: `per_row` entries per row, some of weight zero (whose rows must not
/// matter).
fn random_table(rng: &mut Rng, n: usize, per_row: usize, source_rows: usize) -> GatherTable {
    let rows: Vec<u32> = (0..n * per_row).map(|_| rng.below(source_rows as u64) as u32).collect();
    let weights: Vec<f32> = (0..n * per_row).map(|_| if rng.below(4) == 0 { 0.0 } else { rng.signed() }).collect();
    unwrap("gather table", GatherTable::new(rows, weights, per_row))
}

/// The weighted row gather against a plain loop (interpolation-like tables of 8 entries and
/// others, odd channel counts, source rows wider than the gathered channels).
pub fn gather_matches_a_plain_loop<B: ResidentBackend>(b: &B) {
    let mut rng = Rng::new(4);
    for (n, per_row, source_rows, c, stride) in [(257, 8, 61, 5, 6), (100, 3, 100, 13, 13), (40, 1, 7, 1, 4)] {
        let table = random_table(&mut rng, n, per_row, source_rows);
        let src = rng.values(source_rows * stride);
        let dst = rng.values(n * c);
        let mut want = dst.clone();
        for u in 0..n {
            for q in 0..per_row {
                let (r, w) = (table.rows()[u * per_row + q] as usize, table.weights()[u * per_row + q]);
                if w != 0.0 {
                    for i in 0..c {
                        want[u * c + i] += w * src[r * stride + i];
                    }
                }
            }
        }
        let gt = unwrap("gather table", b.gather_table(&table));
        let st = padded(b, &src, 3);
        let mut dt = padded(b, &dst, 4);
        unwrap("gather", b.gather_add(&gt, &st, stride, c, &mut dt));
        let what = format!("{} gather n {n} per row {per_row} c {c} stride {stride}", b.name());
        assert_close(&what, &download(b, &dt, n * c), &want);
    }
}

/// Bias and argmax against plain loops (odd class counts, ties, a single class).
pub fn bias_and_argmax_match_plain_loops<B: ResidentBackend>(b: &B) {
    let mut rng = Rng::new(5);
    for (rows, k) in [(333, 13), (65, 1), (9, 7)] {
        let y = rng.values(rows * k);
        let bias = rng.values(k);
        let want: Vec<f32> = y.iter().enumerate().map(|(e, v)| v + bias[e % k]).collect();
        let mut yt = padded(b, &y, 2);
        let bt = padded(b, &bias, 1);
        unwrap("bias", b.add_bias(&mut yt, rows, &bt, k));
        assert_close(&format!("{} bias rows {rows} k {k}", b.name()), &download(b, &yt, rows * k), &want);
        // Ties: quantised scores, the first of equal maxima wins.
        let scores: Vec<f32> = y.iter().map(|v| (v * 2.0).round()).collect();
        let want: Vec<u32> =
            scores.chunks(k).map(|r| (0..k).fold(0, |best, c| if r[c] > r[best] { c } else { best }) as u32).collect();
        let st = padded(b, &scores, 3);
        assert_eq!(unwrap("argmax", b.argmax_rows(&st, rows, k)), want, "{} argmax rows {rows} k {k}", b.name());
    }
}

/// Zero rows everywhere: every operation succeeds and leaves nothing behind.
pub fn empty_tensors<B: ResidentBackend>(b: &B) {
    let sub = unwrap("submanifold", b.submanifold(&[], 3));
    let x = unwrap("upload", b.upload(&[]));
    let w = unwrap("upload", b.upload(&vec![0.5; 27 * 3 * 4]));
    let mut y = unwrap("upload", b.upload(&[]));
    unwrap("conv", b.conv(&sub, &x, 3, None, &w, 4, &mut y, false));
    unwrap("gate", b.gate(&mut y, 0, 4));
    let table = unwrap("gather table", GatherTable::new(Vec::new(), Vec::new(), 8));
    let gt = unwrap("gather table", b.gather_table(&table));
    unwrap("gather", b.gather_add(&gt, &x, 5, 4, &mut y));
    let bias = unwrap("upload", b.upload(&[1.0; 4]));
    unwrap("bias", b.add_bias(&mut y, 0, &bias, 4));
    assert!(unwrap("argmax", b.argmax_rows(&y, 0, 4)).is_empty());
    assert!(download(b, &y, 0).is_empty());
}

/// Tensors shorter than the shapes named are errors, never reads past the end.
pub fn short_tensors_are_errors<B: ResidentBackend>(b: &B) {
    let coords = surface_set(3);
    let n = coords.len();
    let sub = unwrap("submanifold", b.submanifold(&coords, 3));
    let x = unwrap("upload", b.upload(&vec![0.1; n * 4]));
    let w = unwrap("upload", b.upload(&vec![0.1; 27 * 4 * 2]));
    let short = unwrap("upload", b.upload(&[0.0; 3]));
    let mut y = unwrap("upload", b.upload(&vec![0.0; n * 2]));
    assert!(b.conv(&sub, &short, 4, None, &w, 2, &mut y, false).is_err(), "short x");
    assert!(b.conv(&sub, &x, 4, None, &short, 2, &mut y, false).is_err(), "short w");
    assert!(b.conv(&sub, &x, 4, Some(&short), &w, 2, &mut y, false).is_err(), "short bn");
    assert!(b.conv(&sub, &x, 4, None, &w, 3, &mut y, false).is_err(), "short y");
    assert!(b.gate(&mut y, n, 2).is_err(), "short gate");
    let table = unwrap("gather table", GatherTable::new(vec![0, 5], vec![1.0, 1.0], 1));
    let gt = unwrap("gather table", b.gather_table(&table));
    let mut dst = unwrap("upload", b.upload(&[0.0; 4]));
    assert!(b.gather_add(&gt, &short, 1, 1, &mut dst).is_err(), "source row out of range");
    assert!(b.gather_add(&gt, &x, 1, 2, &mut dst).is_err(), "more channels than the stride");
    assert!(b.add_bias(&mut y, n, &short, 4).is_err(), "short bias");
    assert!(b.argmax_rows(&short, 2, 2).is_err(), "short scores");
    assert!(GatherTable::new(vec![0, 1, 2], vec![1.0, 1.0], 1).is_err(), "mismatched table");
}

/// One `#[test]` per function of [`resident_tests`](crate::resident_tests) for a backend,
/// as [`backend_test_suite!`](crate::backend_test_suite) does for [`ConvBackend`]s.
#[macro_export]
macro_rules! resident_test_suite {
    ($make:expr) => {
        $crate::resident_test_suite!(@tests $make;
            tensors_round_trip, conv_matches_the_host_path, gate_matches_a_plain_loop,
            gather_matches_a_plain_loop, bias_and_argmax_match_plain_loops, empty_tensors,
            short_tensors_are_errors);
    };
    (@tests $make:expr; $($name:ident),*) => {
        $(
            #[test]
            fn $name() {
                if let Some(backend) = $make {
                    $crate::resident_tests::$name(&backend);
                }
            }
        )*
    };
}
