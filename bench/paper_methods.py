#!/usr/bin/env python3
"""The paper's set-up on `bbbv` (Newton-min, ILU(0)-preconditioned GMRES, initial guess
(g, 0, 0), criteria every ν = 10 iterations) at its three mesh sizes: Newton steps and
cumulated GMRES iterations of the exact and inexact methods next to the paper's
(literature/paper_figure_data.md), and the time per GMRES iteration.

    .venv/bin/python bench/paper_methods.py [--exe build/release/twomem] [--restart 30]

exact:   GMRES to ‖R_alg‖/‖B‖ ≤ 2e-12 in every step   (gmres.forcing=fixed, gmres.rtol=2e-12)
inexact: GMRES until ‖R_alg‖/‖B‖ ≤ ‖R_lin‖/‖[F;0]‖     (gmres.forcing=paper)
Both stop Newton at ‖R_lin‖/‖[F;0]‖ ≤ 1e-10. Add --nested to start from nested iteration.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
# our coarse_h for the paper's sizes, and the paper's (triangles, Newton, GMRES) per method
SIZES = [(0.25, 2048, {"exact": (8, 330), "inexact": (16, 160)}),
         (0.122, 7840, {"exact": (15, 930), "inexact": (46, 460)}),
         (0.0582, 34592, {"exact": (28, 2985), "inexact": (166, 1660)})]
METHODS = {"exact": ["gmres.forcing=fixed", "gmres.rtol=2e-12"],
           "inexact": ["gmres.forcing=paper"]}


def run(exe: str, h: float, method: str, extra: list[str], out: Path) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "paper_p1.nml"), f"mesh.coarse_h={h}", f"mesh.boundary_h={h}",
           "newton.linear=gmres", "gmres.precond=ilu0", "estimate.every=10", "newton.max_it=1000",
           *METHODS[method], *extra,
           "output.fields=.false.", "output.xdmf=.false.", f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    with h5py.File(out) as f:
        s = dict(f["summary"].attrs)
        s["status"] = f.attrs["status"]
        s["solve_time"] = float(f["history/wall_time"][-1])
    return s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--restart", type=int, default=30)
    ap.add_argument("--nested", action="store_true", help="nested iteration instead of (g, 0, 0)")
    args = ap.parse_args()
    extra = [f"gmres.restart={args.restart}", f"newton.initial={'nested' if args.nested else 'paper'}"]
    print(f"{'triangles':>9} {'method':>8} {'Newton':>7} {'paper':>6} {'GMRES':>7} {'paper':>6} "
          f"{'unknowns':>9} {'s/GMRES it':>11} {'status':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for h, nt_paper, paper in SIZES:
            for method in METHODS:
                s = run(args.exe, h, method, extra, Path(tmp) / f"{method}_{h}.h5")
                n_unknowns = 3 * (s["nv"] - 0)  # all vertices; interior ones are slightly fewer
                per_it = s["solve_time"] / max(1, s["gmres_iterations"])
                print(f"{s['nt']:>9} {method:>8} {s['newton_iterations']:>7} {paper[method][0]:>6} "
                      f"{s['gmres_iterations']:>7} {paper[method][1]:>6} {n_unknowns:>9} "
                      f"{per_it:>11.2e} {s['status'][:10]:>10}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
