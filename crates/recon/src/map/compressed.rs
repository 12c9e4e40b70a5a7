//! Lossless packing of one chunk's voxels for chunks that fusion has not touched for a while
//! ("cold" chunks): the in-memory form of a cold chunk, and the payload of a spill-file
//! record.
//!
//! Why this layout: in a scan most voxels of an allocated chunk are never observed (the band
//! around a surface crosses a chunk obliquely), and an unobserved voxel is all zeros. So a
//! packed chunk is a 512-bit observed mask plus only the observed voxels, field by field.
//! Each field is predicted from already-coded neighbours and only the residual is stored, in
//! a Rice code ([`super::rice`]) fitted to each field of each chunk: the signed distance is nearly linear in position near a surface,
//! so the planar predictor `left + below - below-left` leaves sensor noise only; weights and
//! colours change little between neighbours, so the left neighbour predicts them. Fusion
//! colours only the voxels near the surface ([`crate::TsdfConfig::color_band_voxels`]), so a
//! bit per observed voxel says which have a colour, and only those are coded, each predicted
//! from a coloured neighbour: an uncoloured voxel costs a bit instead of four residuals, and
//! the edge of the coloured layer no jump from or to zero. The residual stream then goes
//! through LZ4 (fast, pure Rust) when that shrinks it, which folds long runs of equal
//! residuals (capped weights, saturated colour counts, flat colours).
//!
//! Lossless for every input: a chunk with an unobserved voxel that is not all zeros (which
//! fusion never makes, but a caller of the map could) is packed densely, all 512 voxels.
//!
//! Layout: `[flags u8] [stream length u16] [stream, LZ4 or raw]`; the stream, which holds
//! the observed mask as run lengths (sparse chunks only), is described at `residuals`.

use super::rice::{self, BitReader, BitWriter};
use super::{VoxelBlock, CHUNK_SIDE, CHUNK_VOXELS};

/// What a packed chunk can be wrong about when read back (only bytes from outside the
/// process, the spill file, can be).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PackError {
    /// The bytes end before the layout does.
    #[error("packed chunk truncated ({0} bytes)")]
    Truncated(usize),
    /// Unknown flag bits, a stream of an impossible length, or residuals that do not add up.
    #[error("packed chunk malformed: {0}")]
    Malformed(&'static str),
}

/// Flag bit: the stream is LZ4-compressed (else stored raw: LZ4 did not shrink it).
const LZ4: u8 = 1;
/// Flag bit: all 512 voxels are coded (no mask).
const DENSE: u8 = 2;
/// Bits of the number of runs of the observed mask (at most 512).
const RUN_COUNT_BITS: u32 = 10;
/// Longest residual stream: the mask's runs (one per voxel at most) and per voxel a bit
/// saying whether it has a colour and six values (distance, weight, four colour bytes), each
/// value of at most [`rice::MAX_VALUE_BITS`], and seven section headers. Below 2^16, so its
/// length fits the `u16` of the layout.
const MAX_STREAM: usize =
    (RUN_COUNT_BITS as usize + CHUNK_VOXELS * (1 + 7 * rice::MAX_VALUE_BITS) + 7 * rice::SECTION_BITS).div_ceil(8);

/// Packs `block` losslessly (see the module documentation).
pub(crate) fn pack(block: &VoxelBlock) -> Box<[u8]> {
    let mut mask = [0u64; CHUNK_VOXELS / 64];
    let mut dense = false;
    for i in 0..CHUNK_VOXELS {
        if block.weight[i] != 0 {
            mask[i / 64] |= 1 << (i % 64);
        } else if block.tsdf[i] != 0 || block.color[i] != [0; 4] {
            dense = true;
        }
    }
    if dense {
        mask = [u64::MAX; CHUNK_VOXELS / 64];
    }
    let stream = residuals(block, &mask, dense);
    let compressed = lz4_flex::block::compress(&stream);
    let (flags, body) = if compressed.len() < stream.len() { (LZ4, &compressed) } else { (0, &stream) };
    let flags = flags | if dense { DENSE } else { 0 };
    let mut out = Vec::with_capacity(1 + 2 + body.len());
    out.push(flags);
    // MAX_STREAM < 2^16, so the raw length always fits.
    out.extend_from_slice(&(stream.len() as u16).to_le_bytes());
    out.extend_from_slice(body);
    out.into_boxed_slice()
}

