"""bostrack: Background-Oriented Schlieren dot tracking with per-dot uncertainties.

The Python interface of the bostrack library (Rust, called in-process, not a subprocess):

- :func:`locate` detects and fits every dot of one image (a numpy array or a file);
- :func:`run` processes a campaign described by a ``pipeline.toml`` (the ``bostrack run`` job);
- :func:`load` reads a finished run as fields on the dot lattice (xarray or numpy);
- :func:`crlb` predicts what an experiment will measure (``bostrack crlb``).

Conventions (docs/CONVENTIONS.md of the repository): pixel centres at integer coordinates,
origin at the centre of the top-left pixel, x to the right (columns), y down (rows), lengths in
px, displacement = gradient - reference, uncertainties 1 sigma, dot diameter d = 4 sigma.
Errors are Python exceptions carrying the message the command-line tool prints:
``FileNotFoundError`` for a missing file, ``OSError`` for a file that cannot be read or written,
``TypeError``/``ValueError`` for bad arguments or bad contents, ``RuntimeError`` otherwise.
The GIL is released while the library computes, and Ctrl-C stops a :func:`run` between frames
(the frames done stay complete; running again computes the rest).
"""

from __future__ import annotations

import json
import os
import re
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Union

import numpy as np

from . import _bostrack

__version__: str = _bostrack.__version__

__all__ = ["locate", "run", "load", "crlb", "read_image", "LOCATE_UNITS", "flag_bits"]

PathLike = Union[str, "os.PathLike[str]"]

#: Unit of every column of :func:`locate` ("1": dimensionless; "" for text columns).
LOCATE_UNITS: Dict[str, str] = {
    "i": "index",
    "j": "index",
    "x": "px",
    "y": "px",
    "status": "",
    "flags": "",
    "sigma_x": "px",
    "sigma_y": "px",
    "rho": "1",
    "amplitude": "counts",
    "background": "counts",
    "crlb_x": "px",
    "crlb_y": "px",
    "rms": "counts",
    "iterations": "1",
    "x_pred": "px",
    "y_pred": "px",
}


def _native(a: Any) -> Any:
    """An array in native byte order (the library reads native samples); others unchanged."""
    if isinstance(a, np.ndarray) and not a.dtype.isnative:
        return a.astype(a.dtype.newbyteorder("="))
    return a


def _is_path(x: Any) -> bool:
    return isinstance(x, (str, bytes, os.PathLike))


def _want(module: str, choice: Optional[bool]) -> Any:
    """The optional module when ``choice`` is True or None (and it is installed), else None."""
    if choice is False:
        return None
    try:
        return __import__(module)
    except ImportError:
        if choice:
            raise
        return None


def locate(
    image: Union[np.ndarray, PathLike],
    mask: Union[np.ndarray, PathLike, None] = None,
    *,
    spacing: Optional[float] = None,
    diameter: Optional[float] = None,
    model: str = "elliptical",
    saturation: Union[str, float, None] = None,
    read_noise: Optional[float] = None,
    jobs: Optional[int] = None,
    as_frame: Optional[bool] = None,
) -> Any:
    """Detect every dot of a dot-target image on its lattice and fit each one.

    The same rows and numbers as ``bostrack locate IMAGE -o dots.csv``: one row per lattice
    site, columns ``i, j`` (grid index), ``x, y`` (fitted centre, px; NaN when not fitted),
    ``status`` (why the fit stopped), ``flags`` (``a|b|c``), ``sigma_x, sigma_y`` (px),
    ``rho`` (1), ``amplitude, background`` (counts), ``crlb_x, crlb_y`` (Cramér-Rao bound,
    1 sigma, px), ``rms`` (counts), ``iterations``, ``x_pred, y_pred`` (lattice prediction, px).
    Units are in :data:`LOCATE_UNITS`.

    Parameters
    ----------
    image:
        A 2-D array (rows = y, columns = x) of uint8, uint16, float32 or float64, any strides,
        or the path of a TIFF or PNG file (read as the command-line tool reads it).
    mask:
        Region of interest of the image's shape (bool, or numbers: a pixel is kept when it is
        brighter than the midpoint of the mask's darkest and brightest values), or a file.
    spacing:
        Approximate dot spacing, px (a prior: the lattice is measured from the image).
    diameter:
        Approximate dot diameter d = 4 sigma, px (a prior for the matched filter).
    model:
        ``"elliptical"`` (7 parameters), ``"axis-aligned"`` (rho = 0) or ``"circular"``.
    saturation:
        Clip level in counts, or ``"auto"`` (default): from the file's tags and samples, or
        from an integer array's samples (12-bit data in uint16 clip at 4095); float arrays
        have none unless given. Samples at or above it are left out and flag the dot.
    read_noise:
        Read-noise standard deviation, counts; by default the noise model (read + shot
        noise) is estimated from the image.
    jobs:
        Worker threads (default: the CPUs available).
    as_frame:
        Return a pandas DataFrame (default when pandas is installed); False: a dict of numpy
        arrays.

    Returns
    -------
    A ``pandas.DataFrame`` (with ``attrs``: ``spacing_px``, the noise model in counts² and
    the clip level, and ``units``) or a dict of equally long numpy arrays.
    """
    if _is_path(image):
        image = os.fspath(image)
    else:
        array = np.asarray(image)
        if array.dtype == object:
            raise TypeError(
                "image must be a numpy array or the path of an image file, got "
                + type(image).__name__
            )
        image = _native(array)
    if mask is not None and not _is_path(mask):
        mask = _native(np.asarray(mask))
    elif mask is not None:
        mask = os.fspath(mask)
    cols = _bostrack.locate(
        image,
        mask,
        spacing=spacing,
        diameter=diameter,
        model=model,
        saturation=saturation,
        read_noise=read_noise,
        jobs=jobs,
    )
    info = cols.pop("__info__")
    global _last_info
    _last_info = info
    cols["status"] = np.array(cols["status"], dtype=str)
    cols["flags"] = np.array(cols["flags"], dtype=str)
    pd = _want("pandas", as_frame)
    if pd is None:
        return cols
    df = pd.DataFrame(cols)
    df.attrs.update(info)
    df.attrs["units"] = dict(LOCATE_UNITS)
    return df


