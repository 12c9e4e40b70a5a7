//! `semrecon demo` (placeholder until the data crate lands).

/// Arguments of `semrecon demo`.
#[derive(clap::Args)]
pub struct DemoArgs {}

/// Runs the command.
pub fn run(_args: DemoArgs) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
