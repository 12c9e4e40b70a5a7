//! `semrecon synth` (placeholder until the data crate lands).

/// Arguments of `semrecon synth`.
#[derive(clap::Args)]
pub struct SynthArgs {}

/// Runs the command.
pub fn run(_args: SynthArgs) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