#: The facts of the last locate call (spacing, noise model, clip level, library_seconds).
_last_info: Dict[str, Any] = {}


class _Bar:
    """Progress of :func:`run`: a tqdm bar (``tqdm.auto``: a widget in notebooks) when tqdm is
    installed, else a line on stderr every few seconds."""

    def __init__(self, show: bool) -> None:
        self.show = show
        self.bar: Any = None
        self.last = 0.0
        if show:
            try:
                from tqdm.auto import tqdm  # type: ignore

                self.tqdm = tqdm
            except ImportError:
                self.tqdm = None

    def __call__(self, done: int, to_do: int, failed: int, messages: List[str]) -> None:
        if not self.show:
            return
        for m in messages:
            print(m, file=sys.stderr)
        if self.tqdm is not None:
            if self.bar is None and to_do > 0:
                self.bar = self.tqdm(total=to_do, unit="frame", desc="bostrack run")
            if self.bar is not None:
                self.bar.n = done
                self.bar.set_postfix(failed=failed, refresh=False)
                self.bar.refresh()
        elif to_do > 0 and (time.monotonic() - self.last > 5.0 or done == to_do):
            self.last = time.monotonic()
            print(f"frames {done}/{to_do} ({failed} failed)", file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run(
    config: PathLike,
    out: Optional[PathLike] = None,
    *,
    jobs: Optional[int] = None,
    force: bool = False,
    progress: Union[bool, Callable[[int, int, int, List[str]], None]] = True,
) -> Dict[str, Any]:
    """Process every gradient frame of a campaign (``bostrack run CONFIG``).

    Writes the run's folder (``output.dir`` of the configuration, or ``out``): per frame
    ``dots.csv``, ``summary.json``, figures and, with ``[output] arrays``, ``fields.npz`` /
    ``fields.mat``; the campaign table and the run record. Resumable: complete frames are
    skipped unless ``force``. Ctrl-C stops the run between frames (``KeyboardInterrupt``); the
    frames done are complete and a second call computes the rest.

    Parameters
    ----------
    config:
        The campaign's ``pipeline.toml``.
    out:
        Output folder (default: ``output.dir`` of the configuration).
    jobs:
        Worker threads (default: ``[run] jobs``, else the CPUs available).
    force:
        Recompute every frame, and accept a folder written with another configuration.
    progress:
        True: a progress bar (tqdm when installed); False: nothing; or a callable
        ``progress(done, to_do, failed, messages)`` called on the calling thread.

    Returns
    -------
    dict with ``out_dir``, ``frames``, ``computed``, ``skipped``, ``figures_drawn``,
    ``seconds``, ``threads``, ``warnings`` and ``failures`` (a list of dicts with ``frame``,
    ``stem``, ``file``, ``reason``; a frame that failed does not stop the others).
    """
    bar = _Bar(progress is True)
    callback = progress if callable(progress) else bar
    try:
        report = _bostrack.run(
            os.fspath(config),
            None if out is None else os.fspath(out),
            jobs=jobs,
            force=force,
            progress=callback,
        )
    finally:
        bar.close()
    for w in report["warnings"]:
        warnings.warn(w, stacklevel=2)
    for f in report["failures"]:
        warnings.warn(f"frame {f['frame']} ({f['file']}) failed: {f['reason']}", stacklevel=2)
    return report


def _natural_key(name: str) -> List[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _frames(run_dir: Path) -> List[str]:
    """The frame folders of a run in frame order: those of campaign.json when present, else
    every folder with a summary.json in natural order."""
    campaign = run_dir / "campaign.json"
    if campaign.is_file():
        data = json.loads(campaign.read_text())
        rows = data.get("rows") if isinstance(data, dict) else None
        if isinstance(rows, list):
            stems = [r.get("stem") for r in rows if isinstance(r, dict) and r.get("stem")]
            if stems:
                return stems
    dirs = [p.name for p in run_dir.iterdir() if (p / "summary.json").is_file()]
    return sorted(dirs, key=_natural_key)


def load(run_dir: PathLike, *, as_dataset: Optional[bool] = None) -> Any:
    """A finished run (the output folder of :func:`run` or ``bostrack run``) on the dot lattice.

    Every quantity of the frames' ``dots.csv`` as an array of shape (frames, n_i, n_j): frame,
    then rows i and columns j of the grid index (i grows along the lattice vector closest to
    +x, j along the one closest to +y: on an unrotated target an (i, j) slice is the image
    transposed; plot against ``x_ref``, ``y_ref``). NaN where a site has no dot or a value is
    unknown; ``present`` (bool) tells which sites have a row, ``valid`` (bool) which
    displacements are valid, ``flags`` (uint32) the per-dot flags as bits (``flag_bits``).
    The values are those of the CSV text, as in ``fields.npz`` and ``fields.mat``.

    Returns
    -------
    An ``xarray.Dataset`` (default when xarray is installed) with dimensions ``frame, i, j``,
    each variable's unit in ``attrs["units"]``, and in the dataset's ``attrs``: ``summaries``
    (each frame's summary.json), ``campaign`` (campaign.json), ``failed`` (frames without
    outputs) and ``flag_bits``. Otherwise (or with ``as_dataset=False``) a dict with ``frames``,
    ``i``, ``j``, ``fields`` ({name: array}), ``units``, ``summaries``, ``campaign``,
    ``failed`` and ``flag_bits``.
    """
    root = Path(os.fspath(run_dir))
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such run folder")
    if not ((root / "run.toml").is_file() or (root / "shards").is_dir()):
        raise ValueError(f"{root}: no run record (run.toml): not a bostrack run folder")
    frames: List[str] = []
    failed: List[str] = []
    per_frame: List[Dict[str, np.ndarray]] = []
    summaries: Dict[str, Any] = {}
    ij: Any = None
    units: Dict[str, str] = {}
    for stem in _frames(root):
        d = root / stem
        if not (d / "summary.json").is_file():
            failed.append(stem)
            continue
        i, j, arrays, units = _bostrack.fields(os.fspath(d / "dots.csv"))
        if ij is None:
            ij = (i, j)
        elif not (np.array_equal(ij[0], i) and np.array_equal(ij[1], j)):
            raise ValueError(f"{d / 'dots.csv'}: its lattice differs from the first frame's")
        frames.append(stem)
        per_frame.append(arrays)
        summaries[stem] = json.loads((d / "summary.json").read_text())
    campaign_file = root / "campaign.json"
    campaign = json.loads(campaign_file.read_text()) if campaign_file.is_file() else None
    i, j = ij if ij is not None else (np.zeros(0, np.int32), np.zeros(0, np.int32))
    names = list(per_frame[0]) if per_frame else []
    fields = {n: np.stack([a[n] for a in per_frame]) for n in names}
    bits = flag_bits()
    xr = _want("xarray", as_dataset)
    if xr is None:
        return {
            "frames": frames,
            "i": i,
            "j": j,
            "fields": fields,
            "units": units,
            "summaries": summaries,
            "campaign": campaign,
            "failed": failed,
            "flag_bits": bits,
        }
    ds = xr.Dataset(
        {n: (("frame", "i", "j"), a, {"units": units.get(n, "")}) for n, a in fields.items()},
        coords={"frame": frames, "i": i, "j": j},
    )
    ds.attrs.update(
        summaries=summaries, campaign=campaign, failed=failed, flag_bits=bits
    )
    return ds


def flag_bits() -> Dict[str, int]:
    """The bit of every per-dot flag in the ``flags`` arrays (docs/CONVENTIONS.md)."""
    return dict(_bostrack.flag_bits())


def crlb(setup: PathLike) -> Dict[str, Any]:
    """The experiment-design prediction of a setup file (``bostrack crlb SETUP --json``).

    Returns a dict: ``shift_x, shift_y`` (px), ``sigma_x, sigma_y`` (px), ``rho``,
    ``crlb_x, crlb_y`` and ``crlb_ref_x, crlb_ref_y`` (exact Cramér-Rao bounds, 1 sigma, px),
    ``eq35_*`` (the closed form, px), ``ar_x, ar_y`` and ``ar_exact_*`` (amplification ratios),
    ``u_d_x, u_d_y`` (px), ``magnification``, ``f_number``, ``sensitivity_px`` (px per kg/m⁴),
    ``flags`` and the other fields of ``bostrack crlb --json`` (None where not defined).
    """
    return json.loads(_bostrack.crlb(os.fspath(setup)))


def read_image(path: PathLike) -> np.ndarray:
    """An image file (TIFF or PNG, as bostrack reads it) as a 2-D float64 array (rows = y)."""
    return _bostrack.read_image(os.fspath(path))
