"""Run the demo campaign from Python and plot its displacement field and uncertainty.

    pip install ./python matplotlib          # from the repository root
    python examples/python_demo.py [OUT_DIR]  # writes OUT_DIR/python-demo.png (default: out-python)

The campaign is testdata/demo (a synthetic target with known truth, described by pipeline.toml);
the run goes to OUT_DIR with lattice arrays for numpy and MATLAB (fields.npz, fields.mat).
"""

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import bostrack

root = Path(__file__).resolve().parents[1]
out = Path(sys.argv[1] if len(sys.argv) > 1 else "out-python").resolve()

# pipeline.toml with absolute paths, the run's folder, and lattice arrays
text = (root / "pipeline.toml").read_text()
text = text.replace('dir = "testdata/demo"', f'dir = "{root / "testdata" / "demo"}"', 1)
text = text.replace('dir = "out"', f'dir = "{out}"', 1)
text = text.replace("arrays = []", 'arrays = ["npz", "mat"]', 1)
config = Path(tempfile.mkdtemp()) / "pipeline.toml"
config.write_text(text)

report = bostrack.run(config)  # a progress bar with tqdm installed
print(f"{report['computed']} frames computed, {report['skipped']} complete already, in {report['out_dir']}")

run = bostrack.load(out, as_dataset=False)  # dict of (frame, i, j) arrays
f = run["fields"]
k = len(run["frames"]) - 1  # the last frame
valid = f["valid"][k]
x, y = f["x_ref"][k], f["y_ref"][k]
dx, dy = f["dx"][k], f["dy"][k]
u_d = np.hypot(f["u_dx"][k], f["u_dy"][k])  # |u_d|, px (1 sigma)

fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
m = a.quiver(x[valid], y[valid], dx[valid], dy[valid], np.hypot(dx, dy)[valid], angles="xy")
fig.colorbar(m, ax=a, label="|d| (px)")
a.set_title(f"displacement, {run['frames'][k]} ({valid.sum()} valid dots)")
m = b.scatter(x[valid], y[valid], c=u_d[valid], s=12, cmap="viridis")
fig.colorbar(m, ax=b, label="|u_d| (px, 1σ)")
b.set_title("displacement uncertainty")
for ax in (a, b):
    ax.set_aspect("equal")
    ax.invert_yaxis()  # image coordinates: y down
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
png = out / "python-demo.png"
fig.savefig(png, dpi=110)
print(f"median |d| {np.nanmedian(np.hypot(dx, dy)[valid]):.4f} px, median |u_d| {np.nanmedian(u_d[valid]):.4f} px; wrote {png}")
