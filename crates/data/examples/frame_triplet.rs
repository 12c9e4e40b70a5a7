//! Writes one frame of a dataset as a side-by-side PNG: colour | depth (colour-mapped,
//! near = warm) | class labels (class colours). For the docs and for eyeballing readers.
//!
//! `cargo run --release -p semrecon-data --example frame_triplet -- KIND:PATH INDEX OUT.png`

use semrecon_data::depth_image::write_color_png;
use semrecon_data::{open_dataset, DatasetSpec, SemanticClass};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, spec, index, out] = &args[..] else {
        return Err("usage: frame_triplet KIND:PATH INDEX OUT.png".into());
    };
    let source = open_dataset(&spec.parse::<DatasetSpec>()?)?;
    let frame = source.frame(index.parse()?)?;
    let (w, h) = (frame.intrinsics.width as usize, frame.intrinsics.height as usize);
    let (lo, hi) = frame.depth_range().unwrap_or((0.0, 1.0));
    let depth_color = |d: f32| -> [u8; 3] {
        if d <= 0.0 {
            return [0, 0, 0];
        }
        // A simple blue-to-red ramp through green: enough to read shapes and distances.
        let t = ((d - lo) / (hi - lo).max(1e-6)).clamp(0.0, 1.0);
        let r = (1.0 - t * 2.0).clamp(0.0, 1.0);
        let g = 1.0 - (t * 2.0 - 1.0).abs();
        let b = (t * 2.0 - 1.0).clamp(0.0, 1.0);
        [r, g, b].map(|c| (40.0 + 215.0 * c) as u8)
    };
    let gap = 8;
    let width = 3 * w + 2 * gap;
    let mut pixels = vec![[255u8; 3]; width * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let row = y * width;
            pixels[row + x] = frame.color[i];
            pixels[row + w + gap + x] = depth_color(frame.depth[i]);
            pixels[row + 2 * (w + gap) + x] =
                frame.labels.as_ref().and_then(|l| SemanticClass::from_id(l[i])).map_or([0, 0, 0], |c| c.color());
        }
    }
    write_color_png(std::path::Path::new(out), width as u32, h as u32, &pixels)?;
    println!("wrote {out} (depth {lo:.2}..{hi:.2} m)");
    Ok(())
}