/// Unpacks bytes made by [`pack`] into `block` (every voxel written).
pub(crate) fn unpack_into(bytes: &[u8], block: &mut VoxelBlock) -> Result<(), PackError> {
    let truncated = || PackError::Truncated(bytes.len());
    let (&flags, rest) = bytes.split_first().ok_or_else(truncated)?;
    if flags & !(LZ4 | DENSE) != 0 {
        return Err(PackError::Malformed("unknown flags"));
    }
    let (len, body) = rest.split_at_checked(2).ok_or_else(truncated)?;
    let len = u16::from_le_bytes([len[0], len[1]]) as usize;
    if len > MAX_STREAM {
        return Err(PackError::Malformed("stream longer than any chunk's"));
    }
    let mut raw = [0u8; MAX_STREAM];
    let stream: &[u8] = if flags & LZ4 != 0 {
        let n = lz4_flex::block::decompress_into(body, &mut raw[..len])
            .map_err(|_| PackError::Malformed("LZ4 block does not decode"))?;
        if n != len {
            return Err(PackError::Malformed("LZ4 block of the wrong length"));
        }
        &raw[..len]
    } else {
        if body.len() != len {
            return Err(if body.len() < len { truncated() } else { PackError::Malformed("trailing bytes") });
        }
        body
    };
    decode(stream, flags & DENSE != 0, block)
}

/// Whether voxel `i` is coded.
#[inline]
fn coded(mask: &[u64; CHUNK_VOXELS / 64], i: usize) -> bool {
    mask[i / 64] & (1 << (i % 64)) != 0
}

/// The coded neighbours of voxel `i` that predictions read: left (x - 1), below (y - 1),
/// below-left, and behind (z - 1), each when inside the chunk and coded.
#[derive(Clone, Copy)]
struct Neighbours {
    left: Option<usize>,
    below: Option<usize>,
    below_left: Option<usize>,
    behind: Option<usize>,
}

impl Neighbours {
    #[inline]
    fn of(mask: &[u64; CHUNK_VOXELS / 64], i: usize) -> Self {
        let (x, y, z) = (i % CHUNK_SIDE, (i / CHUNK_SIDE) % CHUNK_SIDE, i / (CHUNK_SIDE * CHUNK_SIDE));
        let at = |ok: bool, j: usize| (ok && coded(mask, j)).then_some(j);
        Self {
            left: at(x > 0, i.wrapping_sub(1)),
            below: at(y > 0, i.wrapping_sub(CHUNK_SIDE)),
            below_left: at(x > 0 && y > 0, i.wrapping_sub(CHUNK_SIDE + 1)),
            behind: at(z > 0, i.wrapping_sub(CHUNK_SIDE * CHUNK_SIDE)),
        }
    }

    /// The nearest coded neighbour (left, else below, else behind).
    #[inline]
    fn nearest(&self) -> Option<usize> {
        self.left.or(self.below).or(self.behind)
    }
}

/// Prediction of a distance: exact for a field linear in x and y.
#[inline]
fn predict_tsdf(t: &[i16; CHUNK_VOXELS], n: Neighbours) -> i16 {
    // The median of the left, the below and the planar prediction (LOCO-I's): planar on a
    // plane, and the nearer neighbour across the kink where the band saturates.
    match (n.left, n.below, n.below_left) {
        (Some(a), Some(b), Some(c)) => {
            let (a, b, c) = (t[a] as i32, t[b] as i32, t[c] as i32);
            (if c >= a.max(b) {
                a.min(b)
            } else if c <= a.min(b) {
                a.max(b)
            } else {
                a + b - c
            }) as i16
        }
        _ => n.nearest().map_or(0, |j| t[j]),
    }
}

/// Planar prediction of a weight, clamped to the range of its neighbours (weights follow
/// the viewing distance and count, smooth across a chunk but not linear).
#[inline]
fn predict_weight(w: &[u16; CHUNK_VOXELS], n: Neighbours) -> u16 {
    match (n.left, n.below, n.below_left) {
        (Some(a), Some(b), Some(c)) => {
            let (a, b, c) = (w[a] as i32, w[b] as i32, w[c] as i32);
            (a + b - c).clamp(a.min(b), a.max(b)) as u16
        }
        _ => n.nearest().map_or(0, |j| w[j]),
    }
}

