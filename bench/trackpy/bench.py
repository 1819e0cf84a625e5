#!/usr/bin/env python3
"""bostrack locate against trackpy.locate: CPU per dot and accuracy against the exact truth.

Run through bench/trackpy/run.sh (it makes the virtual environment and builds bostrack). For each
scene of issue 17 (512 x 512 px synthetic images written by `bostrack synth` with their exact
truth, and the real sample's reference) both locators run on the same image, interleaved, on one
thread each:

- bostrack: the whole process `bostrack locate IMAGE -o CSV --jobs 1` (RAYON_NUM_THREADS=1):
  process start, decode, noise estimate, lattice, seeds, fits, CSV. CPU = user + system time of
  the child (os.wait4).
- trackpy: one warm Python process (the imports paid once, reported apart) that per image reads
  the TIFF (tifffile), runs trackpy.locate and writes the CSV; CPU = process_time() around those
  three steps. OMP/BLAS threads are pinned to 1.

CPU per dot divides by the same count for both: the truth dots of a synthetic scene, bostrack's
usable fits on the real image. Accuracy: each tool's positions matched to the truth (nearest
within half a spacing), the RMS over dots and axes of error / exact bound (truth crlb_x, crlb_y:
the isolated dot's bound, all 7 parameters free; dots cut by the image border left out, see
`compared`), the fraction of the truth found and the count wrong by more than 5 bounds; on the
real image, trackpy's RMS difference from bostrack in units of bostrack's own bound.
"""

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import time

# name, sigma (px), spacing (px), amplitude (counts), trackpy diameter (odd px)
SCENES = [
    ("512², σ 1.25 px, spacing 10", "s125", 1.25, 10.0, 1500.0, 7),
    ("512², σ 0.75 px", "s075", 0.75, 10.0, 1500.0, 5),
    ("512², σ 0.3 px (undersampled)", "s030", 0.3, 10.0, 1500.0, 3),
    ("512², σ 1.25 px, peak SNR ~6", "snr6", 1.25, 10.0, 100.0, 7),
]
ENGINE = "python"
# Every synthetic lattice is turned by ANGLE_DEG about an origin off the pixel grid, so that the
# dots take every sub-pixel position (an unturned lattice of integer spacing puts every dot on a
# pixel centre, where a centroid is exact by symmetry).
ANGLE_DEG = 3.7
ORIGIN = (255.31, 255.77)
REAL = ("real 1-MP reference", "real", None, 8.0, None, 7)


def worker():
    """The trackpy side: reads one JSON job per line on stdin, answers one JSON line each."""
    import resource

    import numpy as np
    import tifffile
    import trackpy as tp

    tp.quiet()
    global ENGINE
    try:
        import numba  # noqa: F401  trackpy's fast engine

        ENGINE = "numba"
    except ImportError:
        ENGINE = "python"
    ru = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"import_cpu_s": ru.ru_utime + ru.ru_stime,
                      "trackpy": tp.__version__, "numpy": np.__version__,
                      "engine": ENGINE}), flush=True)
    for line in sys.stdin:
        job = json.loads(line)
        if job["kind"] == "calibrate":
            # Untimed, once per image: minmass = 0.4 x the median mass of the `expected`
            # brightest features (noise maxima have a small mass, dots a large one).
            img = tifffile.imread(job["image"])
            # Also compiles numba's kernels before anything is timed.
            f = tp.locate(img, job["diameter"], minmass=0, separation=job["separation"],
                          engine=ENGINE)
            m = np.sort(f["mass"].to_numpy())[::-1][: job["expected"]]
            print(json.dumps({"minmass": 0.4 * float(np.median(m))}), flush=True)
            continue
        c0, w0 = time.process_time(), time.perf_counter()
        img = tifffile.imread(job["image"])
        f = tp.locate(img, job["diameter"], minmass=job["minmass"],
                      separation=job["separation"], engine=ENGINE)
        f.to_csv(job["out"], index=False)
        c1, w1 = time.process_time(), time.perf_counter()
        print(json.dumps({"cpu_s": c1 - c0, "wall_s": w1 - w0, "n": len(f)}), flush=True)


