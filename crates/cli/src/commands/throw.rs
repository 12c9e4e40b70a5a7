//! `semrecon throw`: one virtual ball thrown into a labelled mesh; its path and every bounce
//! (with the class hit and the restitution used) as a table or JSON.

use std::path::PathBuf;

use anyhow::Context;
use glam::Vec3;
use semrecon_data::atomic_file::write_atomic;
use semrecon_physics::throw_from_ply;

/// Arguments of `semrecon throw`.
#[derive(clap::Args)]
pub struct ThrowArgs {
    /// Labelled mesh (PLY with a `label` vertex or face property; without labels every surface
    /// gets the default material).
    #[arg(long)]
    mesh: PathBuf,
    /// Materials per class (TOML); the shipped defaults when absent.
    #[arg(long)]
    materials: Option<PathBuf>,
    /// Start position x,y,z in metres.
    #[arg(long, value_parser = crate::cli_values::parse_vec3, allow_hyphen_values = true)]
    from: Vec3,
    /// Throw direction x,y,z (normalised).
    #[arg(long, value_parser = crate::cli_values::parse_vec3, allow_hyphen_values = true)]
    dir: Vec3,
    /// Speed in m/s.
    #[arg(long, default_value_t = 3.0)]
    speed: f32,
    /// Simulated time in seconds.
    #[arg(long, default_value_t = 3.0)]
    seconds: f32,
    /// Write the trajectory (`times`, `positions`, `contacts`) as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: ThrowArgs) -> anyhow::Result<()> {
    let throw = throw_from_ply(&args.mesh, args.materials.as_deref(), args.from, args.dir, args.speed, args.seconds)?;
    for w in &throw.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(path) = &args.json {
        let text = serde_json::to_string(&throw)?;
        write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))?;
    }
    println!("{:>8}  {:>24}  {:>10}  {:>11}", "time s", "position m", "class", "restitution");
    for c in &throw.contacts {
        let [x, y, z] = c.position;
        println!("{:>8.3}  {:>24}  {:>10}  {:>11.2}", c.time, format!("{x:.3},{y:.3},{z:.3}"), c.class, c.restitution);
    }
    if let Some(last) = throw.positions.last() {
        println!(
            "{} bounces; ball at {:.3},{:.3},{:.3} after {} s",
            throw.contacts.len(),
            last[0],
            last[1],
            last[2],
            args.seconds
        );
    }
    Ok(())
}
