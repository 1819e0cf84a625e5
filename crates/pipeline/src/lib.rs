//! Pipeline glue of bostrack: the campaign configuration (`pipeline.toml`), the validated
//! [`Plan`] built from it, and the helpers every command shares (natural file order, worker count).
//!
//! Configuration comes in two levels (docs/CONVENTIONS.md, STYLE "Habits" 2):
//! 1. [`PipelineConfig`]: the file as written. Every struct rejects unknown keys; an unknown key
//!    is reported with the file, the line, the section and the closest valid key
//!    ([`ConfigError::UnknownKey`]). Missing keys take their `Default`, the only place a default
//!    is written; [`template`] generates the annotated file `bostrack init` writes from them.
//! 2. [`Plan`]: paths resolved against the configuration file's folder, files checked to exist,
//!    frame patterns expanded and sorted naturally (`frame2` before `frame10`), values checked.
//!
//! A plan is run frame by frame by [`process_frame`] against a [`ReferenceContext`], and over a
//! whole campaign by [`run_batch`]: parallel, resumable, per-frame outputs written atomically,
//! failures recorded, figures, a campaign table, shards ([`Shard`]) and their
//! [`merge_campaign`].
//!
//! The per-frame pair pipeline: [`ReferenceContext`] (once per campaign: reference image, noise
//! model, detection, fits, the no-flow stack's per-dot u_ref), [`process_frame`] (one gradient
//! frame: tracking, fits, matching and validation, displacement, amplification ratio, u_d) and
//! [`write_frame`] (`dots.csv` + `summary.json`, atomically). See [`ReferenceContext`] for an
//! example.
//!
//! ```
//! use bostrack_pipeline::{parse_config, template, PipelineConfig, ConfigError};
//! use std::path::Path;
//!
//! // The annotated template parses back to the defaults.
//! let text = template(&PipelineConfig::default()).unwrap();
//! assert_eq!(parse_config(&text, Path::new("pipeline.toml")).unwrap(), PipelineConfig::default());
//!
//! // A misspelt key is named with its line and the key that was meant.
//! let err = parse_config("[match]\nserach_radius = 0.3\n", Path::new("pipeline.toml")).unwrap_err();
//! assert!(matches!(err, ConfigError::UnknownKey { line: 2, .. }));
//! assert!(err.to_string().contains("did you mean `search_radius`?"));
//! ```

mod batch;
mod config;
mod density;
mod error;
mod figures;
mod files;
mod jobs;
mod lattice;
mod load;
mod locate;
mod pair;
mod plan;
mod suggest;
mod table;
mod template;

pub use batch::{
    BatchError, BatchOptions, BatchReport, FrameEvent, FrameFailure, FrameStatus, MergeReport,
    Progress, Shard, ShardError, Silent, merge_campaign, run_batch,
};
pub use config::{
    ArVariant, ArrayFormat, DetectSection, Figure, FigureFormat, FitSection, InputConfig,
    MatchConfig, OutputConfig, PipelineConfig, Quantities, ReferenceFrom, ReferencePosition,
    RunConfig, Saturation, UncertaintyConfig,
};
pub use density::{
    DENSITY_COLUMNS, DensityPlan, DensitySection, DensitySummary, FrameDensity, PHYSICAL_COLUMNS,
    PhysicalDot, frame_nodes, integrate_frame,
};
pub use error::{ConfigError, PipelineError};
pub use files::{glob_match, list_matching, natural_cmp};
pub use jobs::{MAX_JOBS, available_jobs, frames_in_flight, resolve_jobs};
pub use lattice::{Field, FieldValues, LatticeFields, flag_bits, unit_of};
pub use load::{
    MAX_CONFIG_BYTES, load_config, load_toml, parse_config, parse_toml, read_config_text,
};
pub use locate::{
    LOCATE_COLUMNS, LOCATE_UNITS, LocateOptions, LocateRow, Located, locate, parse_model,
};
pub use pair::{
    FrameCounts, FrameMedians, FrameResult, FrameSummary, NoiseSummary, ReferenceContext,
    StackSummary, StageTimes, frame_is_complete, process_frame, process_image, write_frame,
};
pub use plan::{OutputPlan, Plan, ReferenceImage};
pub use suggest::{did_you_mean, edit_distance};
pub use table::CsvTable;
pub use template::template;
