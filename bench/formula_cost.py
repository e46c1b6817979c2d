#!/usr/bin/env python3
"""What loads given as formulas cost against the assembly they feed: the paper's bbbv loads
built in (compiled Fortran) and the same loads written as formulas of r, on the same meshes.

    .venv/bin/python bench/formula_cost.py [--exe build/release/twomem] [--levels 4,5]
                                           [--threads 1,2] [--repeat 3]

Each run is input/paper_p1.nml on the unit disk (coarse_h = boundary_h = 0.05, mesh.levels as
given: 9.3e4, 3.7e5 and 1.5e6 vertices for 3, 4 and 5) for one Newton step with multigrid GMRES and the estimators off;
only the set-up matters here. Formula loads are evaluated when the discrete problem is built,
at the load vector's quadrature points, so they show in the `assembly` phase of the run's
per-phase table (/performance assembly_seconds). The table gives the median assembly time of
both runs, the formulas' extra time (formula − built in) and its ratio to the built-in assembly:
the target is an extra time no larger than the assembly itself (ratio ≤ 1).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
R0 = "1/sqrt(2)"
C = "0.05*sqrt(2)/(sqrt(2) - 1)"
# the bbbv loads (docs/method.md §4), as tests/regression/test_user_loads.py writes them
BBBV_F1 = f"(r <= {R0})*(-10*0.05) + (r > {R0})*(-8*0.05)"
BBBV_F2 = f"(r <= {R0})*(-6*0.05) + (r > {R0})*(-{C}*(1 + 8*r - 18*r^2)/r)"


def assembly_seconds(exe: str, levels: int, threads: int, formula: bool, out: Path) -> tuple[int, float]:
    cmd = [exe, "run", str(ROOT / "input" / "paper_p1.nml"), "mesh.coarse_h=0.05", "mesh.boundary_h=0.05", f"mesh.levels={levels}",
           "newton.linear=gmres", "gmres.precond=mg", "newton.max_it=1", "estimate.enabled=.false.",
           "output.xdmf=.false.", "output.fields=.false.", f"output.file={out}"]
    if formula:
        cmd += ["problem.exact=none", "problem.mu1=1", "problem.mu2=1", "problem.g=0.05",
                f"problem.f1={BBBV_F1}", f"problem.f2={BBBV_F2}"]
    else:
        cmd += ["problem.exact=bbbv"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS=str(threads)))
    # exit 1: not converged within newton.max_it = 1, which is what we ask for
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    with h5py.File(out) as f:
        return int(f["summary"].attrs["nv"]), float(f["performance"].attrs["assembly_seconds"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", default="4,5")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    print("| vertices | threads | assembly, built-in loads (s) | assembly, formula loads (s) | formulas add (s) | ratio to assembly |")
    print("|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "formula_cost.h5"
        for levels in (int(x) for x in args.levels.split(",")):
            for threads in (int(x) for x in args.threads.split(",")):
                built, formula = [], []
                for _ in range(args.repeat):
                    nv, t = assembly_seconds(args.exe, levels, threads, False, out)
                    built.append(t)
                    nv, t = assembly_seconds(args.exe, levels, threads, True, out)
                    formula.append(t)
                b, f = statistics.median(built), statistics.median(formula)
                print(f"| {nv} | {threads} | {b:.3f} | {f:.3f} | {f - b:.3f} | {(f - b) / b:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
