//! `bostrack init`: write the annotated pipeline.toml.

use crate::Outcome;
use anyhow::{Context as _, bail};
use bostrack_pipeline::{PipelineConfig, template};
use clap::Args;
use std::path::PathBuf;

/// Write an annotated pipeline.toml with every default.
#[derive(Debug, Args)]
#[command(
    about = "Write an annotated pipeline.toml with every key at its default",
    long_about = "Write an annotated campaign configuration (pipeline.toml): every key of every \
section with its default value and a comment saying what it does. Edit it, then run the chain \
on it. Relative paths in the file are resolved against the file's own folder.\n\n\
The file refuses to overwrite an existing one unless --force is given."
)]
pub(crate) struct InitArgs {
    /// File to write.
    #[arg(value_name = "PATH", default_value = "pipeline.toml")]
    path: PathBuf,
    /// Campaign folder written as `input.dir` (relative to the folder of PATH).
    #[arg(long, value_name = "DIR", default_value = ".")]
    data: PathBuf,
    /// Overwrite PATH if it exists.
    #[arg(long)]
    force: bool,
}

pub(crate) fn run(args: InitArgs) -> anyhow::Result<Outcome> {
    if args.path.exists() && !args.force {
        bail!(
            "{} already exists (use --force to overwrite it)",
            args.path.display()
        );
    }
    let text = template(&PipelineConfig::with_input_dir(&args.data))?;
    std::fs::write(&args.path, text)
        .with_context(|| format!("cannot write {}", args.path.display()))?;
    eprintln!("wrote {}", args.path.display());
    Ok(Outcome::Done)
}
