#!/usr/bin/env python3
"""Work against precision for the paper's three methods (exact, inexact, adaptive) with its
ILU(0) preconditioner and with twomem's multigrid: how much time and how many GMRES iterations
each needs for the error it reaches, on the paper's case over a mesh sequence.

    .venv/bin/python bench/work_precision.py [--levels 1,2,3,4] [-o results/work_precision]

The case is `bbbv` (closed-form solution, so the energy error is the precision) on the disk
of input/paper_p1.nml refined 2..4 times (2k to 33k triangles; --levels 5 adds 130k),
nested iteration, 1 thread, one run at a time (`python -m twomem_post study ... --jobs 1`).
Estimators are computed only where the method needs them (the adaptive ones): the work of the
exact and inexact methods is their solve alone. The study driver writes the runs,
DIR/summary.csv and its figures, among them DIR/work_precision.png (wall time against the
energy error). This script then prints the table: per method and mesh, the final energy error
and estimate, Newton steps and GMRES iterations (finest level, and all levels), the solve and
estimator seconds of the run's own phase clock, and their sum. ILU(0) on fine meshes is slow
(its iterations grow like 1/h).
"""
from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
METHODS = "exact,inexact,adaptive,exact_mg,inexact_mg,adaptive_mg"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", default="2,3,4")
    ap.add_argument("--methods", default=METHODS)
    ap.add_argument("--twomem", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("-o", "--out", default=str(ROOT / "results" / "work_precision"))
    args = ap.parse_args()
    out = Path(args.out)
    cmd = [sys.executable, "-m", "twomem_post", "study", str(ROOT / "input" / "paper_p1.nml"),
           "--levels", args.levels, "--methods", args.methods, "--jobs", "1", "--twomem", args.twomem,
           "--set", "newton.initial=nested", "--set", "mesh.boundary_h=0.25", "--set", "estimate.enabled=.false.",
           "-o", str(out)]
    status = subprocess.run(cmd, stdout=subprocess.DEVNULL).returncode
    if status > 1:
        sys.exit(f"work_precision: the study failed ({' '.join(cmd)})")
    rows = list(csv.DictReader(open(out / "summary.csv")))
    print("| method | triangles | energy error | η | Newton | GMRES (finest) | GMRES (all levels) "
          "| solve s | estimators s | sum s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in rows:
        with h5py.File(out / "runs" / f"{row['tag']}.h5") as f:
            perf = dict(f["performance"].attrs)
            s = dict(f["summary"].attrs)
        solve, est = perf["solve_seconds"], perf["estimators_seconds"]
        # the exact and inexact methods compute no estimator
        eta = "–" if math.isnan(s["eta_total"]) else f"{s['eta_total']:.4e}"
        print(f"| {row['method']} | {s['nt']} | {s['energy_error']:.4e} | {eta} | "
              f"{s['newton_iterations']} | {s['gmres_iterations']} | "
              f"{s['gmres_iterations'] + s['gmres_iterations_coarse']} | {solve:.3f} | {est:.3f} | "
              f"{solve + est:.3f} |")
    print(f"figures: {out}/work_precision.png, {out}/iterations.png", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
