"""Type stubs of the extension module `bostrack._bostrack` (Rust, pyo3). Use the documented
wrappers of `bostrack` (locate, run, load, crlb); these are their building blocks."""

from typing import Any, Callable, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

def locate(
    image: Union[str, npt.NDArray[Any]],
    mask: Union[str, npt.NDArray[Any], None] = None,
    *,
    spacing: Optional[float] = None,
    diameter: Optional[float] = None,
    model: str = "elliptical",
    saturation: Union[str, float, None] = None,
    read_noise: Optional[float] = None,
    jobs: Optional[int] = None,
) -> Dict[str, Any]:
    """Columns of `bostrack locate` (i, j: int32; iterations: uint32; status, flags: lists of
    str; the rest float64, px / counts / 1, NaN where unknown) and `__info__` (spacing_px,
    read_variance counts², gain counts per electron, offset counts, saturation counts)."""

def run(
    config: str,
    out: Optional[str] = None,
    *,
    jobs: Optional[int] = None,
    force: bool = False,
    progress: Optional[Callable[[int, int, int, List[str]], None]] = None,
) -> Dict[str, Any]:
    """The batch job; `progress(done, to_do, failed, messages)` on the calling thread."""

def fields(
    dots_csv: str,
) -> Tuple[npt.NDArray[np.int32], npt.NDArray[np.int32], Dict[str, npt.NDArray[Any]], Dict[str, str]]:
    """A dots.csv on its lattice: (i, j, {name: (n_i, n_j) array}, {name: unit})."""

def flag_bits() -> List[Tuple[str, int]]:
    """(name, bit) of every per-dot flag."""

def crlb(setup: str) -> str:
    """The prediction of a setup file as JSON text (as `bostrack crlb --json`)."""

def read_image(path: str) -> npt.NDArray[np.float64]:
    """An image file as a 2-D float64 array."""
