"""Type stubs of `bostrack` (docstrings with units are in __init__.py)."""

import os
from typing import Any, Callable, Dict, List, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str
PathLike = Union[str, os.PathLike[str]]
LOCATE_UNITS: Dict[str, str]

def locate(
    image: Union[npt.NDArray[Any], PathLike],
    mask: Union[npt.NDArray[Any], PathLike, None] = None,
    *,
    spacing: Optional[float] = None,
    diameter: Optional[float] = None,
    model: str = "elliptical",
    saturation: Union[str, float, None] = None,
    read_noise: Optional[float] = None,
    jobs: Optional[int] = None,
    as_frame: Optional[bool] = None,
) -> Any: ...
def run(
    config: PathLike,
    out: Optional[PathLike] = None,
    *,
    jobs: Optional[int] = None,
    force: bool = False,
    progress: Union[bool, Callable[[int, int, int, List[str]], None]] = True,
) -> Dict[str, Any]: ...
def load(run_dir: PathLike, *, as_dataset: Optional[bool] = None) -> Any: ...
def flag_bits() -> Dict[str, int]: ...
def crlb(setup: PathLike) -> Dict[str, Any]: ...
def read_image(path: PathLike) -> npt.NDArray[np.float64]: ...
