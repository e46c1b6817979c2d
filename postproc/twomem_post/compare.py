"""Compare two twomem result files dataset by dataset under absolute + relative tolerances.

Timing and memory figures are not results and are skipped; NaN equals NaN (a quantity that
was not computed in either file). Used by the regression tests against stored references.
"""
from __future__ import annotations

import sys

import h5py
import numpy as np

#: values that measure the machine, not the computation (`/@umfpack` names the libraries the run
#: solved with: files written before it existed, or on another machine, still compare)
SKIPPED = {"/history/wall_time", "/summary@wall_time", "/summary@peak_memory_kib", "/summary@estimator_time",
           "/summary@omp_threads", "/summary@mpi_ranks", "/@umfpack"}
#: groups that measure the machine: every item below them is skipped
SKIPPED_GROUPS = ("/performance",)


def _collect(f: h5py.File) -> dict[str, np.ndarray]:
    items: dict[str, np.ndarray] = {}

    def visit(name, obj):
        path = "/" + name
        if isinstance(obj, h5py.Dataset):
            items[path] = obj[()]
        for key, value in obj.attrs.items():
            items[f"{path}@{key}"] = value

    for key, value in f.attrs.items():
        items[f"/@{key}"] = value
    f.visititems(visit)
    return items


def compare(a_path: str, b_path: str, rtol: float, atol: float, out=sys.stdout) -> int:
    """Return 0 when every shared numeric item agrees, 1 otherwise (differences printed)."""
    with h5py.File(a_path, "r") as fa, h5py.File(b_path, "r") as fb:
        a, b = _collect(fa), _collect(fb)
    failures = 0
    for key in sorted(set(a) | set(b)):
        if key in SKIPPED or key.startswith(SKIPPED_GROUPS):
            continue
        if key not in a or key not in b:
            print(f"{key}: only in {'the first' if key in a else 'the second'} file", file=out)
            failures += 1
            continue
        va, vb = a[key], b[key]
        if isinstance(va, (bytes, str)) or isinstance(vb, (bytes, str)):
            continue  # text (input echo, version, status) is provenance, not a number
        va, vb = np.asarray(va, dtype=float), np.asarray(vb, dtype=float)
        if va.shape != vb.shape:
            print(f"{key}: shapes differ {va.shape} vs {vb.shape}", file=out)
            failures += 1
            continue
        both_nan = np.isnan(va) & np.isnan(vb)
        with np.errstate(invalid="ignore"):
            diff = np.abs(va - vb)
            bound = atol + rtol * np.abs(vb)
            bad = ~((diff <= bound) | both_nan)
        if bad.any():
            i = np.unravel_index(np.argmax(bad), va.shape)
            print(f"{key}: {int(bad.sum())} of {va.size} values differ; worst at {tuple(map(int, i))}: "
                  f"{va[i]!r} vs {vb[i]!r}", file=out)
            failures += 1
    print(f"compare: {'identical within tolerance' if failures == 0 else f'{failures} items differ'} "
          f"(rtol={rtol:g}, atol={atol:g})", file=out)
    return 0 if failures == 0 else 1


def add_parser(sub) -> None:
    p = sub.add_parser("compare", help="differences between two result files")
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--rtol", type=float, default=1e-8)
    p.add_argument("--atol", type=float, default=1e-12)
    p.set_defaults(func=lambda args: compare(args.a, args.b, args.rtol, args.atol))
