//! Writes generated rooms after augmentation as PLY point clouds, to look at what the
//! network trains on (a short walk's view, rugs, crops, colour changes).
//!
//! ```text
//! cargo run --release -p semrecon-net --example augment_preview -- SOURCE OUT_DIR [training|live-maps|casual-scans|real-rooms|real-scans] [N]
//! ```
//!
//! `SOURCE` is a data source (`synth:0..4`, `ply:DIR`); the first `N` (default 4) rooms are
//! written as `OUT_DIR/room_K.ply` with colour and a `label` vertex property.

use semrecon_data::{write_ply, PlyEncoding};
use semrecon_net::dataset::{load_cloud, rooms_of, sample_seed, Augment, DataSource};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(source), Some(out)) = (args.first(), args.get(1)) else {
        return Err(
            "usage: augment_preview SOURCE OUT_DIR [training|live-maps|casual-scans|real-rooms|real-scans] [N]".into(),
        );
    };
    let recipe = args.get(2).map_or("live-maps", String::as_str);
    let augment = Augment::from_recipe(recipe)
        .ok_or_else(|| format!("unknown recipe `{recipe}`: one of {:?}", Augment::RECIPES))?;
    let n: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(4);
    std::fs::create_dir_all(out)?;
    let rooms = rooms_of(&[DataSource::parse(source)?])?;
    for (k, room) in rooms.iter().take(n).enumerate() {
        let seed = sample_seed(1, 0, k as u64);
        let mut cloud = load_cloud(room, 0.05, seed)?;
        let before = cloud.len();
        augment.apply(&mut cloud, seed);
        let path = std::path::Path::new(out).join(format!("room_{k}.ply"));
        write_ply(&path, &cloud.to_mesh(), PlyEncoding::BinaryLittleEndian)?;
        println!("{}: {} of {} points", path.display(), cloud.len(), before);
    }
    Ok(())
}
