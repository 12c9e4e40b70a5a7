//! CBSCN s20 on the benchmark room of `bench net`, for profilers and quick timings:
//! `valgrind --tool=callgrind --toggle-collect='*NetGeometry*build*'
//! target/release/examples/net_profile [geometry|layers|all] [rulebook]`.
//! Builds the room and the sample first (not the interesting part), then runs the chosen
//! phase: `geometry` builds the geometry 15 times and prints each wall time (the minimum is
//! the least disturbed on a shared machine), `layers` and `all` run once.

use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_net::dataset::points_per_m2;
use semrecon_net::surface::sample_surface;
use semrecon_net::{ConvKernel, NetConfig, NetGeometry, Segmenter, VoxelSample, Weights};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "all".into());
    let rulebook = std::env::args().nth(2).as_deref() == Some("rulebook");
    let config = NetConfig::from_name_or_file("s20")?;
    let room = generate_room(&RoomConfig { seed: 0, style: None });
    let cloud = sample_surface(&room.mesh, points_per_m2(config.voxel_size), 0);
    let sample = VoxelSample::from_cloud(&cloud, config.voxel_size)?;
    let mut net = Segmenter::new(Weights::random(&config, 0), config.clone())?;
    if rulebook {
        net.set_kernel(ConvKernel::Rulebook);
    }
    let t = std::time::Instant::now();
    match mode.as_str() {
        "geometry" => {
            for _ in 0..15 {
                let t = std::time::Instant::now();
                let g = NetGeometry::build(sample.coords.clone(), &config, &Default::default())?;
                println!("levels {}: {:.1} ms", g.levels(), t.elapsed().as_secs_f64() * 1e3);
            }
        }
        "layers" => {
            let g = NetGeometry::build(sample.coords.clone(), &config, &Default::default())?;
            let t = std::time::Instant::now();
            net.segment_geometry(&g, &sample.features)?;
            println!("layers {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
        }
        _ => {
            net.segment(&sample.coords, &sample.features)?;
            println!("{:?}", net.last_timing());
        }
    }
    println!("{mode}: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    Ok(())
}
