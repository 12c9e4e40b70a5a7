//! Lossless packing of one chunk's voxels for chunks that fusion has not touched for a while
//! ("cold" chunks): the in-memory form of a cold chunk, and the payload of a spill-file
//! record.
//!
//! Why this layout: in a scan most voxels of an allocated chunk are never observed (the band
//! around a surface crosses a chunk obliquely), and an unobserved voxel is all zeros. So a
//! packed chunk is a 512-bit observed mask plus only the observed voxels, field by field.
//! Each field is predicted from already-coded neighbours and only the residual is stored as a
//! variable-length integer: the signed distance is nearly linear in position near a surface,
//! so the planar predictor `left + below - below-left` leaves sensor noise only; weights and
//! colours change little between neighbours, so the left neighbour predicts them. Fusion
//! colours only the voxels near the surface ([`crate::TsdfConfig::color_band_voxels`]), so a
//! bit per observed voxel says which have a colour, and only those are coded, each predicted
//! from a coloured neighbour: an uncoloured voxel costs a bit instead of four residuals, and
//! the edge of the coloured layer no jump from or to zero. The residual stream then goes
//! through LZ4 (fast, pure Rust), which folds the long runs of equal residuals (capped
//! weights, saturated colour counts, flat colours).
//!
//! Lossless for every input: a chunk with an unobserved voxel that is not all zeros (which
//! fusion never makes, but a caller of the map could) is packed densely, all 512 voxels.
//!
//! Layout: `[flags u8] [mask 64 bytes, sparse only] [stream length u16] [stream, LZ4 or raw]`;
//! the stream is described at `residuals`.

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
/// Bytes of the observed mask.
const MASK_BYTES: usize = CHUNK_VOXELS / 8;
/// Longest residual stream: two section lengths, then per voxel at most 3 bytes of
/// distance, 3 of weight, a bit saying whether it has a colour and 4 bytes of colour.
const MAX_STREAM: usize = 4 + CHUNK_VOXELS * 10 + CHUNK_VOXELS / 8;

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
    let stream = residuals(block, &mask);
    let compressed = lz4_flex::block::compress(&stream);
    let (flags, body) = if compressed.len() < stream.len() { (LZ4, &compressed) } else { (0, &stream) };
    let flags = flags | if dense { DENSE } else { 0 };
    let mut out = Vec::with_capacity(1 + MASK_BYTES + 2 + body.len());
    out.push(flags);
    if !dense {
        for w in mask {
            out.extend_from_slice(&w.to_le_bytes());
        }
    }
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
    let (mask, rest) = if flags & DENSE != 0 {
        ([u64::MAX; CHUNK_VOXELS / 64], rest)
    } else {
        let (m, rest) = rest.split_at_checked(MASK_BYTES).ok_or_else(truncated)?;
        let mut mask = [0u64; CHUNK_VOXELS / 64];
        for (w, b) in mask.iter_mut().zip(m.chunks_exact(8)) {
            let mut word = [0u8; 8];
            word.copy_from_slice(b);
            *w = u64::from_le_bytes(word);
        }
        (mask, rest)
    };
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
    decode(stream, &mask, block)
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

