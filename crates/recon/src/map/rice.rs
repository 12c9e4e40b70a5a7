//! Rice codes, the entropy coder of packed chunks ([`super::compressed`]).
//!
//! Why Rice codes: a packed chunk's residuals (distance, weight and colour after
//! prediction) are small numbers spread like a two-sided exponential, whose width differs
//! from chunk to chunk and field to field. A Rice code with parameter `k` writes `v >> k` in
//! unary and the low `k` bits plainly: within a fraction of a bit of the entropy of such a
//! distribution when `k` fits its width, with no table to store (one 4-bit `k` per section)
//! and a few instructions per value. Byte-aligned variable-length integers, which this
//! replaced, spend at least 8 bits on a residual worth 4 to 6, and LZ4 after them finds
//! repeats, not skewed symbol frequencies.
//!
//! A quotient of [`ESCAPE`] or more is written as [`ESCAPE`] ones and the value in 16 bits,
//! so that an outlier costs 40 bits, not thousands. Bits go least significant first.

use super::compressed::PackError;

/// Quotients from this on are escaped (the value follows in 16 bits).
pub(super) const ESCAPE: u32 = 24;
/// Bits of a section's parameter `k` (0 to 15).
const K_BITS: u32 = 4;
/// Most bits one value costs: the escape's ones and 16 bits.
pub(super) const MAX_VALUE_BITS: usize = ESCAPE as usize + 16;
/// Bits of a section's header.
pub(super) const SECTION_BITS: usize = K_BITS as usize;

/// Appends bits to a byte vector, least significant first.
pub(super) struct BitWriter {
    bytes: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    pub(super) fn with_capacity(bytes: usize) -> Self {
        Self { bytes: Vec::with_capacity(bytes), acc: 0, n: 0 }
    }

    /// Appends the low `bits` bits of `value` (`bits` at most 32, higher bits of `value` 0).
    #[inline]
    pub(super) fn put(&mut self, value: u64, bits: u32) {
        debug_assert!(bits <= 32 && value >> bits == 0);
        // Fewer than 32 bits wait in `acc`, so 32 more fit.
        self.acc |= value << self.n;
        self.n += bits;
        if self.n >= 32 {
            self.bytes.extend_from_slice(&(self.acc as u32).to_le_bytes());
            self.acc >>= 32;
            self.n -= 32;
        }
    }

    /// The bytes, the last one padded with zero bits.
    pub(super) fn finish(mut self) -> Vec<u8> {
        let tail = self.acc.to_le_bytes();
        self.bytes.extend_from_slice(&tail[..self.n.div_ceil(8) as usize]);
        self.bytes
    }
}

/// Reads what a [`BitWriter`] wrote; reading past the end is an error.
pub(super) struct BitReader<'a> {
    bytes: &'a [u8],
    /// Position in bits.
    pos: usize,
}

impl<'a> BitReader<'a> {
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0 }
    }

    /// The next 57 bits or more (zeros past the end), without consuming them.
    #[inline]
    fn window(&self) -> u64 {
        let at = self.pos / 8;
        let word = match self.bytes.get(at..at + 8) {
            Some(b) => u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
            // The last 7 bytes, and past the end: zeros beyond.
            None => {
                let mut word = [0u8; 8];
                let tail = self.bytes.get(at..).unwrap_or(&[]);
                word[..tail.len()].copy_from_slice(tail);
                u64::from_le_bytes(word)
            }
        };
        word >> (self.pos % 8)
    }

    #[inline]
    fn consume(&mut self, bits: usize) -> Result<(), PackError> {
        self.pos += bits;
        if self.pos > 8 * self.bytes.len() {
            return Err(PackError::Malformed("residual stream ends early"));
        }
        Ok(())
    }

    /// The next `bits` bits (at most 32).
    #[inline]
    pub(super) fn get(&mut self, bits: u32) -> Result<u64, PackError> {
        let v = self.window() & ((1u64 << bits) - 1);
        self.consume(bits as usize)?;
        Ok(v)
    }

    /// Whether everything was read: at most 7 padding bits left, all zero.
    pub(super) fn at_end(&self) -> bool {
        let left = 8 * self.bytes.len() - self.pos;
        left < 8 && self.window() == 0
    }
}

/// Bits that the Rice code with parameter `k` spends on `values`.
fn cost(values: &[u16], k: u32) -> usize {
    values
        .iter()
        .map(|&v| {
            let q = (v as u32) >> k;
            if q < ESCAPE {
                (q + 1 + k) as usize
            } else {
                MAX_VALUE_BITS
            }
        })
        .sum()
}

/// The parameter that codes `values` in the fewest bits, among the three around the one that
/// fits their mean (the exact minimum for a geometric distribution is within one of it).
fn best_k(values: &[u16]) -> u32 {
    let n = values.len().max(1) as u64;
    let mean = values.iter().map(|&v| v as u64).sum::<u64>() / n;
    let guess = 64 - (mean + 1).leading_zeros() - 1;
    let lo = guess.saturating_sub(1);
    let hi = (guess + 1).min((1 << K_BITS) - 1);
    (lo..=hi).min_by_key(|&k| (cost(values, k), k)).unwrap_or(0)
}

