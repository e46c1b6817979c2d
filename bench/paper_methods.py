#!/usr/bin/env python3
"""The paper's set-up on `bbbv` (Newton-min, ILU(0)-preconditioned GMRES, initial guess
(g, 0, 0), criteria every ν = 10 iterations) at its three mesh sizes: Newton steps and
cumulated GMRES iterations of the exact, inexact and adaptive methods next to the paper's
(its Fig. 6, as in postproc/twomem_post/paper.py), the estimate and its effectivity, and the time per GMRES
iteration (estimator time excluded). --gamma-table adds the paper's γ sensitivity table on
the largest mesh.

    .venv/bin/python bench/paper_methods.py [--exe build/release/twomem] [--restart 30] [--gamma-table]

exact:    GMRES to ‖R_alg‖/‖B‖ ≤ 2e-12 in every step   (gmres.forcing=fixed, gmres.rtol=2e-12)
inexact:  GMRES until ‖R_alg‖/‖B‖ ≤ ‖R_lin‖/‖[F;0]‖     (gmres.forcing=paper)
adaptive: Algorithm 1, GMRES until η_alg ≤ γ_alg max(η_disc, η_lin), Newton until
          η_lin ≤ γ_lin η_disc (newton.linear=adaptive, γ = 0.3; estimators at every check,
          estimate.checks=all, as in the paper)
The first two stop Newton at ‖R_lin‖/‖[F;0]‖ ≤ 1e-10 and evaluate the estimators once, at the
end. Add --nested to start from nested iteration.
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
SIZES = [(0.25, 2048, {"exact": (8, 330), "inexact": (16, 160), "adaptive": (7, 80)}),
         (0.122, 7840, {"exact": (15, 930), "inexact": (46, 460), "adaptive": (14, 180)}),
         (0.0582, 34592, {"exact": (28, 2985), "inexact": (166, 1660), "adaptive": (27, 670)})]
METHODS = {"exact": ["newton.linear=gmres", "gmres.forcing=fixed", "gmres.rtol=2e-12", "output.history=.false."],
           "inexact": ["newton.linear=gmres", "gmres.forcing=paper", "output.history=.false."],
           "adaptive": ["newton.linear=adaptive", "estimate.checks=all"]}
# the paper's γ table at about 35000 triangles: (γ_alg, γ_lin) → Newton, mean GMRES per step, total
GAMMAS = {(0.3, 0.3): (26, 26, 670), (0.03, 0.3): (26, 43, 1130), (0.3, 0.03): (27, 25, 680),
          (0.03, 0.03): (27, 42, 1140)}


def run(exe: str, h: float, method: str, extra: list[str], out: Path) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "paper_p1.nml"), f"mesh.coarse_h={h}", f"mesh.boundary_h={h}",
           "gmres.precond=ilu0", "estimate.every=10", "newton.max_it=1000",
           *METHODS[method], *extra,
           "output.fields=.false.", "output.xdmf=.false.", f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    with h5py.File(out) as f:
        s = dict(f["summary"].attrs)
        s["status"] = f.attrs["status"]
    return s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--restart", type=int, default=30)
    ap.add_argument("--nested", action="store_true", help="nested iteration instead of (g, 0, 0)")
    ap.add_argument("--gamma-table", action="store_true", help="the γ sensitivity table on the largest mesh")
    args = ap.parse_args()
    extra = [f"gmres.restart={args.restart}", f"newton.initial={'nested' if args.nested else 'paper'}"]
    print(f"| triangles | method | Newton (paper) | GMRES (paper) | eta | effectivity | s per GMRES it | "
          f"estimator evals | s per eval | status |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for h, _, paper in SIZES:
            for method in METHODS:
                s = run(args.exe, h, method, extra, Path(tmp) / f"{method}_{h}.h5")
                solve_time = s["wall_time"] - s["estimator_time"]
                per_it = solve_time / max(1, s["gmres_iterations"])
                per_eval = s["estimator_time"] / max(1, s["estimator_evaluations"])
                print(f"| {s['nt']} | {method} | {s['newton_iterations']} ({paper[method][0]}) | "
                      f"{s['gmres_iterations']} ({paper[method][1]}) | {s['eta_total']:.4g} | "
                      f"{s['effectivity']:.3f} | {per_it:.2e} | {s['estimator_evaluations']} | {per_eval:.3f} | "
                      f"{s['status'][:24]} |", flush=True)
        if args.gamma_table:
            h = SIZES[-1][0]
            print(f"\n| γ_alg, γ_lin | Newton (paper) | mean GMRES per step (paper) | total GMRES (paper) | effectivity |")
            print("| --- | --- | --- | --- | --- |")
            for (g_alg, g_lin), (p_newton, p_mean, p_total) in GAMMAS.items():
                s = run(args.exe, h, "adaptive", extra + [f"estimate.gamma_alg={g_alg}", f"newton.gamma_lin={g_lin}"],
                        Path(tmp) / f"gamma_{g_alg}_{g_lin}.h5")
                mean = s["gmres_iterations"] / max(1, s["newton_iterations"])
                print(f"| {g_alg}, {g_lin} | {s['newton_iterations']} ({p_newton}) | {mean:.0f} ({p_mean}) | "
                      f"{s['gmres_iterations']} ({p_total}) | {s['effectivity']:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
