"""Python overhead of `bostrack.locate` against the in-process time of the command's locate.

    cargo build --release -p bostrack-pipeline --example locate_time
    python python/benches/locate_overhead.py [IMAGE] [RUNS]     # default: the real sample's reference, 7 runs each

Two measures, both on the same image and thread count:
1. the wall time of `bostrack.locate(path)` (and of an in-memory uint16 array) against that of
   the same work in a Rust process (crates/pipeline/examples/locate_time.rs: read, noise,
   detection, fits; no process start, no CSV), alternating, best and median of RUNS each;
2. the time spent outside the library in each Python call (argument checks, copying the array,
   building the numpy columns and the DataFrame or dict) over the library's own time
   (`library_seconds`, measured inside the call): immune to the load of a shared machine.
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import bostrack

root = Path(__file__).resolve().parents[2]
image = Path(sys.argv[1]) if len(sys.argv) > 1 else root.parent / "shared/data/bos-sample/pair/reference.tif"
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 7
exe = root / "target/release/examples/locate_time"



def rust_once():
    out = subprocess.run([str(exe), str(image), "1"], capture_output=True, text=True, check=True)
    f = out.stdout.split()
    r = dict(zip(f[::2], f[1::2]))
    return float(r["best_s"]), int(r["jobs"]), r["rows"]


_, jobs, rust_rows = rust_once()


def measure(arg, as_frame):
    """RUNS calls, each right after a Rust run of the same work (alternating, so that a change
    of the machine's load falls on both): best and median of each, and the outside shares."""
    py, rust, outside = [], [], []
    for _ in range(runs):
        rust.append(rust_once()[0])
        t = time.perf_counter()
        r = bostrack.locate(arg, jobs=jobs, as_frame=as_frame)
        dt = time.perf_counter() - t
        lib = bostrack._last_info["library_seconds"]
        py.append(dt)
        outside.append((dt - lib) / lib)
    return py, rust, outside, len(r["x"])


print(f"image {image}, {runs} runs each, {jobs} threads, rows {rust_rows} (Rust)")
pd = bostrack._want("pandas", None)
for label, arg in [("path", str(image)), ("uint16 array", bostrack.read_image(image).astype(np.uint16))]:
    for as_frame in ([True, False] if pd is not None else [False]):
        py, rust, outside, n = measure(arg, as_frame)
        kind = "DataFrame" if as_frame else "dict"
        print(
            f"bostrack.locate({label}) -> {kind}: best {min(py):.4f} s (Rust {min(rust):.4f} s, "
            f"{min(py) / min(rust) - 1:+.2%}), median {np.median(py):.4f} s (Rust "
            f"{np.median(rust):.4f} s, {np.median(py) / np.median(rust) - 1:+.2%}); outside the "
            f"library: median {np.median(outside):.2%}, max {max(outside):.2%} of its time; rows {n}"
        )