/// Writes `values` as one section: its parameter, then each value's code.
pub(super) fn put_section(w: &mut BitWriter, values: &[u16]) {
    let k = best_k(values);
    w.put(k as u64, K_BITS);
    let low = (1u32 << k) - 1;
    for &v in values {
        let q = (v as u32) >> k;
        if q < ESCAPE {
            // q ones and the terminating zero in one go, then the low bits.
            w.put((1u64 << q) - 1, q + 1);
            w.put((v as u32 & low) as u64, k);
        } else {
            w.put((1u64 << ESCAPE) - 1, ESCAPE);
            w.put(v as u64, 16);
        }
    }
}

/// Reads a section that [`put_section`] wrote into `out` (as many values as `out` holds).
pub(super) fn get_section(r: &mut BitReader, out: &mut [u16]) -> Result<(), PackError> {
    let k = r.get(K_BITS)? as u32;
    for v in out {
        let q = r.window().trailing_ones().min(ESCAPE);
        if q < ESCAPE {
            r.consume(q as usize + 1)?;
            let low = r.get(k)? as u32;
            let value = (q << k) | low;
            *v = u16::try_from(value).map_err(|_| PackError::Malformed("residual out of range"))?;
        } else {
            r.consume(ESCAPE as usize)?;
            *v = r.get(16)? as u16;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The plain reference: the code of one value as a string of bits, first bit first.
    fn reference_bits(v: u16, k: u32) -> String {
        let q = (v as u32) >> k;
        if q < ESCAPE {
            let low: String = (0..k).map(|b| if (v >> b) & 1 == 1 { '1' } else { '0' }).collect();
            format!("{}0{low}", "1".repeat(q as usize))
        } else {
            let raw: String = (0..16).map(|b| if (v >> b) & 1 == 1 { '1' } else { '0' }).collect();
            format!("{}{raw}", "1".repeat(ESCAPE as usize))
        }
    }

    fn bits_of(bytes: &[u8], n: usize) -> String {
        (0..n).map(|i| if (bytes[i / 8] >> (i % 8)) & 1 == 1 { '1' } else { '0' }).collect()
    }

    #[test]
    fn sections_equal_the_reference_bits_and_round_trip() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for round in 0..200 {
            let n = rng.random_range(0..600);
            let width = rng.random_range(0..16u32);
            let values: Vec<u16> = (0..n)
                .map(|_| match rng.random_range(0..50) {
                    0 => rng.random(),
                    _ => rng.random_range(0..=(1u32 << width) as u16),
                })
                .collect();
            let mut w = BitWriter::with_capacity(0);
            put_section(&mut w, &values);
            let bytes = w.finish();
            let k = best_k(&values);
            let expected: String = format!(
                "{}{}",
                (0..K_BITS).map(|b| if (k >> b) & 1 == 1 { '1' } else { '0' }).collect::<String>(),
                values.iter().map(|&v| reference_bits(v, k)).collect::<String>()
            );
            assert_eq!(bits_of(&bytes, expected.len()), expected, "round {round}");
            assert_eq!(bytes.len(), expected.len().div_ceil(8));
            assert_eq!(expected.len(), SECTION_BITS + cost(&values, k));
            let mut out = vec![0u16; n];
            let mut r = BitReader::new(&bytes);
            get_section(&mut r, &mut out).expect("decodes");
            assert!(r.at_end());
            assert_eq!(out, values, "round {round}");
        }
    }

    #[test]
    fn the_chosen_parameter_is_the_cheapest() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..100 {
            let scale = rng.random_range(0.5f64..3000.0);
            // Two-sided exponential residuals, zigzagged, as prediction leaves them.
            let values: Vec<u16> = (0..400)
                .map(|_| {
                    let r = (-scale * rng.random_range(1e-9f64..1.0).ln()) as i32;
                    let r = if rng.random() { r } else { -r };
                    ((r << 1) ^ (r >> 31)).min(u16::MAX as i32) as u16
                })
                .collect();
            let best = (0..16).map(|k| cost(&values, k)).min().unwrap_or(0);
            assert_eq!(cost(&values, best_k(&values)), best, "scale {scale}");
        }
    }

    #[test]
    fn truncated_sections_are_errors() {
        let values: Vec<u16> = (0..100).map(|i| i * 37).collect();
        let mut w = BitWriter::with_capacity(0);
        put_section(&mut w, &values);
        let bytes = w.finish();
        for n in 0..bytes.len() {
            let mut out = vec![0u16; values.len()];
            assert!(get_section(&mut BitReader::new(&bytes[..n]), &mut out).is_err(), "{n} bytes");
        }
    }
}
