"""MATLAB ``.mat`` files through a column map: each ``column`` names a variable.

Published drive data and lab recordings are usually MATLAB files: vectors of
equal length, one per signal, at the top level or as fields of a struct. The
column map that reads a CSV reads them too; its ``column`` names the variable
(``"velocity"``, or a struct field path ``"data.time"``)::

    time = { column = "data.t", scale = 0.001 }       # ms
    [channels]
    X_velocity_mm_min = { column = "data.v", scale = 20 }   # motor rpm x 20 mm lead
    X_current_a = { column = "data.i" }

Version 5 files (MATLAB's default up to R2006b and ``save -v7``) are read with
SciPy; version 7.3 files (``save -v7.3``) are HDF5 and need h5py (the extra
``ncmeasure[matlab]``), imported only when such a file is read. A MATLAB
file is read whole: its format does not stream.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import check_times
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import CHUNK_ROWS

__all__ = ["is_matlab", "read_matlab"]

log = logging.getLogger(__name__)

_HDF5_SIGNATURE: Final = b"\x89HDF\r\n\x1a\n"
_MATLAB_HEADER: Final = b"MATLAB"
#: Where a MATLAB 7.3 file's HDF5 data begin (after its 512-byte text header).
_USERBLOCK: Final = 512


def is_matlab(path: Path) -> bool:
    """True for a MATLAB file (its text header, or HDF5 data) whatever its name."""
    try:
        with path.open("rb") as file:
            head = file.read(_USERBLOCK + len(_HDF5_SIGNATURE))
    except OSError:
        return False
    return head.startswith(_MATLAB_HEADER) or _HDF5_SIGNATURE in (
        head[: len(_HDF5_SIGNATURE)],
        head[_USERBLOCK:],
    )


def _is_hdf5(path: Path) -> bool:
    with path.open("rb") as file:
        head = file.read(_USERBLOCK + len(_HDF5_SIGNATURE))
    return _HDF5_SIGNATURE in (head[: len(_HDF5_SIGNATURE)], head[_USERBLOCK:])


def read_matlab(
    job: ImportJob,
    refs: Mapping[str, str | int],
    map_name: str,
) -> tuple[dict[str, NDArray[np.float64]], list[str], str]:
    """The vectors the map names, by target (``time_s``, channel names), as float64.

    Args:
        job: The import (its file).
        refs: Target -> variable name or struct field path (``data.time``).
        map_name: How messages name the column map.

    Returns:
        The vectors, the file's variables the map does not name, and the file's
        version in words (``MATLAB 5``, ``MATLAB 7.3 (HDF5)``).

    Raises:
        ConfigError: A ``column`` is a position, not a variable name.
        RecordingError: The file cannot be read, a variable is missing or is no
            numeric vector, or the vectors differ in length.
    """
    path = job.path
    positions = [f"{t}: column = {r}" for t, r in refs.items() if not isinstance(r, str)]
    if positions:
        raise ConfigError(
            f"{map_name}: a MATLAB file's columns are variables, named by text "
            f'(column = "data.time"), not by position: {", ".join(positions)}'
        )
    names = {t: str(r) for t, r in refs.items()}
    if _is_hdf5(path):
        vectors, others = _read_hdf5(path, names)
        version = "MATLAB 7.3 (HDF5)"
    else:
        vectors, others = _read_v5(path, names)
        version = "MATLAB 5"
    lengths = {t: len(v) for t, v in vectors.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{names[t]!r}: {n}" for t, n in lengths.items())
        raise RecordingError(f"{path}: the variables differ in length ({listed})")
    return vectors, others, version


def _vector(path: Path, name: str, value: Any) -> NDArray[np.float64]:
    array = np.asarray(value)
    if array.dtype.kind not in "biuf" or array.ndim == 0:
        raise RecordingError(
            f"{path}: variable {name!r} is not a numeric vector ({_shape_words(array)})"
        )
    if sum(n > 1 for n in array.shape) > 1:
        raise RecordingError(
            f"{path}: variable {name!r} is a {'x'.join(map(str, array.shape))} matrix, "
            "not a vector (name one column of it as its own variable)"
        )
    return np.ravel(array).astype(np.float64)


def _shape_words(array: NDArray[Any]) -> str:
    if array.dtype.kind in "US":
        return "text"
    if array.dtype.kind == "O":
        return "a cell array or struct"
    return f"{array.dtype} of shape {array.shape}"


def _missing(path: Path, name: str, part: str, available: list[str]) -> RecordingError:
    where = f"{name!r}" if part == name else f"{name!r} (no {part!r})"
    return RecordingError(
        f"{path}: no variable {where}",
        [f"the file has: {', '.join(available) if available else 'no variables'}"],
    )


def _read_v5(
    path: Path, names: Mapping[str, str]
) -> tuple[dict[str, NDArray[np.float64]], list[str]]:
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    try:
        data = loadmat(path, simplify_cells=True)
    except (MatReadError, ValueError, OSError, NotImplementedError) as exc:
        raise RecordingError(f"{path}: not a MATLAB file that can be read ({exc})") from exc
    top = {k: v for k, v in data.items() if not k.startswith("__")}
    vectors = {}
    for target, name in names.items():
        value: Any = top
        for depth, part in enumerate(name.split(".")):
            if not isinstance(value, dict) or part not in value:
                here = value if isinstance(value, dict) else {}
                prefix = ".".join(name.split(".")[:depth])
                listed = sorted(f"{prefix}.{k}" if prefix else k for k in here)
                raise _missing(path, name, part, listed)
            value = value[part]
        vectors[target] = _vector(path, name, value)
    used = {n.split(".")[0] for n in names.values()}
    return vectors, sorted(k for k in top if k not in used)


def _read_hdf5(
    path: Path, names: Mapping[str, str]
) -> tuple[dict[str, NDArray[np.float64]], list[str]]:
    try:
        import h5py
    except ImportError as exc:
        raise RecordingError(
            f"{path}: a MATLAB 7.3 (HDF5) file needs h5py: pip install 'ncmeasure[matlab]' "
            "(or save it in MATLAB with -v7)"
        ) from exc
    try:
        file = h5py.File(path, "r")
    except OSError as exc:
        raise RecordingError(f"{path}: not an HDF5 file that can be read ({exc})") from exc
    with file:
        vectors = {}
        for target, name in names.items():
            node: Any = file
            for depth, part in enumerate(name.split(".")):
                if not isinstance(node, h5py.Group) or part not in node:
                    here = list(node.keys()) if isinstance(node, h5py.Group) else []
                    prefix = ".".join(name.split(".")[:depth])
                    listed = sorted(f"{prefix}.{k}" if prefix else k for k in here)
                    raise _missing(path, name, part, [n for n in listed if "#" not in n])
                node = node[part]
            if not isinstance(node, h5py.Dataset):
                raise RecordingError(f"{path}: {name!r} is a struct, not a vector")
            vectors[target] = _vector(path, name, node[()])
        used = {n.split(".")[0] for n in names.values()}
        others = sorted(k for k in file if k not in used and not k.startswith("#"))
    return vectors, others


def feed(
    job: ImportJob,
    time_s: NDArray[np.float64],
    values: NDArray[np.float64],
    append: Callable[[NDArray[np.float64], NDArray[np.float64]], None],
) -> None:
    """Check the times and hand the rows on in chunks."""
    path = job.path
    check_times(time_s, -np.inf, lambda i: f"{path}: sample {i + 1}")
    for start in range(0, len(time_s), CHUNK_ROWS):
        append(time_s[start : start + CHUNK_ROWS], values[start : start + CHUNK_ROWS])


def import_matlab_meta(
    job: ImportJob,
    refs: Mapping[str, str | int],
    scales: Mapping[str, tuple[float, float]],
    period_s: float | None,
    map_name: str,
    open_sink: Callable[[], Callable[[NDArray[np.float64], NDArray[np.float64]], None]],
) -> RecordingMeta:
    """Read the vectors, convert them (``raw x scale + offset``) and write the recording.

    ``refs`` and ``scales`` hold ``time_s`` when the map has a time variable;
    the channels follow in the recording's order.
    """
    vectors, others, version = read_matlab(job, refs, map_name)
    job.note(f"{job.path.name}: {version} file")
    rows = len(next(iter(vectors.values())))
    if rows < 2:
        raise RecordingError(f"{job.path}: the variables hold {rows} sample(s); at least 2")
    if "time_s" in vectors:
        scale, offset = scales["time_s"]
        time_s = vectors["time_s"] * scale + offset
    else:
        assert period_s is not None
        time_s = np.arange(rows, dtype=np.float64) * period_s
    targets = [t for t in refs if t != "time_s"]
    values = np.column_stack([vectors[t] * scales[t][0] + scales[t][1] for t in targets])
    for target in ["time_s", *targets] if "time_s" in refs else targets:
        nan = int(np.count_nonzero(np.isnan(vectors[target])))
        if nan:
            job.note(f"{target}: {nan} NaN value(s) in variable {refs[target]!r}")
    if others:
        job.note(
            f"{len(others)} variable(s) not in the column map, not imported: "
            f"{', '.join(map(repr, others))}"
        )
    feed(job, time_s, values, open_sink())
    return job.finish()
