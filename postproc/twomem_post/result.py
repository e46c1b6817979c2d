"""Reading one twomem result file (layout in docs/output.md) into plain numpy arrays.

Every command reads through :func:`load`, so a file that is missing, not HDF5, truncated or
inconsistent (a field whose length is not the mesh's) fails in one place, as a
:class:`~twomem_post.errors.ResultError` that the command line turns into one line and exit
status 2. Datasets a file lacks are None (or absent from the dicts): what to do without them is
the caller's choice.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .errors import ResultError


@dataclass
class Result:
    """What the figures and studies need from a result file; None where the file lacks it."""
    path: str
    case: str
    status: str
    input_text: str = ""
    xy: np.ndarray | None = None
    triangles: np.ndarray | None = None
    u1: np.ndarray | None = None
    u2: np.ndarray | None = None
    lam: np.ndarray | None = None
    error: np.ndarray | None = None
    eta: np.ndarray | None = None
    history: dict[str, np.ndarray] = field(default_factory=dict)
    #: an adaptive run's steps: `/adapt`'s one-entry-per-step datasets by name (empty otherwise)
    adapt: dict[str, np.ndarray] = field(default_factory=dict)
    summary: dict[str, float] = field(default_factory=dict)


def text(value) -> str:
    """An HDF5 string attribute (bytes, str or a one-element array) as str."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return text(value.reshape(())[()])
    return str(value)


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (h5py's span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def case_name(input_text: str | None, fallback: str) -> str:
    """The case from the input echo's first line ``! twomem input: case 'NAME' ...``."""
    if input_text:
        m = re.search(r"!\s*twomem input:\s*case\s+'([^']*)'", input_text)
        if m and m.group(1):
            return m.group(1)
    return fallback


def load(path) -> Result:
    """Read what the figures and studies need; raise ResultError when the file is unusable."""
    path = str(path)
    if not os.path.exists(path):
        raise ResultError(path, "no such file")
    if os.path.isdir(path):
        raise ResultError(path, "is a directory")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ResultError(path, f"not a readable HDF5 file ({one_line(exc)})") from None
    try:
        with f:
            return _read(f, path)
    except ResultError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError) as exc:
        raise ResultError(path, one_line(exc)) from None


def _dataset(f: h5py.File, name: str, ndim: int, cols: int | None = None):
    if name not in f:
        return None
    obj = f[name]
    if not isinstance(obj, h5py.Dataset):
        raise ValueError(f"/{name} is not a dataset")
    a = obj[()]
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "fiub" or a.ndim != ndim \
            or (cols is not None and a.shape[1] != cols):
        shape = getattr(a, "shape", "?")
        want = f"(n, {cols})" if cols else "(n)"
        raise ValueError(f"/{name} has shape {shape} and type {getattr(a, 'dtype', type(a))}, "
                         f"expected numbers of shape {want}")
    return a


def _read(f: h5py.File, path: str) -> Result:
    groups = [g for g in ("mesh", "solution", "history", "error", "summary") if g in f]
    if not groups and "input" not in f.attrs and "version" not in f.attrs:
        raise ResultError(path, "not a twomem result (no /mesh, /solution, /history, /summary "
                                "or 'input' attribute)")
    input_text = text(f.attrs["input"]) if "input" in f.attrs else ""
    status = text(f.attrs["status"]) if "status" in f.attrs else "status unknown"
    r = Result(path=path, case=case_name(input_text, Path(path).stem), status=status,
               input_text=input_text)
    _read_mesh(f, r)
    _read_element_data(f, r)
    r.history = _read_history(f)
    r.adapt = _read_adapt(f)
    if "summary" in f:
        r.summary = {k: v.item() for k, v in f["summary"].attrs.items()
                     if np.ndim(v) == 0 and np.asarray(v).dtype.kind in "fiub"}
    return r


def _read_mesh(f: h5py.File, r: Result) -> None:
    r.xy = _dataset(f, "mesh/vertices", 2, 2)
    r.triangles = _dataset(f, "mesh/triangles", 2, 3)
    if (r.xy is None) != (r.triangles is None):
        raise ValueError("/mesh has vertices or triangles but not both")
    if r.xy is None:
        return
    nv = len(r.xy)
    if r.triangles.dtype.kind not in "iu":
        raise ValueError("/mesh/triangles is not an integer array")
    if len(r.triangles) and (r.triangles.min() < 0 or r.triangles.max() >= nv):
        raise ValueError(f"/mesh/triangles refers to vertices outside 0..{nv - 1}")
    r.xy = r.xy.astype(float)
    r.triangles = r.triangles.astype(np.int64)


def _read_element_data(f: h5py.File, r: Result) -> None:
    """Nodal fields and per-element errors, checked against the mesh sizes."""
    for attr, name, size in (("u1", "solution/u1", "nv"), ("u2", "solution/u2", "nv"),
                             ("lam", "solution/lambda", "nv"), ("error", "error/energy", "nt"),
                             ("eta", "estimators/eta_total", "nt")):
        a = _dataset(f, name, 1)
        if a is None:
            continue
        if r.xy is not None:
            n = len(r.xy) if size == "nv" else len(r.triangles)
            if len(a) != n:
                raise ValueError(f"/{name} has {len(a)} values, the mesh has {n} "
                                 f"{'vertices' if size == 'nv' else 'triangles'}")
        setattr(r, attr, a.astype(float))


def _read_adapt(f: h5py.File) -> dict[str, np.ndarray]:
    """`/adapt`'s per-step datasets (not its step_NNN groups), all of one length."""
    adapt: dict[str, np.ndarray] = {}
    if "adapt" not in f:
        return adapt
    for name, obj in f["adapt"].items():
        if isinstance(obj, h5py.Dataset):
            adapt[name] = _dataset(f, f"adapt/{name}", 1)
    lengths = {len(a) for a in adapt.values()}
    if len(lengths) > 1 or "vertices" not in adapt or "eta" not in adapt:
        raise ValueError("/adapt needs 'vertices' and 'eta' and one entry per step in every dataset")
    return adapt


def _read_history(f: h5py.File) -> dict[str, np.ndarray]:
    history: dict[str, np.ndarray] = {}
    if "history" not in f:
        return history
    rows = None
    for name, obj in f["history"].items():
        if not isinstance(obj, h5py.Dataset):
            continue
        a = _dataset(f, f"history/{name}", 1)
        if rows is not None and len(a) != rows:
            raise ValueError(f"/history/{name} has {len(a)} rows, other columns {rows}")
        rows = len(a)
        history[name] = a
    return history
