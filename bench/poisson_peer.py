#!/usr/bin/python3
"""twomem's multigrid against hypre's BoomerAMG on the Poisson block, the same matrix.

What it measures. Without contact (f1 = 1, f2 = −1, μ1 = μ2 = 1, g = 0.05: the membranes move
apart), a Newton step of twomem is one linear solve whose exact elimination leaves two SPD
blocks, both the P1 stiffness matrix K of the interior vertices; its GMRES applies one
multigrid V-cycle to each block per iteration (geometric levels on a refined hierarchy,
algebraic ones by smoothed aggregation below a fine mesh used as it is). The script runs
twomem cold (`newton.initial = 'paper'`) with GMRES to `--rtol` and reads its iterations and
`/performance@solve_seconds` (the whole solve: multigrid set-up, Galerkin products,
iterations, residuals). It then reads the finest mesh from twomem's result, assembles K
itself (numpy) and solves K x = b for the same two right-hand sides with PETSc's CG and
BoomerAMG (one process: Debian's hypre has no OpenMP) to the same relative residual: set-up
once, two solves. Both reach the tolerance; the table compares iterations and seconds.

    bench/setup_petsc.sh                                    # once: Debian's petsc4py, h5py
    /usr/bin/python3 bench/poisson_peer.py --levels 3,5     # twomem's disk refined 3 and 5 times
    /usr/bin/python3 bench/poisson_peer.py --mesh a.msh     # a Gmsh mesh solved as it is

BoomerAMG runs in the configuration that was fastest here on these matrices (listed in the
table's notes; `--hypre "-pc_hypre_boomeramg_strong_threshold 0.5"` overrides options).
Medians of `--repeat` runs, interleaved.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PETSC_DIR = "/usr/lib/petscdir/petsc3.18/x86_64-linux-gnu-real"
CASE = ["problem.exact=none", "problem.f1=1", "problem.f2=-1", "problem.mu1=1", "problem.mu2=1", "problem.g=0.05",
        "newton.linear=gmres", "gmres.precond=mg", "gmres.forcing=fixed", "estimate.enabled=.false.",
        "newton.initial=paper", "output.xdmf=.false.", "output.history=.false."]
# the options that were fastest here (2-D P1 Laplacians): HMIS coarsening with ext+i
# interpolation and aggressive coarsening on the first level take about half of the default's
# set-up time at the same iteration counts
BOOMERAMG = ["-pc_hypre_boomeramg_coarsen_type", "HMIS", "-pc_hypre_boomeramg_interp_type", "ext+i",
             "-pc_hypre_boomeramg_strong_threshold", "0.25", "-pc_hypre_boomeramg_agg_nl", "1",
             "-pc_hypre_boomeramg_P_max", "4"]
np = h5py = sp = None


def import_modules(extra: list[str]):
    """numpy, scipy.sparse, h5py as globals and PETSc initialised with `extra` options."""
    global np, h5py, sp
    os.environ.setdefault("PETSC_DIR", PETSC_DIR)
    site = Path(os.environ["PETSC_DIR"]) / "lib" / "python3" / "dist-packages"
    if site.is_dir() and str(site) not in sys.path:
        sys.path.append(str(site))
    try:
        import h5py
        import numpy as np
        import scipy.sparse as sp
        import petsc4py
        petsc4py.init([sys.argv[0], *extra])
        from petsc4py import PETSc
    except ImportError as exc:
        sys.exit(f"poisson_peer: {exc.name} is not importable under {sys.executable}: run bench/setup_petsc.sh")
    return PETSc


def run_twomem(exe: str, mesh_args: list[str], threads: int, rtol: float, out: Path) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), *CASE, f"gmres.rtol={rtol:g}", *mesh_args,
           f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS=str(threads)))
    if proc.returncode != 0:
        sys.exit(f"poisson_peer: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stdout[-1500:]}{proc.stderr[-1500:]}")
    with h5py.File(out) as f:
        s, perf = dict(f["summary"].attrs), dict(f["performance"].attrs)
        if int(s["newton_iterations"]) != 1:
            sys.exit(f"poisson_peer: expected one Newton step without contact, got {s['newton_iterations']}")
        return {"nv": int(s["nv"]), "gmres": int(s["gmres_iterations"]), "solve": float(perf["solve_seconds"]),
                "vertices": f["mesh/vertices"][()], "triangles": f["mesh/triangles"][()]}


def stiffness(vertices, triangles):
    """P1 stiffness matrix of the interior vertices (boundary: vertices on an edge of one triangle)."""
    p = vertices[triangles]                                       # (nt, 3, 2)
    e = np.roll(p, -1, axis=1) - np.roll(p, 1, axis=1)            # edge opposite each vertex
    area = 0.5 * np.abs(e[:, 1, 0] * e[:, 2, 1] - e[:, 1, 1] * e[:, 2, 0])
    local = np.einsum("tik,tjk->tij", e, e) / (4 * area)[:, None, None]
    rows = np.repeat(triangles, 3, axis=1).ravel()
    cols = np.tile(triangles, (1, 3)).ravel()
    n = len(vertices)
    k = sp.csr_matrix((local.ravel(), (rows, cols)), shape=(n, n))
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = np.zeros(n, bool)
    boundary[uniq[count == 1].ravel()] = True
    interior = np.flatnonzero(~boundary)
    return k[interior][:, interior].tocsr(), area, interior


def boomeramg(PETSc, k, rhs: list, rtol: float) -> dict:
    a = PETSc.Mat().createAIJ(size=k.shape, csr=(k.indptr.astype(PETSc.IntType), k.indices.astype(PETSc.IntType),
                                                 k.data))
    a.setOption(PETSc.Mat.Option.SPD, True)
    ksp = PETSc.KSP().create()
    ksp.setOperators(a)
    ksp.setType("cg")
    ksp.getPC().setType("hypre")
    ksp.getPC().setHYPREType("boomeramg")
    ksp.setTolerances(rtol=rtol, atol=0.0, max_it=1000)
    ksp.setFromOptions()
    x = a.createVecLeft()
    t0 = time.perf_counter()
    ksp.setUp()
    setup = time.perf_counter() - t0
    its = []
    t0 = time.perf_counter()
    for r in rhs:
        b = a.createVecLeft()
        b.setArray(r)
        x.set(0.0)
        ksp.solve(b, x)
        if ksp.getConvergedReason() <= 0:
            sys.exit(f"poisson_peer: CG + BoomerAMG did not converge ({ksp.getConvergedReason()})")
        its.append(ksp.getIterationNumber())
    solve = time.perf_counter() - t0
    ksp.destroy()
    a.destroy()
    return {"setup": setup, "solve": solve, "its": its}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", default="3,5", help="refinements of twomem's disk (coarse_h 0.1), comma list")
    ap.add_argument("--mesh", action="append", default=[], help="a Gmsh mesh solved as it is (repeatable)")
    ap.add_argument("--threads", default="1,2", help="twomem's OpenMP threads, comma list")
    ap.add_argument("--rtol", type=float, default=1e-10)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--hypre", default="", help="extra PETSc options, after the defaults")
    args = ap.parse_args()
    PETSc = import_modules([*BOOMERAMG, *args.hypre.split()])
    cases = [(f"disk, {lv} refinements", ["mesh.domain=disk", "mesh.coarse_h=0.1", "mesh.boundary_h=0.02",
                                          f"mesh.levels={lv}"]) for lv in (int(x) for x in args.levels.split(",") if x)]
    cases += [(f"{Path(m).name} as it is", ["mesh.domain=gmsh", f"mesh.file={Path(m).resolve()}", "mesh.levels=0"])
              for m in args.mesh]
    threads = [int(t) for t in args.threads.split(",")]
    print("| mesh | vertices | solver | iterations | set-up s | solve s | total s | BoomerAMG / twomem |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmpdir:
        for label, mesh_args in cases:
            runs = {t: [] for t in threads}
            peer = []
            for _ in range(args.repeat):
                for t in threads:
                    runs[t].append(run_twomem(args.exe, mesh_args, t, args.rtol, Path(tmpdir) / "p.h5"))
                last = runs[threads[0]][-1]
                k, area, interior = stiffness(last["vertices"], last["triangles"])
                # the two blocks' right-hand sides: the lumped loads f1 = 1 and f2 = −1
                lumped = np.zeros(len(last["vertices"]))
                np.add.at(lumped, last["triangles"].ravel(), np.repeat(area / 3, 3))
                rhs = [lumped[interior], -lumped[interior]]
                peer.append(boomeramg(PETSc, k, rhs, args.rtol))
            nv = runs[threads[0]][0]["nv"]
            cg = peer[0]["its"]
            p_setup = statistics.median(r["setup"] for r in peer)
            p_solve = statistics.median(r["solve"] for r in peer)
            p_total = statistics.median(r["setup"] + r["solve"] for r in peer)
            for t in threads:
                tw = statistics.median(r["solve"] for r in runs[t])
                print(f"| {label} | {nv} | twomem MG-GMRES, both blocks at once, {t} thread{'s' * (t > 1)} | "
                      f"{runs[t][0]['gmres']} | | | {tw:.3f} | {p_total / tw:.1f} |", flush=True)
            print(f"| {label} | {nv} | PETSc CG + BoomerAMG, each block, 1 process | {cg[0]}, {cg[1]} | "
                  f"{p_setup:.3f} | {p_solve:.3f} | {p_total:.3f} | 1 |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
