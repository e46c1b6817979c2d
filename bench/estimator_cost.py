#!/usr/bin/env python3
"""What one evaluation of the a posteriori estimators costs: against the number of vertices
(linear growth expected: O(1) work per patch), against one GMRES iteration on the same mesh,
and with 1 and 2 OpenMP threads.

    .venv/bin/python bench/estimator_cost.py [--exe build/release/twomem] [--levels 1,2,3,4] [--flux rt1]

Per mesh (input/default.nml, the radial case without its exact error, refined `levels` times):
- the estimators are evaluated at every Newton step of a direct solve (newton.linear=direct);
  s/eval = /summary estimator_time / estimator_evaluations, once with OMP_NUM_THREADS=1 and
  once with 2;
- one GMRES iteration: the finest level's solve time of newton.linear=gmres (ILU(0), paper
  forcing, estimate.enabled=.false.) over its GMRES iterations, ILU set-up and residuals
  included, with 2 threads.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]


def run(exe: str, overrides: list[str], out: Path, threads: int) -> tuple[dict, float]:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), *overrides, "output.fields=.false.",
           "output.xdmf=.false.", f"output.file={out}"]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    with h5py.File(out) as f:
        return dict(f["summary"].attrs), float(f["history/wall_time"][-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", default="1,2,3,4")
    ap.add_argument("--flux", default="rt1", choices=["rt1", "rt0"])
    args = ap.parse_args()
    print(f"estimator: {args.flux}, algebraic flux on the 3 finest meshes")
    print("| vertices | triangles | s/eval, 1 thread | s/eval, 2 threads | speed-up | µs/vertex (1 thread) "
          "| s/GMRES it | GMRES its per eval |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for level in (int(x) for x in args.levels.split(",")):
            common = [f"mesh.levels={level}", f"estimate.flux={args.flux}", "problem.exact=none"]
            per_eval = {}
            for threads in (1, 2):
                s, _ = run(args.exe, common + ["newton.linear=direct"], Path(tmp) / f"e{level}_{threads}.h5", threads)
                per_eval[threads] = s["estimator_time"] / s["estimator_evaluations"]
            g, solve = run(args.exe, common + ["newton.linear=gmres", "estimate.enabled=.false."],
                           Path(tmp) / f"g{level}.h5", 2)
            per_it = solve / max(1, g["gmres_iterations"])
            print(f"| {s['nv']} | {s['nt']} | {per_eval[1]:.4f} | {per_eval[2]:.4f} | "
                  f"{per_eval[1] / per_eval[2]:.2f} | {1e6 * per_eval[1] / s['nv']:.1f} | {per_it:.2e} | "
                  f"{per_eval[2] / per_it:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
