//! A minimal animated GIF writer for the AR view's preview (the `image` crate is built here
//! without its GIF codec). Colours are mapped to a fixed 6 x 7 x 6 colour cube (252
//! colours): coarse, but identical for every frame, so the animation does not flicker as
//! per-frame palettes would, and no quantiser is needed.

use std::collections::HashMap;

/// Encodes `frames` (each `width * height` sRGB pixels, row-major) as a looping GIF with
/// `delay_cs` hundredths of a second per frame.
///
/// # Shapes
/// Every frame is `width * height` long; `width` and `height` are below 65536.
pub fn encode(width: u16, height: u16, frames: &[Vec<[u8; 3]>], delay_cs: u16) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(b"GIF89a");
    out.extend_from_slice(&width.to_le_bytes());
    out.extend_from_slice(&height.to_le_bytes());
    // Global colour table of 256 entries (size field 7), 8 bits per primary.
    out.extend_from_slice(&[0xF7, 0, 0]);
    for i in 0..256u32 {
        let c = if i < 252 { [i / 42, (i / 6) % 7, i % 6] } else { [0, 0, 0] };
        out.extend_from_slice(&[(c[0] * 51) as u8, (c[1] * 255 / 6) as u8, (c[2] * 51) as u8]);
    }
    // NETSCAPE2.0 extension: loop for ever.
    out.extend_from_slice(&[0x21, 0xFF, 11]);
    out.extend_from_slice(b"NETSCAPE2.0");
    out.extend_from_slice(&[3, 1, 0, 0, 0]);
    for frame in frames {
        out.extend_from_slice(&[0x21, 0xF9, 4, 0]);
        out.extend_from_slice(&delay_cs.to_le_bytes());
        out.extend_from_slice(&[0, 0]);
        out.push(0x2C);
        out.extend_from_slice(&[0, 0, 0, 0]);
        out.extend_from_slice(&width.to_le_bytes());
        out.extend_from_slice(&height.to_le_bytes());
        out.push(0);
        let indices: Vec<u8> =
            frame.iter().enumerate().map(|(i, &c)| dithered_index(c, i % width as usize, i / width as usize)).collect();
        out.push(8);
        for block in lzw(&indices).chunks(255) {
            out.push(block.len() as u8);
            out.extend_from_slice(block);
        }
        out.push(0);
    }
    out.push(0x3B);
    out
}

/// Nearest entry of the colour cube (undithered).
#[cfg(test)]
fn palette_index(c: [u8; 3]) -> u8 {
    let q = |x: u8, levels: u32| ((x as u32 * (levels - 1) + 127) / 255) as u8;
    q(c[0], 6) * 42 + q(c[1], 7) * 6 + q(c[2], 6)
}

/// Colour cube entry with 4 x 4 ordered (Bayer) dithering: smooth shading becomes a fine
/// pattern instead of visible bands (the same pattern every frame, so nothing crawls).
fn dithered_index(c: [u8; 3], x: usize, y: usize) -> u8 {
    const BAYER: [u8; 16] = [0, 8, 2, 10, 12, 4, 14, 6, 3, 11, 1, 9, 15, 7, 13, 5];
    let t = (BAYER[(y % 4) * 4 + x % 4] as f32 + 0.5) / 16.0 - 0.5;
    let q = |v: u8, levels: u32| {
        let step = 255.0 / (levels - 1) as f32;
        ((v as f32 / step + t).round().clamp(0.0, (levels - 1) as f32)) as u8
    };
    q(c[0], 6) * 42 + q(c[1], 7) * 6 + q(c[2], 6)
}

