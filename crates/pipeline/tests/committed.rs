//! The files committed at the top of the repository agree with the code: the main
//! `pipeline.toml` is exactly the generated template (so its defaults are the code's), both
//! campaigns resolve to the files they describe, and the table of statuses and flags in
//! `docs/CONVENTIONS.md` is the code's.

use bostrack_core::{DotFlags, FitStatus};
use bostrack_displacement::DisplacementConfig;
use bostrack_pipeline::{MatchConfig, PipelineConfig, Plan, ReferenceImage, load_config, template};
use std::path::{Path, PathBuf};

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `pipeline.toml` = `bostrack init pipeline.toml --data testdata/demo`. With BOSTRACK_BLESS=1
/// the file is rewritten instead of compared.
#[test]
fn pipeline_toml_is_the_generated_template() {
    let path = repo_root().join("pipeline.toml");
    let expected_cfg = PipelineConfig::with_input_dir("testdata/demo");
    let expected = template(&expected_cfg).unwrap();
    if std::env::var("BOSTRACK_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(&path, &expected).unwrap();
    }
    let committed = std::fs::read_to_string(&path).unwrap();
    assert!(
        committed == expected,
        "pipeline.toml is not the generated template: regenerate it with \
         `BOSTRACK_BLESS=1 cargo test -p bostrack-pipeline --test committed` \
         (or `bostrack init pipeline.toml --data testdata/demo --force`)"
    );
    // Every value in it is the code's default, except the campaign folder.
    assert_eq!(load_config(&path).unwrap(), expected_cfg);
}

/// The comments `bostrack init` writes into every new `pipeline.toml` point only inside the
/// repository: no `../` path, and every `docs/…` file they name exists.
#[test]
fn the_template_points_only_inside_the_repository() {
    let text = template(&PipelineConfig::default()).unwrap();
    assert!(
        !text.contains("../"),
        "the template names a path outside the repository"
    );
    assert!(
        !text.contains("shared/"),
        "the template names the shared folder"
    );
    let mut named = 0;
    for (k, _) in text.match_indices("docs/") {
        let path: String = text[k..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || "/._-".contains(*c))
            .collect();
        let path = path.trim_end_matches('.');
        assert!(
            repo_root().join(path).is_file(),
            "the template names {path}, which does not exist"
        );
        named += 1;
    }
    assert!(named > 0);
}

#[test]
fn the_demo_campaign_resolves() {
    let plan = Plan::load(&repo_root().join("pipeline.toml")).unwrap();
    let name = |p: &Path| p.file_name().unwrap().to_string_lossy().into_owned();
    match &plan.reference {
        ReferenceImage::File(p) => assert_eq!(name(p), "reference.tif"),
        other => panic!("reference: {other:?}"),
    }
    let stack: Vec<String> = plan.stack.iter().map(|p| name(p)).collect();
    assert_eq!(
        stack,
        [
            "noflow_01.tif",
            "noflow_02.tif",
            "noflow_03.tif",
            "noflow_04.tif",
            "noflow_05.tif"
        ]
    );
    let grads: Vec<String> = plan.gradients.iter().map(|p| name(p)).collect();
    assert_eq!(grads, ["frame_01.tif", "frame_02.tif", "frame_03.tif"]);
    assert_eq!(plan.mask, None);
    assert!(plan.output.dir.ends_with("out"));
}

#[test]
fn the_sample_campaign_resolves() {
    let cfg_path = repo_root().join("testdata/bos-sample.toml");
    let cfg = load_config(&cfg_path).unwrap();
    assert_eq!(cfg.detect.spacing, Some(8.0));
    let Some(_) = bostrack_io::bos_sample_dir() else {
        return;
    };
    let plan = Plan::load(&cfg_path).unwrap();
    let name = |p: &Path| p.file_name().unwrap().to_string_lossy().into_owned();
    let stack: Vec<String> = plan.stack.iter().map(|p| name(p)).collect();
    let expected: Vec<String> = (1..=10).map(|k| format!("im_{k:04}.tif")).collect();
    assert_eq!(stack, expected);
    assert_eq!(plan.gradients.len(), 1);
    assert_eq!(name(&plan.gradients[0]), "gradient.tif");
    assert!(plan.mask.as_ref().is_some_and(|m| m.is_file()));
    assert!(matches!(&plan.reference, ReferenceImage::File(p) if p.is_file()));
}

/// The rows of the status and flag table of docs/CONVENTIONS.md: `(column, name, meaning,
/// invalid by default)`, names without their backticks.
fn flag_table() -> Vec<[String; 4]> {
    let text = std::fs::read_to_string(repo_root().join("docs/CONVENTIONS.md")).unwrap();
    let mut lines = text
        .lines()
        .skip_while(|l| !l.starts_with("| column | name | meaning |"))
        .skip(2); // the header and its rule
    let mut rows = Vec::new();
    for line in lines.by_ref().take_while(|l| l.starts_with('|')) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        assert_eq!(cells.len(), 6, "a row of four cells: {line}");
        let name = cells[2].trim_matches('`');
        assert!(!cells[3].is_empty(), "no meaning: {line}");
        rows.push([cells[1], name, cells[3], cells[4]].map(str::to_owned));
    }
    assert!(!rows.is_empty(), "no table in docs/CONVENTIONS.md");
    rows
}

/// Every `FitStatus` and every `DotFlags` flag has one row, in the code's order, nothing else
/// does, and the last column says what the code does: a status that is not usable makes the
/// displacement invalid (through `fit_failed`), a flag does when it is in
/// `DisplacementConfig::DEFAULT_INVALID_IF`, "unless kept" when `[match] keep_flagged` can keep
/// it.
#[test]
fn conventions_table_lists_every_status_and_flag() {
    let rows = flag_table();
    let names = |column: &str| -> Vec<&str> {
        rows.iter()
            .filter(|r| r[0] == column)
            .map(|r| r[1].as_str())
            .collect()
    };
    let statuses: Vec<&str> = FitStatus::ALL.iter().map(FitStatus::as_str).collect();
    assert_eq!(names("status"), statuses);
    let flags: Vec<&str> = DotFlags::from_bits(u32::MAX).names().collect();
    assert_eq!(names("flags"), flags);
    assert_eq!(
        rows.len(),
        statuses.len() + flags.len(),
        "rows of another column"
    );

    for s in FitStatus::ALL {
        let row = rows.iter().find(|r| r[1] == s.as_str()).unwrap();
        let want = if s.is_ok() {
            "no"
        } else {
            "yes (`fit_failed`)"
        };
        assert_eq!(row[3], want, "status {s}");
    }
    for f in flags {
        let row = rows.iter().find(|r| r[0] == "flags" && r[1] == f).unwrap();
        let flag = DotFlags::parse(f).unwrap();
        let want = if !DisplacementConfig::DEFAULT_INVALID_IF.contains(flag) {
            "no"
        } else if MatchConfig::KEEPABLE.contains(&flag) {
            "yes, unless kept"
        } else {
            "yes"
        };
        assert_eq!(row[3], want, "flag {f}");
    }
}
