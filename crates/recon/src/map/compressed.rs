//! Packing of one chunk's voxels for chunks that fusion has not touched for a while
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
//! Lossless for every input with [`DistanceCoding::EXACT`]: a chunk with an unobserved voxel
//! that is not all zeros (which fusion never makes, but a caller of the map could) is packed
//! densely, all 512 voxels. With a coarse [`DistanceCoding`] (the map's default, see
//! [`crate::TsdfConfig::packed_far_step_voxels`]) the distances of voxels far from the surface
//! are stored in coarser steps: meshing, tracking's raycast and the labels read distances only
//! near zero crossings, and in the far part of the band the sensor's noise is what the
//! finest steps spend their bits on. Coding stays closed-loop (predictions read the values
//! as decoded), so packing a decoded chunk again gives the same bytes and the same voxels:
//! a chunk that goes cold, comes back and goes cold again moves only where fusion changed it.
//!
//! Layout: `[flags u8] [stream length u16] [stream, LZ4 or raw]`; the stream, which holds
//! the observed mask as run lengths (sparse chunks only), is described at `residuals`.

use super::rice::{self, BitReader, BitWriter};
use super::{VoxelBlock, CHUNK_SIDE, CHUNK_VOXELS, TSDF_SCALE};

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
/// Flag bit: distances far from the surface are coarse; the layout's header then carries the
/// [`DistanceCoding`] (two `u16`, little-endian) after the stream length.
const COARSE: u8 = 4;

/// How a packed chunk stores distances: exactly, or, where the prediction from already-coded
/// neighbours is at least `exact_below` from zero (in stored units), in steps of `far_step`.
///
/// In a coarse context a voxel whose distance is itself at least `exact_below` (and a valid
/// distance, at most [`crate::map::TSDF_SCALE`]) is stored to the nearest step from the
/// prediction that is also at least `exact_below` from zero: within half a step (a step at
/// the band's edge), on the same side of zero; any other voxel is stored exactly, with a code
/// above every step's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct DistanceCoding {
    /// Distances nearer to zero than this are exact.
    pub exact_below: u16,
    /// Step of the far distances (1: exact everywhere).
    pub far_step: u16,
}

impl DistanceCoding {
    /// Every distance exact.
    pub(crate) const EXACT: Self = Self { exact_below: u16::MAX, far_step: 1 };

    fn is_exact(self) -> bool {
        self.far_step <= 1
    }
}
/// Bits of the number of runs of the observed mask (at most 512).
const RUN_COUNT_BITS: u32 = 10;
/// Longest residual stream: the mask's runs (one per voxel at most) and per voxel a bit
/// saying whether it has a colour and six values (distance, weight, four colour bytes), each
/// value of at most [`rice::MAX_VALUE_BITS`], and seven section headers. Below 2^16, so its
/// length fits the `u16` of the layout.
const MAX_STREAM: usize =
    (RUN_COUNT_BITS as usize + CHUNK_VOXELS * (1 + 7 * rice::MAX_VALUE_BITS) + 7 * rice::SECTION_BITS).div_ceil(8);

/// Packs `block`, its distances coded as `coding` says (see the module documentation).
pub(crate) fn pack(block: &VoxelBlock, coding: DistanceCoding) -> Box<[u8]> {
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
    // Coarse coding is for fusion's distances, within +-TSDF_SCALE; a chunk holding anything
    // else (which fusion never makes) is packed exactly.
    let valid = |t: i16| (t as i32).unsigned_abs() <= TSDF_SCALE as u32;
    let coding = if coding.is_exact() || block.tsdf.iter().all(|&t| valid(t)) { coding } else { DistanceCoding::EXACT };
    let stream = residuals(block, &mask, dense, coding);
    let compressed = lz4_flex::block::compress(&stream);
    let (flags, body) = if compressed.len() < stream.len() { (LZ4, &compressed) } else { (0, &stream) };
    let flags = flags | if dense { DENSE } else { 0 } | if coding.is_exact() { 0 } else { COARSE };
    let mut out = Vec::with_capacity(1 + 2 + 4 + body.len());
    out.push(flags);
    // MAX_STREAM < 2^16, so the raw length always fits.
    out.extend_from_slice(&(stream.len() as u16).to_le_bytes());
    if !coding.is_exact() {
        out.extend_from_slice(&coding.exact_below.to_le_bytes());
        out.extend_from_slice(&coding.far_step.to_le_bytes());
    }
    out.extend_from_slice(body);
    out.into_boxed_slice()
}

