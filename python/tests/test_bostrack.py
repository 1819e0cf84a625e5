"""Tests of the Python package against the command-line tool and the files a run writes.

Run by python/run-tests.sh (README's test command) in a fresh virtual environment. The real
sample is expected in ../shared/data/bos-sample beside the repository: tests that need it skip
with a message when it is absent, and fail when CI=true.
"""

import csv
import json
import math
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import bostrack

ROOT = Path(__file__).resolve().parents[2]
CLI = ROOT / "target" / "release" / "bostrack"
SAMPLE = ROOT.parent / "shared" / "data" / "bos-sample"
DEMO = ROOT / "testdata" / "demo"


def need_sample():
    if not (SAMPLE / "pair" / "reference.tif").is_file():
        if os.environ.get("CI") == "true":
            pytest.fail(f"the real sample is missing: {SAMPLE}")
        pytest.skip(f"the real sample is not at {SAMPLE}")


def cli(*args, cwd=ROOT):
    assert CLI.is_file(), f"{CLI} is missing: build it with cargo build --release -p bostrack"
    r = subprocess.run([str(CLI), *map(str, args)], cwd=cwd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def cell(v):
    """A value as the CLI writes it: 6 decimals, an unknown value as the empty field."""
    if isinstance(v, (str, np.str_)):
        return str(v)
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return "" if not math.isfinite(v) else f"{v:.6f}"


def assert_table_equals_csv(cols, path):
    header, rows = read_csv(path)
    assert header == list(bostrack.LOCATE_UNITS)
    assert list(cols) == header
    n = len(rows)
    assert all(len(cols[c]) == n for c in header)
    for k, name in enumerate(header):
        got = [cell(v) for v in cols[name]]
        want = [r[k] for r in rows]
        bad = [(r, g, w) for r, (g, w) in enumerate(zip(got, want)) if g != w]
        assert not bad, f"column {name}: first differences {bad[:3]}"
    return n


def demo_config(tmp_path, arrays=True):
    """The demo campaign's pipeline.toml, written with absolute paths into tmp_path."""
    text = (ROOT / "pipeline.toml").read_text()
    text = text.replace('dir = "testdata/demo"', f'dir = "{DEMO}"', 1)
    text = text.replace('dir = "out"', f'dir = "{tmp_path / "out"}"', 1)
    if arrays:
        text = text.replace("arrays = []", 'arrays = ["npz", "mat"]', 1)
        assert 'arrays = ["npz", "mat"]' in text
    # (the list may span several lines)
    text, n = re.subn(r"^figures = \[.*?\]", "figures = []", text, count=1, flags=re.S | re.M)
    assert n == 1
    p = tmp_path / "pipeline.toml"
    p.write_text(text)
    return p


# --- locate -------------------------------------------------------------------------------


def test_locate_on_the_real_reference_equals_the_cli_csv_and_releases_the_gil(tmp_path):
    need_sample()
    ref, mask = SAMPLE / "pair" / "reference.tif", SAMPLE / "mask.tif"
    out = tmp_path / "dots.csv"
    cli("locate", ref, "--mask", mask, "-o", out)
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=tick)
    t.start()
    t0 = time.perf_counter()
    cols = bostrack.locate(ref, mask, as_frame=False)
    seconds = time.perf_counter() - t0
    stop.set()
    t.join()
    assert assert_table_equals_csv(cols, out) == 12236
    # another Python thread ran while the library computed (the GIL was released)
    during = [x for x in ticks if t0 < x < t0 + seconds]
    assert len(during) > 0.2 * seconds / 0.001, (len(during), seconds)
    # the mask as an array (a numpy logical) gives the same rows
    keep = bostrack.read_image(mask) > 0
    again = bostrack.locate(ref, keep, as_frame=False)
    np.testing.assert_array_equal(again["x"], cols["x"])


def test_locate_takes_arrays_of_every_dtype_and_any_strides():
    ref = DEMO / "reference.tif"
    want = bostrack.locate(ref, as_frame=False)
    img = bostrack.read_image(ref)  # float64 samples of a 16-bit file
    u16 = img.astype(np.uint16)
    # the clip level of a uint16 array comes from its samples, as for the file
    for a in [u16, np.asfortranarray(u16), u16[::-1, ::-1][::-1, ::-1], u16.T.copy().T]:
        got = bostrack.locate(a, as_frame=False)
        for name in ("x", "y", "crlb_x", "sigma_x", "amplitude"):
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)
        assert list(got["status"]) == list(want["status"])
    # a strided view of a larger array: every other column of a doubled image
    wide = np.repeat(u16, 2, axis=1)
    got = bostrack.locate(wide[:, ::2], as_frame=False)
    np.testing.assert_array_equal(got["x"], want["x"])
    # float arrays have no clip level unless given: the same dots, here nothing clips
    f32 = bostrack.locate(img.astype(np.float32), saturation=4095, as_frame=False)
    np.testing.assert_array_equal(f32["x"], want["x"])
    u8 = bostrack.locate((img / img.max() * 250).astype(np.uint8), as_frame=False)
    assert len(u8["x"]) == len(want["x"])


