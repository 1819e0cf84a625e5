//! A reduced fuzzing round (issue #14): 3,000 mutated image and configuration files, none of
//! which may panic. The full round (≥ 10⁵ executions) is `examples/fuzz.rs`.

#[path = "common/fuzz.rs"]
mod fuzz;

#[test]
fn mutated_files_never_panic() {
    let corpus = fuzz::corpus(bostrack_io::bos_sample_dir().as_deref());
    let dir = tempfile::tempdir().unwrap();
    let round = fuzz::run(&corpus, 3000, 7, dir.path());
    println!("{round:?}");
    assert!(round.decoded > 100 && round.fitted > 10, "{round:?}");
    assert!(round.config_cases > 100, "{round:?}");
    assert!(round.panics.is_empty(), "{:?}", round.panics);
}
