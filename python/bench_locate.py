"""Python overhead of `bostrack.locate` against the in-process time of the command's locate.

    cargo build --release -p bostrack-pipeline --example locate_time
    python python/bench_locate.py [IMAGE] [RUNS]     # default: the real sample's reference, 7 runs

Two measures, both on the same image and thread count:
1. best wall time of `bostrack.locate(path)` over the best time of the same work in a Rust
   process (crates/pipeline/examples/locate_time.rs: read, noise, detection, fits; no process
   start, no CSV), each the best of RUNS; and the same for an in-memory uint16 array;
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

root = Path(__file__).resolve().parents[1]
image = Path(sys.argv[1]) if len(sys.argv) > 1 else root.parent / "shared/data/bos-sample/pair/reference.tif"
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 7
exe = root / "target/release/examples/locate_time"

out = subprocess.run([str(exe), str(image), str(runs)], capture_output=True, text=True, check=True)
fields = out.stdout.split()
rust = dict(zip(fields[::2], fields[1::2]))
rust_best = float(rust["best_s"])
jobs = int(rust["jobs"])


def measure(arg, as_frame):
    best, outside = float("inf"), []
    for _ in range(runs):
        t = time.perf_counter()
        r = bostrack.locate(arg, jobs=jobs, as_frame=as_frame)
        dt = time.perf_counter() - t
        lib = bostrack._last_info["library_seconds"]
        best = min(best, dt)
        outside.append((dt - lib) / lib)
    return best, outside, len(r["x"])


print(f"image {image}, {runs} runs each, {jobs} threads")
print(f"Rust process (read + locate): best {rust_best:.4f} s, median {float(rust['median_s']):.4f} s, rows {rust['rows']}")
pd = bostrack._want("pandas", None)
for label, arg in [("path", str(image)), ("uint16 array", bostrack.read_image(image).astype(np.uint16))]:
    for as_frame in ([True, False] if pd is not None else [False]):
        best, outside, n = measure(arg, as_frame)
        kind = "DataFrame" if as_frame else "dict"
        line = f"bostrack.locate({label}) -> {kind}: best {best:.4f} s, {best / rust_best - 1:+.2%} against Rust, rows {n}"
        if outside:  # always
            line += f"; outside the library: median {np.median(outside):.2%}, max {max(outside):.2%} of its time"
        print(line)
