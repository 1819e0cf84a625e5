//! One module per subcommand: its clap arguments (first level) and `run`, which builds the
//! validated library objects and does the work.

pub(crate) mod bench;
pub(crate) mod check;
pub(crate) mod crlb;
pub(crate) mod info;
pub(crate) mod init;
pub(crate) mod locate;
pub(crate) mod merge;
pub(crate) mod run;
pub(crate) mod synth;
