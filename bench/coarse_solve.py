#!/usr/bin/python3
"""Time of one sparse direct triangular solve on twomem's coarse disk meshes, for the coarsest
level term of bench/mpi_scaling.py's model.

    /usr/bin/python3 bench/coarse_solve.py TWOMEM_EXE N1,N2,...   # prints JSON {vertices: seconds}

For each target size, twomem builds the unit-disk mesh (mesh.levels = 0, coarse_h chosen for
about N vertices) and writes it; this script assembles the P1 Laplacian of its interior
vertices (what one SPD block of the multigrid's coarsest level is), factors it with SciPy's
SuperLU (minimum-degree ordering of AᵀA + A) and reports the median time of one forward and
back substitution. twomem itself uses UMFPACK there; both are supernodal/multifrontal LU codes
whose triangular solves cost about 2 nnz(L + U) flops, so the order of magnitude carries over.
Needs numpy, scipy and h5py (bench/setup_petsc.sh installs Debian's).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# bound by import_numerics() once the arguments are parsed, so that `--help` needs none of them
h5py = np = sp = spla = None


def import_numerics() -> None:
    global h5py, np, sp, spla
    try:
        import h5py
        import numpy as np
        import scipy.sparse as sp
        import scipy.sparse.linalg as spla
    except ImportError as exc:
        sys.exit(f"coarse_solve: {exc.name} is not importable under {sys.executable}: run bench/setup_petsc.sh")


def disk_mesh(exe: str, n_target: int, tmp: Path) -> tuple[np.ndarray, np.ndarray]:
    h = math.sqrt(3.6 / n_target)  # a uniform disk mesh has about π/(√3/2 h²) vertices
    out = tmp / "mesh.h5"
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), f"mesh.coarse_h={h:.6g}", f"mesh.boundary_h={h:.6g}",
           "mesh.levels=0", "newton.max_it=1", "newton.initial=paper", "estimate.enabled=.false.", "output.xdmf=.false.",
           f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
    if proc.returncode not in (0, 1):
        sys.exit(f"coarse_solve: {' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()}")
    with h5py.File(out) as f:
        return f["mesh/vertices"][()], f["mesh/triangles"][()]  # 0-based (docs/output.md)


def laplacian(x: np.ndarray, t: np.ndarray) -> sp.csc_matrix:
    n = len(x)
    p = x[t]                                            # (nt, 3, 2)
    d = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
    area = 0.5 * np.abs(d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])
    k = np.einsum("tik,tjk->tij", d, d) / (4 * area[:, None, None])
    rows = np.repeat(t, 3, axis=1).ravel()
    cols = np.tile(t, (1, 3)).ravel()
    a = sp.csr_matrix((k.ravel(), (rows, cols)), shape=(n, n))
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = np.unique(uniq[counts == 1])
    interior = np.setdiff1d(np.arange(n), boundary)
    return a[interior][:, interior].tocsc()


def solve_seconds(a: sp.csc_matrix, repeat: int = 50) -> float:
    lu = spla.splu(a, permc_spec="MMD_AT_PLUS_A")
    b = np.ones(a.shape[0])
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        lu.solve(b)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] + " " + __doc__.splitlines()[1])
    ap.add_argument("twomem", help="twomem executable")
    ap.add_argument("sizes", help="target vertex counts, comma-separated (e.g. 1000,4000,16000)")
    args = ap.parse_args()
    sizes = [int(v) for v in args.sizes.split(",")]
    import_numerics()
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            x, t = disk_mesh(args.twomem, n, Path(tmp))
            result[len(x)] = solve_seconds(laplacian(x, t))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