def run_bostrack(exe, image, out, extra):
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    w0 = time.perf_counter()
    p = subprocess.Popen([exe, "locate", image, "-o", out, "--jobs", "1", *extra], env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - w0
    err = p.stderr.read().decode()
    p.stderr.close()
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        sys.exit(f"bostrack locate {image} failed ({p.returncode}): {err}")
    return {"cpu_s": ru.ru_utime + ru.ru_stime, "wall_s": wall}


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def num(s):
    return float(s) if s not in ("", None) else math.nan


def bostrack_points(path):
    pts = []
    for r in read_rows(path):
        if r["status"] in ("converged", "iteration_limit") and r["x"] != "":
            pts.append((num(r["x"]), num(r["y"]), num(r["crlb_x"]), num(r["crlb_y"])))
    return pts


def trackpy_points(path):
    return [(num(r["x"]), num(r["y"])) for r in read_rows(path)]


def accuracy(found, truth, radius):
    """found: [(x, y, ...)]; truth: [(x, y, cx, cy)] with finite bounds. The nearest found point
    within `radius` of each truth dot: (fraction of the truth matched, RMS over the matched dots
    and both axes of error / bound, count wrong by more than 5 bounds on an axis)."""
    from scipy.spatial import cKDTree

    tree = cKDTree([(p[0], p[1]) for p in found])
    d, k = tree.query([(t[0], t[1]) for t in truth], distance_upper_bound=radius)
    s2 = 0.0
    n = wrong = 0
    for t, dist, idx in zip(truth, d, k):
        if not math.isfinite(dist):
            continue
        zx, zy = (found[idx][0] - t[0]) / t[2], (found[idx][1] - t[1]) / t[3]
        s2 += zx * zx + zy * zy
        n += 1
        wrong += abs(zx) > 5 or abs(zy) > 5
    return n / len(truth), math.sqrt(s2 / (2 * n)) if n else math.nan, wrong


def compared(truth):
    """The truth dots both tools are scored on: a finite bound at most 3 x the scene's median
    (dots cut by the image border have a bound up to 1e5 x larger and would weigh nothing)."""
    truth = [t for t in truth if math.isfinite(t[2]) and math.isfinite(t[3])]
    med = statistics.median(max(t[2], t[3]) for t in truth)
    return [t for t in truth if max(t[2], t[3]) <= 3 * med]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bostrack", required=True, help="path of the bostrack binary")
    ap.add_argument("--out", required=True, help="working folder (scenes, CSVs, results)")
    ap.add_argument("--real", help="real reference image (skipped when absent)")
    ap.add_argument("--mask", help="bostrack's mask for the real reference")
    ap.add_argument("--baseline", help="a second bostrack binary (e.g. a build of main), timed "
                    "interleaved with the first: its CPU per dot and the ratio in one more column")
    ap.add_argument("--runs", type=int, default=5, help="interleaved repetitions (median)")
    ap.add_argument("--seed", type=int, default=17)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    load0 = open("/proc/loadavg").read().split()[:3]
    t_start = time.time()

    images = []  # (label, key, image, truth or None, spacing, diameter)
    for label, key, sigma, spacing, amp, diam in SCENES:
        d = os.path.join(a.out, "scenes", key)
        if not os.path.exists(os.path.join(d, "reference.tif")):
            os.makedirs(d, exist_ok=True)
            scene = os.path.join(a.out, "scenes", f"{key}.toml")
            with open(scene, "w") as fh:
                fh.write(f"[lattice]\nangle_deg = {ANGLE_DEG}\norigin = [{ORIGIN[0]}, {ORIGIN[1]}]\n")
            subprocess.run([a.bostrack, "synth", "-o", d, "--force", "--scene", scene, "--width", "512",
                            "--height", "512", "--spacing", str(spacing), "--sigma",
                            str(sigma), "--amplitude", str(amp), "--stack", "0", "--frames",
                            "0", "--seed", str(a.seed), "--jobs", "1"], check=True,
                           stdout=subprocess.DEVNULL)
        truth = [(num(r["x"]), num(r["y"]), num(r["crlb_x"]), num(r["crlb_y"]))
                 for r in read_rows(os.path.join(d, "truth", "reference.csv"))]
        # The dots of the truth with a bound: those inside the image (border dots have none).
        ntruth = sum(math.isfinite(t[2]) and math.isfinite(t[3]) for t in truth)
        images.append((label, key, os.path.join(d, "reference.tif"), (ntruth, compared(truth)),
                       spacing, diam, []))
    if a.real and os.path.exists(a.real):
        label, key, _, spacing, _, diam = REAL
        # bostrack with the sample's mask (its decode is in bostrack's time); trackpy has none.
        extra = ["--mask", a.mask] if a.mask else []
        images.append((label, key, a.real, None, spacing, diam, extra))

    wk = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker"],
                          stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                          env=dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                                   MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1"))

    def ask(job):
        wk.stdin.write(json.dumps(job) + "\n")
        wk.stdin.flush()
        return json.loads(wk.stdout.readline())

    hello = json.loads(wk.stdout.readline())
    res = {}
    for label, key, img, truth, spacing, diam, extra in images:
        bcsv = os.path.join(a.out, f"{key}.bostrack.csv")
        run_bostrack(a.bostrack, img, bcsv, extra)  # warms the page cache
        expected = truth[0] if truth else len(bostrack_points(bcsv))
        mm = ask({"kind": "calibrate", "image": img, "diameter": diam,
                  "separation": min(diam + 1, spacing - 2), "expected": expected})["minmass"]
        res[key] = {"label": label, "expected": expected, "minmass": mm, "diameter": diam,
                    "separation": min(diam + 1, spacing - 2), "b": [], "t": [], "base": []}
    for r in range(a.runs):
        for label, key, img, truth, spacing, diam, extra in images:
            e = res[key]
            tjob = {"kind": "locate", "image": img, "out": os.path.join(a.out, f"{key}.trackpy.csv"),
                    "diameter": diam, "minmass": e["minmass"], "separation": e["separation"]}
            order = ["b", "t"] + (["base"] if a.baseline else [])
            for who in (order if r % 2 == 0 else order[::-1]):
                if who == "base":
                    e["base"].append(run_bostrack(a.baseline, img, os.path.join(a.out, f"{key}.baseline.csv"),
                                                  extra))
                elif who == "b":
                    e["b"].append(run_bostrack(a.bostrack, img, os.path.join(a.out, f"{key}.bostrack.csv"),
                                              extra))
                else:
                    e["t"].append(ask(tjob))
    wk.stdin.close()
    wk.wait()

    rows = []
    for label, key, img, truth, spacing, diam, extra in images:
        e = res[key]
        bp = bostrack_points(os.path.join(a.out, f"{key}.bostrack.csv"))
        tp_ = trackpy_points(os.path.join(a.out, f"{key}.trackpy.csv"))
        bcpu = statistics.median(x["cpu_s"] for x in e["b"])
        tcpu = statistics.median(x["cpu_s"] for x in e["t"])
        row = {"scene": label, "dots": e["expected"],
               "bostrack_us_per_dot": 1e6 * bcpu / e["expected"],
               "trackpy_us_per_dot": 1e6 * tcpu / e["expected"],
               "ratio": bcpu / tcpu, "scored": len(truth[1]) if truth else None,
               "bostrack_cpu_ms": 1e3 * bcpu, "trackpy_cpu_ms": 1e3 * tcpu,
               "bostrack_cpu_ms_min": 1e3 * min(x["cpu_s"] for x in e["b"]),
               "trackpy_cpu_ms_min": 1e3 * min(x["cpu_s"] for x in e["t"]),
               "baseline_us_per_dot": (1e6 * statistics.median(x["cpu_s"] for x in e["base"])
                                       / e["expected"]) if e["base"] else None,
               "trackpy_features": e["t"][-1]["n"], "trackpy_minmass": e["minmass"],
               "trackpy_diameter": diam, "trackpy_separation": e["separation"]}
        if truth:
            for who, pts in (("bostrack", bp), ("trackpy", tp_)):
                f, q, w = accuracy(pts, truth[1], spacing / 2)
                row[f"{who}_found"], row[f"{who}_rms_over_bound"], row[f"{who}_wrong5"] = f, q, w
        else:
            # No truth: trackpy against bostrack, in bostrack's bound.
            f, q, w = accuracy(tp_, [(p[0], p[1], p[2], p[3]) for p in bp], spacing / 2)
            row["trackpy_vs_bostrack_found"], row["trackpy_vs_bostrack_rms_over_bound"] = f, q
        rows.append(row)

    def fmt(v, spec):
        return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)

    lines = [
        "| scene | dots | bostrack CPU µs/dot | trackpy CPU µs/dot | bostrack / trackpy | "
        "bostrack RMS error / bound (found, > 5 bounds) | trackpy RMS error / bound (found, > 5 bounds) |"
        + (" baseline bostrack CPU µs/dot | bostrack / baseline |" if a.baseline else ""),
        "|---|---|---|---|---|---|---|" + ("---|---|" if a.baseline else ""),
    ]
    for r in rows:
        if "bostrack_found" in r:
            acc_b, acc_t = (f"{fmt(r[w + '_rms_over_bound'], '.3f')} ({r[w + '_found']:.4f}, "
                            f"{r[w + '_wrong5']})" for w in ("bostrack", "trackpy"))
        else:
            acc_b = "— (no truth)"
            acc_t = (f"{fmt(r['trackpy_vs_bostrack_rms_over_bound'], '.3f')} from bostrack "
                     f"({r['trackpy_vs_bostrack_found']:.4f})")
        lines.append(f"| {r['scene']} | {r['dots']} | {r['bostrack_us_per_dot']:.2f} | "
                     f"{r['trackpy_us_per_dot']:.2f} | **{r['ratio']:.2f}** | {acc_b} | {acc_t} |"
                     + (f" {r['baseline_us_per_dot']:.2f} | {r['bostrack_us_per_dot'] / r['baseline_us_per_dot']:.3f} |"
                        if a.baseline else ""))
    load1 = open("/proc/loadavg").read().split()[:3]
    meta = {
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime(t_start)),
        "runs": a.runs, "load_start": load0, "load_end": load1,
        "wall_s": round(time.time() - t_start, 1), "trackpy": hello["trackpy"],
        "numpy": hello["numpy"], "engine": hello["engine"],
        "trackpy_import_cpu_ms": 1e3 * hello["import_cpu_s"],
        "python": sys.version.split()[0], "bostrack": a.bostrack, "baseline": a.baseline,
    }
    text = "\n".join(lines)
    note = (f"\n\nmedian CPU of {a.runs} interleaved runs; trackpy {meta['trackpy']} (engine "
            f"{meta['engine']}, "
            f"numpy {meta['numpy']}), its interpreter start + imports once per process: "
            f"{meta['trackpy_import_cpu_ms']:.0f} ms CPU (not in the table); load average "
            f"{' '.join(load0)} at the start, {' '.join(load1)} at the end; {meta['wall_s']} s.")
    print(text + note)
    with open(os.path.join(a.out, "results.md"), "w") as fh:
        fh.write(text + note + "\n")
    with open(os.path.join(a.out, "results.json"), "w") as fh:
        json.dump({"meta": meta, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    if sys.argv[1:] == ["--worker"]:
        worker()
    else:
        main()
