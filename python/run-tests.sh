#!/usr/bin/env bash
# The Python package's tests, as README's test command runs them after `cargo test`: a fresh
# virtual environment in target/python-venv, `pip install ./python` into it (maturin builds the
# extension into the workspace's target/ with the release profile, so the crates it shares with
# the workspace build are reused where their features agree), then pytest on python/tests.
# Needs python3 (3.9 or newer) with venv and pip, and PyPI for maturin, numpy, scipy, pytest,
# pandas and xarray (the last two for the DataFrame and Dataset paths).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$PWD
venv="$root/target/python-venv"
start=$SECONDS
python3 -m venv --clear "$venv"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check numpy scipy pytest pandas xarray
echo "python: venv with numpy, scipy, pytest, pandas, xarray in $((SECONDS - start)) s"
# the command-line tool the tests compare against: the units of README's `cargo test` (nothing
# to do after it; a `cargo build -p bostrack` would select other features and build again)
cargo test --workspace --release --no-run --quiet 2>/dev/null || cargo test --workspace --release --no-run
t=$SECONDS
CARGO_TARGET_DIR="$root/target" "$venv/bin/python" -m pip install --quiet \
    --disable-pip-version-check "$root/python"
echo "python: pip install ./python in $((SECONDS - t)) s"
# from the root, where no `bostrack` folder shadows the installed package
"$venv/bin/pytest" -q -p no:cacheprovider python/tests
echo "python: $((SECONDS - start)) s in all"
