"""Result files: the :class:`~moju_core.result.Result` of :func:`moju_core.reconstruct`,
written to and read back from npz or HDF5.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from moju_core import __version__
from moju_core.file_types import HDF5_MAGIC
from moju_core.io._sources import PathLike
from moju_core.io.atomic import atomic_output
from moju_core.params import SolverParams
from moju_core.result import Diagnostics, Result

_RESULT_EXTENSIONS = {".npz": "npz", ".h5": "h5", ".hdf5": "h5"}
_HISTORY_PREFIX = "history_"
_RESULT_ARRAYS = ("shapes", "rotations", "labels")
#: Optional in a result file: files written before it existed lack it.
_RESULT_VISIBILITY = "visibility"
_RESULT_JSON = ("params", "timings", "metadata", "diagnostics")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _result_contents(
    result: Result, metadata: Mapping[str, Any] | None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """Arrays, history and scalar metadata of a result, checked before any file is touched."""
    shapes = np.ascontiguousarray(result.shapes, dtype=np.float64)
    rotations = np.ascontiguousarray(result.rotations, dtype=np.float64)
    labels = np.ascontiguousarray(result.labels, dtype=np.int64)
    if shapes.ndim != 3 or shapes.shape[2] != 3:
        raise ValueError(f"result.shapes has shape {shapes.shape}; expected (F, P, 3)")
    n_frames, n_points, _ = shapes.shape
    if rotations.shape != (n_frames, 2, 3) or labels.shape != (n_points,):
        raise ValueError(
            f"result.rotations {rotations.shape} and result.labels {labels.shape} do not match "
            f"result.shapes {shapes.shape}: expected ({n_frames}, 2, 3) and ({n_points},)"
        )
    visibility = result.visibility
    if visibility is None:  # a solve of complete data
        visibility = np.ones((n_frames, n_points), dtype=bool)
    visibility = np.ascontiguousarray(visibility, dtype=bool)
    if visibility.shape != (n_frames, n_points):
        raise ValueError(
            f"result.visibility {visibility.shape} does not match result.shapes "
            f"{shapes.shape}: expected ({n_frames}, {n_points})"
        )
    history = {}
    for key, values in result.history.items():
        if not key or "/" in key or "\0" in key:
            raise ValueError(f"history key {key!r} cannot be stored; use a plain name")
        history[key] = np.asarray(values)
    scalars = {
        "params": json.dumps(result.params.model_dump(mode="json")),
        "timings": json.dumps(dict(result.timings), default=_json_default),
        "metadata": json.dumps(
            dict(result.metadata if metadata is None else metadata), default=_json_default
        ),
        "diagnostics": json.dumps(
            None if result.diagnostics is None else result.diagnostics.to_dict(),
            default=_json_default,
        ),
        "n_iter": int(result.n_iter),
        "stop_reason": str(result.stop_reason),
        "scale": float(result.scale),
        "version": __version__,
    }
    arrays = {
        "shapes": shapes,
        "rotations": rotations,
        "labels": labels,
        _RESULT_VISIBILITY: visibility,
    }
    return arrays, history, scalars


def _result_format(path: Path) -> str:
    try:
        return _RESULT_EXTENSIONS[path.suffix.lower()]
    except KeyError:
        raise ValueError(
            f"cannot tell the result format of {path.name}: use the extension .npz, .h5 or .hdf5"
        ) from None


def write_result(
    path: PathLike, result: Result, *, metadata: Mapping[str, Any] | None = None
) -> Path:
    """Write a reconstruction to an npz or HDF5 file, atomically.

    The data goes to a temporary file in the same directory, which is renamed to ``path`` only
    once complete; on failure it is removed. Large arrays are stored uncompressed: float64
    shapes barely compress and gzip would add seconds for a 70 MB result.

    Parameters
    ----------
    path : str or os.PathLike
        Target file; ``.npz`` or ``.h5`` / ``.hdf5``.
    result : Result
        The reconstruction.
    metadata : mapping, optional
        Extra JSON-serialisable information stored with the result (job id, input name, ...);
        ``result.metadata`` when omitted (empty for a fresh solve, what the file held for a
        result read back with :func:`read_result`).

    Returns
    -------
    Path
        The path written.

    Notes
    -----
    npz layout: arrays ``shapes``, ``rotations``, ``labels``, ``visibility`` (F x P bool,
    all True when ``result.visibility`` is None), ``history_<key>``, 0-d
    ``n_iter`` (int64) and ``scale`` (float64), 0-d unicode ``stop_reason``, ``version`` (of
    the writer, :data:`moju_core.__version__`) and the JSON documents ``params``, ``timings``,
    ``metadata`` and ``diagnostics`` (:meth:`moju_core.result.Diagnostics.to_dict`, ``null``
    when ``result.diagnostics`` is None). HDF5 layout: the same arrays as datasets, the history
    as datasets of group ``history``, the rest as root attributes.
    """
    path = Path(path)
    file_format = _result_format(path)
    arrays, history, scalars = _result_contents(result, metadata)
    with atomic_output(path) as temporary:
        if file_format == "npz":
            members = dict(arrays)
            members.update({_HISTORY_PREFIX + key: value for key, value in history.items()})
            members.update({key: np.asarray(value) for key, value in scalars.items()})
            with open(temporary, "wb") as handle:
                np.savez(handle, **members)
        else:
            with h5py.File(temporary, "w") as h5:
                for name, value in arrays.items():
                    h5.create_dataset(name, data=value)
                group = h5.create_group("history", track_order=True)
                for key, value in history.items():
                    group.create_dataset(key, data=value)
                h5.attrs.update(scalars)
    return path


def _text(value: Any) -> str:
    if isinstance(value, np.ndarray):
        value = value.item()
    return value.decode() if isinstance(value, bytes) else str(value)


def _result_visibility(arrays: Mapping[str, np.ndarray]) -> np.ndarray | None:
    if _RESULT_VISIBILITY not in arrays:
        return None
    visibility = np.asarray(arrays[_RESULT_VISIBILITY], dtype=bool)
    if visibility.shape != arrays["shapes"].shape[:2]:
        raise ValueError(
            f"visibility has shape {visibility.shape}, shapes {arrays['shapes'].shape}"
        )
    return visibility


def read_result(path: PathLike) -> Result:
    """Read a result file written by :func:`write_result` (npz or HDF5, by content).

    Files written by earlier versions read too:

    * ``params`` keys that :class:`~moju_core.params.SolverParams` no longer has are dropped,
      and parameters added since take their defaults; a stored value the current schema
      refuses makes the file unreadable (ValueError);
    * without a ``visibility`` dataset, :attr:`Result.visibility` is None (the viewer and the
      metrics then treat every point as observed);
    * without a ``diagnostics`` document, or with one this version cannot interpret (a field
      missing, a value of the wrong form), :attr:`Result.diagnostics` is None; keys it does
      not know are ignored;
    * a missing ``timings`` or ``metadata`` document reads as an empty dict.

    Parameters
    ----------
    path : str or os.PathLike
        The result file.

    Returns
    -------
    Result
        With ``version`` the moju version that wrote the file and ``metadata`` what its writer
        passed as ``metadata``.

    Raises
    ------
    ValueError
        When the file cannot be read or lacks a part of the result layout.
    """
    path = Path(path)
    with open(path, "rb") as handle:
        is_hdf5 = handle.read(8) == HDF5_MAGIC
    try:
        arrays, history, scalars = _read_hdf5(path) if is_hdf5 else _read_npz(path)
        documents = {key: json.loads(_text(scalars[key])) for key in _RESULT_JSON if key in scalars}
        return Result(
            shapes=np.asarray(arrays["shapes"], dtype=np.float64),
            rotations=np.asarray(arrays["rotations"], dtype=np.float64),
            labels=np.asarray(arrays["labels"], dtype=np.int64),
            history=history,
            timings=documents.get("timings") or {},
            params=_stored_params(documents["params"]),
            n_iter=int(scalars["n_iter"]),
            stop_reason=_text(scalars["stop_reason"]),
            scale=float(scalars["scale"]),
            diagnostics=_stored_diagnostics(documents.get("diagnostics")),
            visibility=_result_visibility(arrays),
            version=_text(scalars["version"]),
            metadata=documents.get("metadata") or {},
        )
    except Exception as exc:  # h5py, zipfile, json and pydantic each raise their own types
        raise ValueError(
            f"{path.name} is not a readable MoJu result file ({type(exc).__name__}: {exc})"
        ) from exc


_Parts = tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]


def _read_hdf5(path: Path) -> _Parts:
    """Arrays, history and root attributes of an HDF5 result file."""
    with h5py.File(path, "r") as h5:
        arrays = {name: h5[name][()] for name in _RESULT_ARRAYS}
        if _RESULT_VISIBILITY in h5:
            arrays[_RESULT_VISIBILITY] = h5[_RESULT_VISIBILITY][()]
        group = h5.get("history")
        history = {key: group[key][()] for key in group} if group is not None else {}
        return arrays, history, dict(h5.attrs)


def _read_npz(path: Path) -> _Parts:
    """Arrays, history and 0-d members of an npz result file."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in _RESULT_ARRAYS}
        if _RESULT_VISIBILITY in npz.files:
            arrays[_RESULT_VISIBILITY] = npz[_RESULT_VISIBILITY]
        history = {
            key[len(_HISTORY_PREFIX) :]: npz[key]
            for key in npz.files
            if key.startswith(_HISTORY_PREFIX)
        }
        scalars = {
            key: npz[key]
            for key in npz.files
            if key not in arrays and not key.startswith(_HISTORY_PREFIX)
        }
    return arrays, history, scalars


def _stored_params(values: Mapping[str, Any]) -> SolverParams:
    """The stored parameters, without the keys this version's schema no longer has."""
    known = SolverParams.model_fields
    return SolverParams.model_validate({k: v for k, v in values.items() if k in known})


def _stored_diagnostics(values: Mapping[str, Any] | None) -> Diagnostics | None:
    """The stored diagnostics, or None when there are none this version can interpret."""
    if not isinstance(values, Mapping):
        return None
    try:
        return Diagnostics.from_dict(values)
    except (TypeError, ValueError):
        return None