/// Planar prediction of a distance: exact for a field linear in x and y.
#[inline]
fn predict_tsdf(t: &[i16; CHUNK_VOXELS], n: Neighbours) -> i16 {
    match (n.left, n.below, n.below_left) {
        (Some(a), Some(b), Some(c)) => (t[a] as i32 + t[b] as i32 - t[c] as i32) as i16,
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

/// Appends `v` in 7-bit groups, low first, the top bit saying "more follows".
#[inline]
fn put_varint(out: &mut Vec<u8>, mut v: u16) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Reads what [`put_varint`] wrote.
#[inline]
fn get_varint(s: &[u8], pos: &mut usize) -> Result<u16, PackError> {
    let mut v = 0u32;
    for shift in [0, 7, 14] {
        let b = *s.get(*pos).ok_or(PackError::Malformed("residual stream ends early"))?;
        *pos += 1;
        v |= ((b & 0x7f) as u32) << shift;
        if b & 0x80 == 0 {
            return u16::try_from(v).map_err(|_| PackError::Malformed("residual out of range"));
        }
    }
    Err(PackError::Malformed("residual longer than 3 bytes"))
}

/// The residual stream: the byte lengths of the distance and weight sections (u16 each),
/// then distances and weights over the coded voxels in index order, a bit per coded voxel
/// (low bit first) set when its colour is not all zeros, and the four colour bytes of those
/// voxels (sections apart, so equal residuals sit together for LZ4). One pass over the
/// voxels fills all seven sections.
fn residuals(block: &VoxelBlock, mask: &[u64; CHUNK_VOXELS / 64]) -> Vec<u8> {
    let n = mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
    let mut tsdf = Vec::with_capacity(2 * n);
    let mut weight = Vec::with_capacity(2 * n);
    let mut coloured = vec![0u8; n.div_ceil(8)];
    let mut color = [Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n)];
    let (mut k, mut last) = (0, [0u8; 4]);
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            put_varint(&mut tsdf, zigzag(block.tsdf[i].wrapping_sub(predict_tsdf(&block.tsdf, nb))));
            put_varint(&mut weight, zigzag(block.weight[i].wrapping_sub(predict_weight(&block.weight, nb)) as i16));
            let c = block.color[i];
            if c != [0; 4] {
                coloured[k / 8] |= 1 << (k % 8);
                let p = predict_color(&block.color, nb, last);
                for (plane, (&c, p)) in color.iter_mut().zip(c.iter().zip(p)) {
                    plane.push(c.wrapping_sub(p));
                }
                last = c;
            }
            k += 1;
        }
    }
    let m = color[0].len();
    let mut out = Vec::with_capacity(4 + tsdf.len() + weight.len() + coloured.len() + 4 * m);
    // Each section is at most 3 bytes a voxel, 1536 bytes: the lengths fit in u16.
    out.extend_from_slice(&(tsdf.len() as u16).to_le_bytes());
    out.extend_from_slice(&(weight.len() as u16).to_le_bytes());
    out.extend_from_slice(&tsdf);
    out.extend_from_slice(&weight);
    out.extend_from_slice(&coloured);
    for c in &color {
        out.extend_from_slice(c);
    }
    out
}

/// Inverts [`residuals`] into `block`; voxels outside `mask` become all zeros.
fn decode(s: &[u8], mask: &[u64; CHUNK_VOXELS / 64], block: &mut VoxelBlock) -> Result<(), PackError> {
    let short = PackError::Malformed("residual stream ends early");
    let n = mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
    let (lens, rest) = s.split_at_checked(4).ok_or(short.clone())?;
    let (tsdf_len, weight_len) =
        (u16::from_le_bytes([lens[0], lens[1]]) as usize, u16::from_le_bytes([lens[2], lens[3]]) as usize);
    let (tsdf, rest) = rest.split_at_checked(tsdf_len).ok_or(short.clone())?;
    let (weight, rest) = rest.split_at_checked(weight_len).ok_or(short.clone())?;
    let (coloured, colors) = rest.split_at_checked(n.div_ceil(8)).ok_or(short.clone())?;
    let m = coloured.iter().map(|b| b.count_ones() as usize).sum::<usize>();
    if colors.len() != 4 * m {
        return Err(if colors.len() < 4 * m {
            short
        } else {
            PackError::Malformed("residual stream longer than its voxels")
        });
    }
    let color: [&[u8]; 4] = [&colors[..m], &colors[m..2 * m], &colors[2 * m..3 * m], &colors[3 * m..]];
    block.tsdf.fill(0);
    block.weight.fill(0);
    block.color.fill([0; 4]);
    let dense = mask == &[u64::MAX; CHUNK_VOXELS / 64];
    let (mut pt, mut pw, mut k, mut c, mut last) = (0, 0, 0, 0, [0u8; 4]);
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            let r = unzigzag(get_varint(tsdf, &mut pt)?);
            block.tsdf[i] = r.wrapping_add(predict_tsdf(&block.tsdf, nb));
            let r = unzigzag(get_varint(weight, &mut pw)?);
            block.weight[i] = (r as u16).wrapping_add(predict_weight(&block.weight, nb));
            if !dense && block.weight[i] == 0 {
                // A sparse chunk codes observed voxels only: the bytes were altered.
                return Err(PackError::Malformed("an observed voxel decoded with weight 0"));
            }
            if coloured[k / 8] & (1 << (k % 8)) != 0 {
                let p = predict_color(&block.color, nb, last);
                let v: [u8; 4] = std::array::from_fn(|ch| color[ch][c].wrapping_add(p[ch]));
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
    if n % 8 != 0 && coloured.last().is_some_and(|&b| b >> (n % 8) != 0) {
        return Err(PackError::Malformed("colour bits past the last voxel"));
    }
    if pt != tsdf.len() || pw != weight.len() {
        return Err(PackError::Malformed("residual sections longer than their voxels"));
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