def test_locate_mask_as_array_and_as_file(tmp_path):
    ref = DEMO / "reference.tif"
    img = bostrack.read_image(ref)
    mask = np.zeros(img.shape, dtype=bool)
    mask[:, : img.shape[1] // 2] = True
    got = bostrack.locate(img.astype(np.uint16), mask, as_frame=False)
    inside = ~np.char.find(got["flags"], "masked").astype(bool)
    assert np.all(got["x_pred"][got["status"] != "not_fitted"] < img.shape[1] / 2 + 3)
    assert inside.any()
    same = bostrack.locate(img.astype(np.uint16), mask.astype(np.uint8) * 255, as_frame=False)
    np.testing.assert_array_equal(same["x"], got["x"])


# --- bad input ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "image, exc, words",
    [
        (np.zeros((64, 64), dtype=np.int64), TypeError, "uint8, uint16, float32 or float64"),
        (np.zeros((64, 64), dtype=bool), TypeError, "dtype bool"),
        (np.zeros((4, 64, 64), dtype=np.uint16), ValueError, "2-D array"),
        (np.zeros(64, dtype=np.uint16), ValueError, "2-D array"),
        ([[1, 2], [3, 4]], TypeError, "int64"),
        (object(), TypeError, "numpy array or the path"),
    ],
)
def test_bad_images_are_exceptions(image, exc, words):
    with pytest.raises(exc, match=words):
        bostrack.locate(image)


def test_bad_arguments_are_exceptions_with_the_cli_messages(tmp_path):
    img = bostrack.read_image(DEMO / "reference.tif").astype(np.uint16)
    with pytest.raises(ValueError, match=r"mask is 10 x 10 pixels .* the image"):
        bostrack.locate(img, np.ones((10, 10), dtype=bool))
    with pytest.raises(ValueError, match="unknown model `round`"):
        bostrack.locate(img, model="round")
    with pytest.raises(ValueError, match="read_noise"):
        bostrack.locate(img, read_noise=-1.0)
    with pytest.raises(FileNotFoundError, match="absent.tif"):
        bostrack.locate(tmp_path / "absent.tif")
    # a file that is not an image: the one-line message the CLI prints (after "error: ")
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"II*\x00garbage")
    r = subprocess.run([str(CLI), "locate", junk, "-o", tmp_path / "d.csv"], capture_output=True, text=True)
    assert r.returncode == 1
    with pytest.raises(OSError) as e:
        bostrack.locate(junk)
    assert r.stderr.strip() == f"error: {e.value}"
    with pytest.raises(ValueError, match="no lattice|detection failed|no dots|dots"):
        bostrack.locate(np.full((64, 64), 100, dtype=np.uint16), read_noise=2.0)