#[inline]
fn zigzag(r: i16) -> u16 {
    ((r << 1) ^ (r >> 15)) as u16
}

#[inline]
fn unzigzag(u: u16) -> i16 {
    ((u >> 1) as i16) ^ -((u & 1) as i16)
}

/// The colour that predicts voxel `i`'s (coloured) colour: its nearest coloured coded
/// neighbour's (left, below, behind), else `last`, the colour of the previous coloured voxel
/// in coding order.
#[inline]
fn predict_color(c: &[[u8; 4]; CHUNK_VOXELS], n: Neighbours, last: [u8; 4]) -> [u8; 4] {
    [n.left, n.below, n.behind].into_iter().flatten().map(|j| c[j]).find(|&c| c != [0; 4]).unwrap_or(last)
}

/// The residual stream, a bit stream ([`rice`]): for a sparse chunk the observed mask as the
/// lengths of its alternating runs in index order (unobserved first; the number of runs in
/// 10 bits, then a Rice-coded section of the first run's length and the others' minus one:
/// the band makes a few long runs, cheaper than a 64-byte mask), a bit per coded voxel set
/// when its colour is not all zeros, then six Rice-coded sections of zigzagged residuals:
/// distances and weights of the coded voxels, then the red, green, blue and count bytes of
/// the coloured ones (sections apart, each with its own parameter). One pass over the voxels
/// fills all sections.
fn residuals(block: &VoxelBlock, mask: &[u64; CHUNK_VOXELS / 64], dense: bool) -> Vec<u8> {
    let n = mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
    let mut out = BitWriter::with_capacity(n.div_ceil(8) + 64);
    if !dense {
        let runs = mask_runs(mask);
        out.put(runs.len() as u64, RUN_COUNT_BITS);
        rice::put_section(&mut out, &runs);
    }
    let mut tsdf = Vec::with_capacity(n);
    let mut weight = Vec::with_capacity(n);
    let mut color: [Vec<u16>; 4] = std::array::from_fn(|_| Vec::with_capacity(n));
    let mut last = [0u8; 4];
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            tsdf.push(zigzag(block.tsdf[i].wrapping_sub(predict_tsdf(&block.tsdf, nb))));
            weight.push(zigzag(block.weight[i].wrapping_sub(predict_weight(&block.weight, nb)) as i16));
            let c = block.color[i];
            out.put((c != [0; 4]) as u64, 1);
            if c != [0; 4] {
                let p = predict_color(&block.color, nb, last);
                for (plane, (&c, p)) in color.iter_mut().zip(c.iter().zip(p)) {
                    plane.push(zigzag(c.wrapping_sub(p) as i8 as i16));
                }
                last = c;
            }
        }
    }
    for section in [&tsdf, &weight, &color[0], &color[1], &color[2], &color[3]] {
        rice::put_section(&mut out, section);
    }
    out.finish()
}

/// The observed mask's runs as [`residuals`] codes them: the lengths of alternating runs of
/// unobserved and observed voxels in index order, the first (unobserved, maybe empty) as is,
/// the others minus one.
fn mask_runs(mask: &[u64; CHUNK_VOXELS / 64]) -> Vec<u16> {
    let mut runs = Vec::new();
    let (mut state, mut len) = (false, 0u16);
    for i in 0..CHUNK_VOXELS {
        if coded(mask, i) != state {
            runs.push(if runs.is_empty() { len } else { len - 1 });
            (state, len) = (!state, 0);
        }
        len += 1;
    }
    runs.push(if runs.is_empty() { len } else { len - 1 });
    runs
}

/// Inverts [`mask_runs`].
fn mask_from_runs(runs: &[u16]) -> Result<[u64; CHUNK_VOXELS / 64], PackError> {
    let mut mask = [0u64; CHUNK_VOXELS / 64];
    let mut at = 0usize;
    for (k, &r) in runs.iter().enumerate() {
        let len = r as usize + (k > 0) as usize;
        if at + len > CHUNK_VOXELS {
            return Err(PackError::Malformed("mask runs longer than a chunk"));
        }
        if k % 2 == 1 {
            for i in at..at + len {
                mask[i / 64] |= 1 << (i % 64);
            }
        }
        at += len;
    }
    if at != CHUNK_VOXELS {
        return Err(PackError::Malformed("mask runs shorter than a chunk"));
    }
    Ok(mask)
}