/// Unpacks bytes made by [`pack`] into `block` (every voxel written).
pub(crate) fn unpack_into(bytes: &[u8], block: &mut VoxelBlock) -> Result<(), PackError> {
    let truncated = || PackError::Truncated(bytes.len());
    let (&flags, rest) = bytes.split_first().ok_or_else(truncated)?;
    if flags & !(LZ4 | DENSE | COARSE) != 0 {
        return Err(PackError::Malformed("unknown flags"));
    }
    let (len, mut body) = rest.split_at_checked(2).ok_or_else(truncated)?;
    let len = u16::from_le_bytes([len[0], len[1]]) as usize;
    let mut coding = DistanceCoding::EXACT;
    if flags & COARSE != 0 {
        let (c, b) = body.split_at_checked(4).ok_or_else(truncated)?;
        coding = DistanceCoding {
            exact_below: u16::from_le_bytes([c[0], c[1]]),
            far_step: u16::from_le_bytes([c[2], c[3]]),
        };
        if coding.is_exact() {
            return Err(PackError::Malformed("coarse distances with a step of 1"));
        }
        body = b;
    }
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
    decode(stream, flags & DENSE != 0, coding, block)
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

/// Whether a voxel predicted `pred` is coded in a coarse context.
#[inline]
fn coarse_context(pred: i16, coding: DistanceCoding) -> bool {
    (pred as i32).unsigned_abs() >= coding.exact_below as u32
}

/// Whether distance `v` in a coarse context is stored in steps.
#[inline]
fn coarse_value(v: i16, coding: DistanceCoding) -> bool {
    let a = (v as i32).unsigned_abs();
    a >= coding.exact_below as u32 && a <= TSDF_SCALE as u32
}

/// The first code of an exact residual in a coarse context: every step code is below it
/// (steps from a prediction within 3 x TSDF_SCALE to a distance within TSDF_SCALE).
#[inline]
fn exact_code_base(coding: DistanceCoding) -> u16 {
    let most_steps = 4 * TSDF_SCALE as u32 / coding.far_step.max(2) as u32 + 1;
    (2 * most_steps + 2) as u16
}

/// The distance `r` steps from `pred`, kept within the valid distances.
#[inline]
fn coarse_reconstruction(pred: i16, r: i32, coding: DistanceCoding) -> i16 {
    let limit = TSDF_SCALE as i32;
    (pred as i32 + r * coding.far_step as i32).clamp(-limit, limit) as i16
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
fn residuals(block: &VoxelBlock, mask: &[u64; CHUNK_VOXELS / 64], dense: bool, coding: DistanceCoding) -> Vec<u8> {
    let n = mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
    let mut out = BitWriter::with_capacity(n.div_ceil(8) + 64);
    if !dense {
        let runs = mask_runs(mask);
        out.put(runs.len() as u64, RUN_COUNT_BITS);
        rice::put_section(&mut out, &runs);
    }
    let mut tsdf = Vec::with_capacity(n);
    // Coarse contexts' codes, a section of their own: their steps are a few units wide where
    // the exact residuals near the surface are hundreds.
    let mut far = Vec::new();
    let mut weight = Vec::with_capacity(n);
    let mut color: [Vec<u16>; 4] = std::array::from_fn(|_| Vec::with_capacity(n));
    let mut last = [0u8; 4];
    // The distances as the decoder will see them (closed loop): predictions read these.
    let mut decoded = block.tsdf;
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            let pred = predict_tsdf(&decoded, nb);
            let v = block.tsdf[i];
            if coding.is_exact() || !coarse_context(pred, coding) {
                tsdf.push(zigzag(v.wrapping_sub(pred)));
            } else if coarse_value(v, coding) {
                let d = v as i32 - pred as i32;
                let step = coding.far_step as i32;
                let mut r = (d + step / 2).div_euclid(step);
                if !coarse_value(coarse_reconstruction(pred, r, coding), coding) {
                    // Rounded into the exact band: one step further out, so that the value
                    // stays coarse and packing the decoded chunk again changes nothing.
                    r += (v as i32).signum();
                }
                decoded[i] = coarse_reconstruction(pred, r, coding);
                far.push(zigzag(r as i16));
            } else {
                // An exact residual in a coarse context, above every step code. Coarse
                // chunks hold valid distances only (`pack`): a prediction is within
                // 3 x TSDF_SCALE, a residual's zigzag within 15 bits.
                far.push(exact_code_base(coding) + zigzag(v.wrapping_sub(pred)));
            }
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
    if !coding.is_exact() {
        out.put(far.len() as u64, RUN_COUNT_BITS);
    }
    rice::put_section(&mut out, &tsdf);
    if !coding.is_exact() {
        rice::put_section(&mut out, &far);
    }
    for section in [&weight, &color[0], &color[1], &color[2], &color[3]] {
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
fn decode(s: &[u8], dense: bool, coding: DistanceCoding, block: &mut VoxelBlock) -> Result<(), PackError> {
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
    let n_far = if coding.is_exact() { 0 } else { r.get(RUN_COUNT_BITS)? as usize };
    if n_far > n {
        return Err(PackError::Malformed("more coarse distances than voxels"));
    }
    let mut far = [0u16; CHUNK_VOXELS];
    rice::get_section(&mut r, &mut tsdf[..n - n_far])?;
    if !coding.is_exact() {
        rice::get_section(&mut r, &mut far[..n_far])?;
    }
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
    let (mut k_near, mut k_far) = (0, 0);
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let i = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let nb = Neighbours::of(mask, i);
            let pred = predict_tsdf(&block.tsdf, nb);
            block.tsdf[i] = if coding.is_exact() || !coarse_context(pred, coding) {
                let v = *tsdf[..n - n_far].get(k_near).ok_or(PackError::Malformed("too few exact distances"))?;
                k_near += 1;
                unzigzag(v).wrapping_add(pred)
            } else {
                let v = *far[..n_far].get(k_far).ok_or(PackError::Malformed("too few coarse distances"))?;
                k_far += 1;
                let base = exact_code_base(coding);
                if v >= base {
                    unzigzag(v - base).wrapping_add(pred)
                } else {
                    coarse_reconstruction(pred, unzigzag(v) as i32, coding)
                }
            };
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
    if k_near + k_far != n || k_far != n_far {
        return Err(PackError::Malformed("coarse distance count does not match the voxels"));
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
        let packed = pack(b, DistanceCoding::EXACT);
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

    /// A chunk like fusion makes at 5 mm with a 10-voxel band: distances within
    /// +-TSDF_SCALE, noisy far out.
    fn fused(rng: &mut ChaCha8Rng) -> Box<VoxelBlock> {
        let mut b = empty();
        let (nx, ny, d) = (rng.random_range(-1.0f32..1.0), rng.random_range(-1.0f32..1.0), rng.random_range(0.0..8.0));
        for i in 0..CHUNK_VOXELS {
            let (x, y, z) = ((i % 8) as f32, ((i / 8) % 8) as f32, (i / 64) as f32);
            let voxels = z + nx * x + ny * y - d;
            if voxels.abs() < 10.0 {
                let noise = rng.random_range(-1.0..1.0);
                let t = ((voxels + noise) / 10.0).clamp(-1.0, 1.0) * TSDF_SCALE;
                b.tsdf[i] = t.round() as i16;
                b.weight[i] = if rng.random_range(0..8) == 0 { rng.random_range(1..64 * 16) } else { 64 * 16 };
                if voxels.abs() < 4.0 {
                    b.color[i] = [rng.random_range(90..110), 128, rng.random_range(100..110), rng.random_range(1..200)];
                }
            }
        }
        b
    }

    /// The 5 mm default: exact within 3 voxels, steps of 0.2 voxels beyond (10-voxel band).
    const COARSE_CODING: DistanceCoding = DistanceCoding { exact_below: 614, far_step: 41 };

    #[test]
    fn coarse_distances_stay_within_half_a_step_far_out_and_exact_near_the_surface() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let (mut exact_bytes, mut coarse_bytes, mut moved) = (0, 0, 0);
        for _ in 0..200 {
            let b = fused(&mut rng);
            let packed = pack(&b, COARSE_CODING);
            let mut out = empty();
            unpack_into(&packed, &mut out).expect("own pack decodes");
            assert_eq!((out.weight, out.color), (b.weight, b.color), "weights and colours exact");
            for i in 0..CHUNK_VOXELS {
                let (v, w) = (b.tsdf[i] as i32, out.tsdf[i] as i32);
                if v.abs() < COARSE_CODING.exact_below as i32 {
                    assert_eq!(w, v, "near the surface: exact");
                } else {
                    let half = COARSE_CODING.far_step as i32 / 2;
                    let step = COARSE_CODING.far_step as i32;
                    let bound = if w.abs() < 614 + step { step } else { half };
                    assert!((w - v).abs() <= bound, "{v} -> {w}");
                    assert!(w.signum() == v.signum() && w.abs() >= 614, "{v} -> {w}");
                }
                moved += (w != v) as usize;
            }
            // Closed loop: packing the decoded chunk again gives the same bytes.
            assert_eq!(pack(&out, COARSE_CODING), packed, "repacking is idempotent");
            exact_bytes += pack(&b, DistanceCoding::EXACT).len();
            coarse_bytes += packed.len();
        }
        assert!(moved > 1000, "the far distances were coarsened ({moved} voxels)");
        // (On fused scans the saving is larger: docs/benchmarks_log.md, "Session 22".)
        assert!(coarse_bytes < exact_bytes, "{coarse_bytes} against {exact_bytes} bytes");
    }

    #[test]
    fn chunks_fusion_never_makes_pack_exactly_under_coarse_coding() {
        // Distances beyond +-TSDF_SCALE: the chunk falls back to exact coding.
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        for _ in 0..20 {
            let b = banded(&mut rng);
            let packed = pack(&b, COARSE_CODING);
            let mut out = empty();
            unpack_into(&packed, &mut out).expect("decodes");
            assert_eq!(&*out, &*b);
        }
    }

    #[test]
    fn damaged_bytes_are_errors_not_panics() {
        let mut out = empty();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let exact = pack(&banded(&mut rng), DistanceCoding::EXACT);
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let coarse = pack(&fused(&mut rng), COARSE_CODING);
        assert_ne!(coarse[0] & COARSE, 0);
        for packed in [exact, coarse] {
            for n in 0..packed.len() {
                assert!(unpack_into(&packed[..n], &mut out).is_err(), "truncated to {n} bytes");
            }
            // Flipped bytes: an error or some block, never a panic.
            for k in 0..packed.len() {
                let mut bad = packed.to_vec();
                bad[k] ^= 0x5a;
                let _ = unpack_into(&bad, &mut out);
            }
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
                b.tsdf[i] = rng.random_range(-400..400) + (i as i16 % 64) * 40 - 1200;
                b.weight[i] = rng.random_range(1..16000);
                b.color[i] = [rng.random_range(100..120), 50, 60, rng.random_range(10..40)];
            }
        }
        let n = 2000;
        for (name, coding) in
            [("exact", DistanceCoding::EXACT), ("coarse", DistanceCoding { exact_below: 614, far_step: 41 })]
        {
            let t = std::time::Instant::now();
            let mut p = pack(&b, coding);
            for _ in 0..n {
                p = pack(std::hint::black_box(&b), coding);
            }
            let pack_us = t.elapsed().as_secs_f64() * 1e6 / n as f64;
            let mut out = VoxelBlock::empty();
            let t = std::time::Instant::now();
            for _ in 0..n {
                unpack_into(std::hint::black_box(&p), &mut out).expect("decodes");
            }
            let unpack_us = t.elapsed().as_secs_f64() * 1e6 / n as f64;
            println!("{name}: pack {pack_us:.1} us, unpack {unpack_us:.1} us, {} bytes", p.len());
        }
    }
}