def test_missing_or_bad_config_is_an_exception(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.toml"):
        bostrack.run(tmp_path / "missing.toml", progress=False)
    bad = tmp_path / "bad.toml"
    bad.write_text("[match]\nserach_radius = 0.3\n")
    r = subprocess.run([str(CLI), "check", bad], capture_output=True, text=True)
    with pytest.raises(ValueError) as e:
        bostrack.run(bad, progress=False)
    assert "did you mean `search_radius`?" in str(e.value)
    assert r.stderr.strip() == f"error: {e.value}"
    with pytest.raises(FileNotFoundError):
        bostrack.load(tmp_path / "no-run-here")
    with pytest.raises(ValueError, match="not a bostrack run folder"):
        bostrack.load(tmp_path)
    with pytest.raises(FileNotFoundError):
        bostrack.crlb(tmp_path / "missing-setup.toml")


# --- run, load and the lattice arrays -----------------------------------------------------


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("demo")
    cfg = demo_config(tmp)
    seen = []
    report = bostrack.run(cfg, progress=lambda *a: seen.append(a))
    assert report["computed"] == 3 and not report["failures"], report
    assert seen and seen[-1][0] == 3, seen
    return tmp / "out"


def parse_dots(path):
    header, rows = read_csv(path)
    return header, rows


def test_load_equals_dots_csv(demo_run):
    data = bostrack.load(demo_run, as_dataset=False)
    assert data["frames"] == ["frame_01", "frame_02", "frame_03"]
    bits = data["flag_bits"]
    for k, stem in enumerate(data["frames"]):
        header, rows = parse_dots(demo_run / stem / "dots.csv")
        i0, j0 = data["i"][0], data["j"][0]
        present = np.zeros(data["fields"]["present"][k].shape, dtype=bool)
        for r in rows:
            rec = dict(zip(header, r))
            a, b = int(rec["i"]) - i0, int(rec["j"]) - j0
            present[a, b] = True
            for name, text in rec.items():
                if name in ("i", "j"):
                    continue
                got = data["fields"][name][k][a, b]
                if name == "valid":
                    assert bool(got) == (text == "true")
                elif name == "flags":
                    want = sum(bits[f] for f in text.split("|") if f)
                    assert int(got) == want
                elif text == "":
                    assert math.isnan(got), (name, got)
                else:
                    assert got == float(text), (name, got, text)
        np.testing.assert_array_equal(data["fields"]["present"][k], present)
        # a site without a row is NaN in every numeric array
        assert np.all(np.isnan(data["fields"]["dx"][k][~present]))
        assert data["summaries"][stem]["counts"]["reference_sites"] == len(rows)
    assert data["units"]["dx"] == "px" and data["units"]["amp_ref"] == "counts"


def test_npz_and_mat_hold_the_same_values_as_load(demo_run):
    from scipy.io import loadmat

    data = bostrack.load(demo_run, as_dataset=False)
    for k, stem in enumerate(data["frames"]):
        npz = np.load(demo_run / stem / "fields.npz")
        mat = loadmat(demo_run / stem / "fields.mat")
        np.testing.assert_array_equal(npz["i"], data["i"])
        np.testing.assert_array_equal(mat["i"].ravel(), data["i"])
        np.testing.assert_array_equal(mat["j"].ravel(), data["j"])
        units = dict(zip(npz["variables"], npz["units"]))
        assert units == data["units"]
        for name, arrays in data["fields"].items():
            want = arrays[k]
            a, m = npz[name], mat[name]
            assert a.shape == m.shape == want.shape, name
            if want.dtype == bool:
                assert a.dtype == bool
                np.testing.assert_array_equal(m.astype(bool), want)
            else:
                np.testing.assert_array_equal(m, want, err_msg=name)
            np.testing.assert_array_equal(a, want, err_msg=name)
            assert str(mat["units"][name][0, 0][0]) if units[name] else True
            if units[name]:
                assert mat["units"][name][0, 0][0] == units[name]
        flag_bits = mat["flag_bits"]
        for name, bit in zip(npz["flag_names"], npz["flag_bits"]):
            assert flag_bits[name][0, 0][0, 0] == bit == data["flag_bits"][name]


def test_octave_loads_the_mat_file(demo_run, tmp_path):
    octave = shutil.which("octave-cli") or shutil.which("octave")
    if octave is None:
        pytest.skip("Octave is not installed (apt-get install octave)")
    mat = demo_run / "frame_01" / "fields.mat"
    out = tmp_path / "dx.txt"
    script = (
        f"s = load('{mat}'); d = s.dx; d(isnan(d)) = -999; "
        f"f = fopen('{out}', 'w'); fprintf(f, '%.17g\\n', d); fclose(f); "
        f"printf('%s %d %d %s\\n', class(s.valid), size(s.dx), s.units.dx);"
    )
    r = subprocess.run([octave, "--no-gui", "--quiet", "--eval", script], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    npz = np.load(demo_run / "frame_01" / "fields.npz")
    want = npz["dx"].copy()
    want[np.isnan(want)] = -999
    got = np.loadtxt(out)  # column-major, as Octave prints a matrix
    np.testing.assert_array_equal(got, want.ravel(order="F"))
    assert r.stdout.split()[:4] == ["logical", str(want.shape[0]), str(want.shape[1]), "px"]


def test_load_as_xarray_dataset_when_installed(demo_run):
    xr = pytest.importorskip("xarray")
    ds = bostrack.load(demo_run)
    assert isinstance(ds, xr.Dataset)
    assert ds["dx"].dims == ("frame", "i", "j")
    assert ds["u_dx"].attrs["units"] == "px"


def test_a_rerun_skips_and_ctrl_c_stops_between_frames(tmp_path):
    cfg = demo_config(tmp_path, arrays=False)

    def interrupt(done, to_do, failed, messages):
        # a real SIGINT: Python's handler raises KeyboardInterrupt here, on the calling thread
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)

    with pytest.raises(KeyboardInterrupt):
        bostrack.run(cfg, jobs=1, progress=interrupt)
    out = tmp_path / "out"
    done = [d for d in out.iterdir() if (d / "summary.json").is_file()]
    assert len(done) < 3
    report = bostrack.run(cfg, progress=False)
    assert report["computed"] == 3 - len(done) and report["skipped"] == len(done)
    again = bostrack.run(cfg, progress=False)
    assert again["computed"] == 0 and again["skipped"] == 3


# --- crlb ---------------------------------------------------------------------------------


def test_crlb_equals_the_cli_json():
    setup = ROOT / "testdata" / "crlb-setup.toml"
    want = json.loads(cli("crlb", setup, "--json").stdout)
    got = bostrack.crlb(setup)
    assert got == want
    assert got["crlb_x"] > 0 and got["u_d_x"] >= got["crlb_x"]


def test_locate_gives_a_dataframe_with_units_when_pandas_is_installed():
    pd = pytest.importorskip("pandas")
    df = bostrack.locate(DEMO / "reference.tif")
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == list(bostrack.LOCATE_UNITS)
    assert df.attrs["units"]["crlb_x"] == "px" and df.attrs["spacing_px"] > 0
    cols = bostrack.locate(DEMO / "reference.tif", as_frame=False)
    np.testing.assert_array_equal(df["x"].to_numpy(), cols["x"])