/// Inverts [`residuals`] into `block`; voxels outside the mask become all zeros.
fn decode(s: &[u8], dense: bool, block: &mut VoxelBlock) -> Result<(), PackError> {
    let mut r = BitReader::new(s);
    let mask = if dense {
        [u64::MAX; CHUNK_VOXELS / 64]
    } else {
        let count = r.get(RUN_COUNT_BITS)? as usize;
        if count == 0 || count > CHUNK_VOXELS {
            return Err(PackError::Malformed("mask run count out of range"));
        }
        let mut runs = [0u16; CHUNK_VOXELS];
        rice::get_section(&mut r, &mut runs[..count])?;
        mask_from_runs(&runs[..count])?
    };
    let mask = &mask;
    let n = mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
    let mut coloured = [false; CHUNK_VOXELS];
    for group in coloured[..n].chunks_mut(32) {
        let bits = r.get(group.len() as u32)?;
        for (j, c) in group.iter_mut().enumerate() {
            *c = (bits >> j) & 1 == 1;
        }
    }
    let m = coloured.iter().filter(|&&c| c).count();
    let (mut tsdf, mut weight) = ([0u16; CHUNK_VOXELS], [0u16; CHUNK_VOXELS]);
    let mut color = [[0u16; CHUNK_VOXELS]; 4];
    rice::get_section(&mut r, &mut tsdf[..n])?;
    rice::get_section(&mut r, &mut weight[..n])?;
    for plane in &mut color {
        rice::get_section(&mut r, &mut plane[..m])?;
    }
    if !r.at_end() {
        return Err(PackError::Malformed("residual stream longer than its voxels"));
    }
    block.tsdf.fill(0);
    block.weight.fill(0);
    block.color.fill([0; 4]);
    let (mut k, mut c, mut last) = (0, 0, [0u8; 4]);
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            block.tsdf[i] = unzigzag(tsdf[k]).wrapping_add(predict_tsdf(&block.tsdf, nb));
            block.weight[i] = (unzigzag(weight[k]) as u16).wrapping_add(predict_weight(&block.weight, nb));
            if !dense && block.weight[i] == 0 {
                // A sparse chunk codes observed voxels only: the bytes were altered.
                return Err(PackError::Malformed("an observed voxel decoded with weight 0"));
            }
            if coloured[k] {
                let p = predict_color(&block.color, nb, last);
                let mut v = [0u8; 4];
                for (ch, v) in v.iter_mut().enumerate() {
                    let r = unzigzag(color[ch][c]);
                    if !(-128..=127).contains(&r) {
                        return Err(PackError::Malformed("colour residual out of range"));
                    }
                    *v = (r as i8 as u8).wrapping_add(p[ch]);
                }
                if v == [0; 4] {
                    // A colour marked present decodes to none: the bytes were altered.
                    return Err(PackError::Malformed("a coloured voxel decoded without colour"));
                }
                block.color[i] = v;
                last = v;
                c += 1;
            }
            k += 1;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn empty() -> Box<VoxelBlock> {
        VoxelBlock::empty()
    }

    /// A chunk like fusion makes: a plane's band observed, the rest zero.
    fn banded(rng: &mut ChaCha8Rng) -> Box<VoxelBlock> {
        let mut b = empty();
        let (nx, ny, d) = (rng.random_range(-1.0f32..1.0), rng.random_range(-1.0f32..1.0), rng.random_range(0.0..8.0));
        for i in 0..CHUNK_VOXELS {
            let (x, y, z) = ((i % 8) as f32, ((i / 8) % 8) as f32, (i / 64) as f32);
            let s = (z + nx * x + ny * y - d) / 4.0;
            if s.abs() < 1.0 {
                b.tsdf[i] = (s * 32767.0 + rng.random_range(-300.0..300.0)).clamp(-32767.0, 32767.0) as i16;
                b.weight[i] = if rng.random_range(0..4) == 0 { rng.random_range(1..u16::MAX) } else { 64 * 256 };
                b.color[i] = [rng.random(), 128, rng.random_range(100..110), rng.random()];
            }
        }
        b
    }

    fn round_trip(b: &VoxelBlock) -> usize {
        let packed = pack(b);
        let mut out = empty();
        out.tsdf.fill(7);
        unpack_into(&packed, &mut out).expect("own pack decodes");
        assert_eq!(&*out, b, "bit-exact round trip");
        packed.len()
    }

    #[test]
    fn random_chunks_round_trip_bit_exact() {
        let mut rng = ChaCha8Rng::seed_from_u64(20);
        for _ in 0..200 {
            round_trip(&banded(&mut rng));
        }
        // Noise everywhere, every field extreme, and an unobserved voxel with data (dense).
        for _ in 0..50 {
            let mut b = empty();
            for i in 0..CHUNK_VOXELS {
                if rng.random_range(0..3) > 0 {
                    b.tsdf[i] = rng.random();
                    b.weight[i] = rng.random_range(1..=u16::MAX);
                    b.color[i] = rng.random();
                }
            }
            round_trip(&b);
            b.weight[3] = 0;
            b.color[3] = [1, 2, 3, 4];
            round_trip(&b);
        }
        assert!(round_trip(&empty()) < 100);
        let mut full = empty();
        full.tsdf.fill(i16::MIN);
        full.weight.fill(u16::MAX);
        full.color.fill([255; 4]);
        round_trip(&full);
    }

    #[test]
    fn banded_chunks_pack_small() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let b = banded(&mut rng);
        let observed = b.weight.iter().filter(|&&w| w != 0).count();
        let size = round_trip(&b);
        assert!(size < 8 * observed, "{size} bytes for {observed} observed voxels");
    }

    #[test]
    fn uncoloured_voxels_cost_a_bit_and_colours_need_no_neighbour() {
        // Fusion colours only a layer at the surface: voxels outside it are not coded.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut b = banded(&mut rng);
        let with_all = round_trip(&b);
        b.color.iter_mut().for_each(|c| *c = [0; 4]);
        let with_none = round_trip(&b);
        let observed = b.weight.iter().filter(|&&w| w != 0).count();
        // Colour of every observed voxel costs more than a bit each; none costs about a bit.
        assert!(with_all > with_none + observed / 8, "{with_all} vs {with_none}");
        // A lone coloured voxel, no coloured neighbour: predicted from zero, still exact.
        b.color[200] = [9, 8, 7, 1];
        b.weight[200] = 5;
        round_trip(&b);
    }

    #[test]
    fn damaged_bytes_are_errors_not_panics() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let packed = pack(&banded(&mut rng));
        let mut out = empty();
        for n in 0..packed.len() {
            assert!(unpack_into(&packed[..n], &mut out).is_err(), "truncated to {n} bytes");
        }
        // Flipped bytes: an error or some block, never a panic.
        for k in 0..packed.len() {
            let mut bad = packed.to_vec();
            bad[k] ^= 0x5a;
            let _ = unpack_into(&bad, &mut out);
        }
        assert_eq!(unpack_into(&[0xff], &mut out), Err(PackError::Malformed("unknown flags")));
    }
}

#[cfg(test)]
mod speed {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    #[ignore = "timing probe, run by hand"]
    fn pack_unpack_speed() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut b = VoxelBlock::empty();
        for i in 0..CHUNK_VOXELS {
            if rng.random_range(0..4) > 0 {
                b.tsdf[i] = rng.random_range(-2000..2000) + (i as i16) * 40;
                b.weight[i] = rng.random_range(1..16000);
                b.color[i] = [rng.random_range(100..120), 50, 60, rng.random_range(10..40)];
            }
        }
        let n = 2000;
        let t = std::time::Instant::now();
        let mut p = pack(&b);
        for _ in 0..n {
            p = pack(std::hint::black_box(&b));
        }
        let pack_us = t.elapsed().as_secs_f64() * 1e6 / n as f64;
        let mut out = VoxelBlock::empty();
        let t = std::time::Instant::now();
        for _ in 0..n {
            unpack_into(std::hint::black_box(&p), &mut out).expect("decodes");
        }
        let unpack_us = t.elapsed().as_secs_f64() * 1e6 / n as f64;
        println!("pack {pack_us:.1} us, unpack {unpack_us:.1} us, {} bytes", p.len());
    }
}
