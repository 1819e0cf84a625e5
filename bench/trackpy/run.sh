#!/usr/bin/env bash
# bostrack locate against trackpy.locate on the same images, one thread each: CPU per dot and
# both accuracies against the exact truth (issue 17). Usage, from anywhere:
#
#   bench/trackpy/run.sh [--runs N] [--seed S] [--baseline /path/to/other/bostrack]
#
# Makes (once) a virtual environment with the pinned trackpy of requirements.txt under
# target/bench-trackpy/venv, builds the release bostrack (BOSTRACK=/path/to/bostrack to use
# another build), writes the scenes with `bostrack synth` and prints the table (also in
# target/bench-trackpy/results.md and results.json). The real reference is taken from
# ../shared/data/bos-sample beside the repository (BOSTRACK_SAMPLE=DIR to point elsewhere).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
out=${BENCH_OUT:-$root/target/bench-trackpy}
venv=$out/venv
mkdir -p "$out"
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$root/bench/trackpy/requirements.txt" "$venv/requirements.txt"; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$root/bench/trackpy/requirements.txt"
    cp "$root/bench/trackpy/requirements.txt" "$venv/requirements.txt"
fi
if [ -z "${BOSTRACK:-}" ]; then
    (cd "$root" && cargo build --release --quiet -p bostrack)
    BOSTRACK=$root/target/release/bostrack
fi
sample=${BOSTRACK_SAMPLE:-$root/../shared/data/bos-sample}
exec env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \
    "$venv/bin/python" "$root/bench/trackpy/bench.py" --bostrack "$BOSTRACK" --out "$out" \
    --real "$sample/pair/reference.tif" --mask "$sample/mask.tif" "$@"
