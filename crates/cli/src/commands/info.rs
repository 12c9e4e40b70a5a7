//! `semrecon info` (placeholder until the data crate lands).

/// Arguments of `semrecon info`.
#[derive(clap::Args)]
pub struct InfoArgs {}

/// Runs the command.
pub fn run(_args: InfoArgs) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
