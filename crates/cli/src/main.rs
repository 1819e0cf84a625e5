//! `bostrack`: the command-line interface of bostrack.
//!
//! Arguments are parsed in two levels: clap turns the command line into the raw structs below,
//! then each command builds validated library objects (a `Plan`, stage configurations) from
//! them. Library errors are typed; only this binary uses `anyhow`.
//!
//! Exit codes: 0 success; 1 usage, configuration or input error (one line on stderr naming the
//! problem); 2 a batch finished but some of its items failed.

mod cmd;
mod jobs;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// How a command that did not fail outright ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// Everything succeeded.
    Done,
    /// A batch finished but some items failed (each reported on stderr).
    SomeFailed,
}

const LONG_ABOUT: &str = "\
bostrack measures per-dot displacements between a reference image of a dot target and images of \
the same target seen through a flow (Background-Oriented Schlieren), with a per-dot uncertainty \
for each: the exact Cramér-Rao bound of the fit, the reference position noise from a no-flow stack \
and the amplification ratio of the gradient image.

Conventions: pixel centres at integer coordinates, origin at the centre of the top-left pixel, x to \
the right, y down, lengths in px, displacement = gradient - reference (docs/CONVENTIONS.md).

Exit codes: 0 success; 1 usage, configuration or input error; 2 a batch finished but some of its \
items failed.";

#[derive(Debug, Parser)]
#[command(
    name = "bostrack",
    version,
    about = "Background-Oriented Schlieren dot tracking with per-dot uncertainties",
    long_about = LONG_ABOUT,
    propagate_version = true
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    Bench(cmd::bench::BenchArgs),
    Check(cmd::check::CheckArgs),
    Crlb(cmd::crlb::CrlbArgs),
    Info(cmd::info::InfoArgs),
    Init(cmd::init::InitArgs),
    Locate(cmd::locate::LocateArgs),
    Merge(cmd::merge::MergeArgs),
    Run(cmd::run::RunArgs),
    Synth(cmd::synth::SynthArgs),
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // Help and --version go to stdout and succeed; every usage error exits 1 (not
            // clap's default 2, which here means "a batch partly failed").
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let result = match cli.command {
        Command::Bench(args) => cmd::bench::run(args),
        Command::Check(args) => cmd::check::run(args),
        Command::Crlb(args) => cmd::crlb::run(args),
        Command::Info(args) => cmd::info::run(args),
        Command::Init(args) => cmd::init::run(args),
        Command::Locate(args) => cmd::locate::run(args),
        Command::Merge(args) => cmd::merge::run(args),
        Command::Run(args) => cmd::run::run(args),
        Command::Synth(args) => cmd::synth::run(args),
    };
    match result {
        Ok(Outcome::Done) => ExitCode::SUCCESS,
        Ok(Outcome::SomeFailed) => ExitCode::from(2),
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::from(1)
        }
    }
}

/// The error and its causes on one line ("context: cause"), leaving out a cause whose text the
/// line already holds (library errors often print their source themselves).
pub(crate) fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line.replace('\n', " ")
}