/// GIF's variable-width LZW with 8-bit symbols, codes packed least significant bit first.
fn lzw(symbols: &[u8]) -> Vec<u8> {
    const CLEAR: u16 = 256;
    const END: u16 = 257;
    let mut bits = BitWriter::default();
    let mut dict: HashMap<(u16, u8), u16> = HashMap::new();
    let mut size = 9u32;
    let mut next = END + 1;
    bits.put(CLEAR, size);
    let Some((&first, rest)) = symbols.split_first() else {
        bits.put(END, size);
        return bits.finish();
    };
    let mut prefix = first as u16;
    for &s in rest {
        if let Some(&code) = dict.get(&(prefix, s)) {
            prefix = code;
            continue;
        }
        bits.put(prefix, size);
        if next < 4096 {
            dict.insert((prefix, s), next);
            // The decoder adds this entry one code later and then widens its codes: mirror it.
            if next == 1 << size {
                size += 1;
            }
            next += 1;
        } else {
            bits.put(CLEAR, size);
            dict.clear();
            size = 9;
            next = END + 1;
        }
        prefix = s as u16;
    }
    bits.put(prefix, size);
    // The decoder still adds an entry after this last code, which may widen the end code.
    if next < 4096 && next == 1 << size {
        size += 1;
    }
    bits.put(END, size);
    bits.finish()
}

#[derive(Default)]
struct BitWriter {
    bytes: Vec<u8>,
    acc: u32,
    n: u32,
}

impl BitWriter {
    fn put(&mut self, code: u16, size: u32) {
        self.acc |= (code as u32) << self.n;
        self.n += size;
        while self.n >= 8 {
            self.bytes.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }

    fn finish(mut self) -> Vec<u8> {
        if self.n > 0 {
            self.bytes.push(self.acc as u8);
        }
        self.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plain GIF LZW decoder (the format's reference algorithm), for checking the encoder.
    fn unlzw(data: &[u8]) -> Vec<u8> {
        let mut table: Vec<Vec<u8>> = (0..258).map(|i| if i < 256 { vec![i as u8] } else { vec![] }).collect();
        let (mut pos, mut size, mut out, mut prev): (usize, u32, Vec<u8>, Option<Vec<u8>>) = (0, 9, vec![], None);
        loop {
            let mut code = 0u32;
            for b in 0..size {
                let bit = (data[(pos + b as usize) / 8] >> ((pos + b as usize) % 8)) & 1;
                code |= (bit as u32) << b;
            }
            pos += size as usize;
            match code {
                256 => {
                    table.truncate(258);
                    size = 9;
                    prev = None;
                }
                257 => return out,
                _ => {
                    let entry = if (code as usize) < table.len() {
                        table[code as usize].clone()
                    } else {
                        let p = prev.clone().expect("KwKwK after a code");
                        let mut e = p.clone();
                        e.push(p[0]);
                        e
                    };
                    if let Some(p) = prev {
                        if table.len() < 4096 {
                            let mut e = p;
                            e.push(entry[0]);
                            table.push(e);
                        }
                    }
                    if table.len() == 1 << size && size < 12 {
                        size += 1;
                    }
                    out.extend_from_slice(&entry);
                    prev = Some(entry);
                }
            }
        }
    }

    #[test]
    fn lzw_round_trips_through_the_reference_decoder() {
        // Runs (long codes), noise (table fills and clears) and tiny inputs.
        let mut state = 12345u32;
        let mut noise = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 24) as u8
        };
        let long: Vec<u8> = (0..60_000).map(|i| if i % 700 < 500 { (i / 700) as u8 } else { noise() % 5 }).collect();
        let random: Vec<u8> = (0..20_000).map(|_| noise()).collect();
        for input in [vec![], vec![7], vec![1, 1, 1, 1, 1, 1], long, random] {
            assert_eq!(unlzw(&lzw(&input)), input, "length {}", input.len());
        }
    }

    #[test]
    fn file_structure() {
        let gif = encode(2, 1, &[vec![[255, 0, 0], [0, 0, 255]], vec![[0, 0, 0], [255, 255, 255]]], 10);
        assert_eq!(&gif[..6], b"GIF89a");
        assert_eq!(gif[gif.len() - 1], 0x3B);
        assert!(gif.iter().filter(|&&b| b == 0x2C).count() >= 2);
        assert_eq!(palette_index([255, 255, 255]), 251);
        assert_eq!(palette_index([0, 0, 0]), 0);
        for (x, y) in [(0, 0), (1, 2), (3, 3)] {
            assert_eq!(dithered_index([255, 255, 255], x, y), 251);
            assert_eq!(dithered_index([0, 0, 0], x, y), 0);
        }
    }
}
