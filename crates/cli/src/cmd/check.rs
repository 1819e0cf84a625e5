//! `bostrack check`: validate a campaign configuration and print the resolved plan.

use crate::Outcome;
use bostrack_pipeline::{Plan, ReferenceImage};
use clap::Args;
use serde_json::json;
use std::path::PathBuf;

/// Validate a pipeline.toml and print the plan it resolves to.
#[derive(Debug, Args)]
#[command(
    about = "Validate a pipeline.toml and print the resolved plan as JSON",
    long_about = "Read a campaign configuration, check it and print the plan it resolves to as one \
JSON object: the reference image (a file or \"stack-mean\"), the no-flow stack and gradient files \
in the order they will be processed (natural order: frame2 before frame10), the mask, the flags \
that make a displacement invalid (`[match] keep_flagged` taken out), the output folder and the \
number of worker threads.\n\n\
Relative paths are resolved against the folder of the configuration file. Unknown keys, \
values out of range, missing files and patterns that match nothing are errors (exit 1) that \
name the file, and for unknown keys the line and the closest valid key; a path that is a folder \
where a file is needed (or a file where a folder is needed, also for output.dir), a broken \
symbolic link or a link loop is named with what it is. Warnings (printed on stderr and listed \
under \"warnings\") do not fail the check: a pattern that also matches the reference image, \
the mask or a no-flow image, and folders whose names match a pattern (skipped)."
)]
pub(crate) struct CheckArgs {
    /// Campaign configuration file.
    #[arg(value_name = "CONFIG", default_value = "pipeline.toml")]
    config: PathBuf,
}

pub(crate) fn run(args: CheckArgs) -> anyhow::Result<Outcome> {
    let plan = Plan::load(&args.config)?;
    for w in &plan.warnings {
        eprintln!("warning: {w}");
    }
    let reference = match &plan.reference {
        ReferenceImage::File(p) => json!(p),
        ReferenceImage::StackMean => json!("stack-mean"),
    };
    let figures: Vec<&str> = plan.output.figures.iter().map(|f| f.name()).collect();
    let out = json!({
        "config": plan.config_file,
        "reference": reference,
        "stack": plan.stack,
        "gradients": plan.gradients,
        "mask": plan.mask,
        "invalid_if": plan.invalid_if.to_string(),
        "output": {
            "dir": plan.output.dir,
            "figures": figures,
            "overwrite": plan.output.overwrite,
        },
        "jobs": plan.jobs,
        "warnings": plan.warnings,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(Outcome::Done)
}
