#!/usr/bin/env python3
"""Adaptive against uniform refinement on the "pacman" domain (the unit disk without its first
quadrant: a re-entrant 270° corner, where the solution is singular and uniform refinement loses
the optimal rate), the default adaptive method, f1 = −1, f2 = 0, g = 0.05, μ1 = μ2 = 1. Markdown
tables on stdout, JSON and a figure in the output directory.

    python bench/adaptivity.py [--exe build/release/twomem] [--h 0.2] [--levels 2,3,4,5,6]
                               [--theta 0.5] [--set KEY=VALUE ...] [--threads 2]
                               [--omp-wait passive] [--repeat 1] [--check 3] [-o results/adaptivity]

The initial mesh is Gmsh's of size --h (the gmsh Python wheel: `.venv/bin/pip install gmsh`).
Uniform refinement runs it with mesh.levels = each of --levels (red refinement, nested
iteration); the adaptive run starts from it (mesh.levels = 0) with adapt.tol = the η of the
finest uniform run, so both reach the same η. Both keep the coarse mesh's boundary polygon, so
they solve the same discrete domain. Tables:
1. uniform: vertices, η, wall time per level, and the slope of log η against log N;
2. adaptive: per step vertices, η, its parts, the step's and the cumulative wall time;
3. summary at the common η: vertices and wall time of both (the adaptive run's whole wall
   time, every step included, against the uniform run that reaches it), the slope of the
   adaptive steps' second half;
4. per step against a single solve: the last --check steps' meshes, written as Gmsh files and
   solved by a plain run on them (mesh.levels = 0, the same method, its own initial guess);
   the step's time (solve from the previous mesh's interpolated solution, estimators, marking,
   refinement) over the plain run's wall time;
5. where the error is known: the same adaptive loop on the unit disk with the `radial` closed
   form (fine boundary polygon), η, the energy error and the effectivity per step.
--set adds an override to every run (uniform, adaptive, plain and radial), e.g.
`--set estimate.bound=sharp --set newton.gamma_lin=0.1` for the sharper bound with Newton's
linearization estimate held to a tenth of the discretization one.

Wall times on a shared machine vary by tens of percent from run to run: compare ratios. Every
run gets OMP_WAIT_POLICY=--omp-wait (default passive: on a machine loaded by other work,
threads spinning at OpenMP barriers made a 6·10^4-vertex run 5 times slower; `default` leaves
the variable unset); with --repeat N each uniform and adaptive run is repeated and the one of
median wall time reported.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

# the pacman domain's Gmsh mesh, as the single-mesh benchmark makes it (the script's folder is on sys.path)
from single_mesh import pacman

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ("problem.exact=none", "problem.f1=-1", "problem.f2=0", "problem.g=0.05", "problem.mu1=1",
           "problem.mu2=1", "newton.linear=adaptive", "output.xdmf=.false.")


def write_msh(xy: np.ndarray, triangles: np.ndarray, path: Path) -> Path:
    """A mesh (zero-based triangles) as MSH 2.2 ASCII."""
    with open(path, "w") as f:
        f.write("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n" % len(xy))
        f.writelines("%d %.17g %.17g 0\n" % (i + 1, x, y) for i, (x, y) in enumerate(xy))
        f.write("$EndNodes\n$Elements\n%d\n" % len(triangles))
        f.writelines("%d 2 2 1 1 %d %d %d\n" % (i + 1, *(t + 1)) for i, t in enumerate(triangles))
        f.write("$EndElements\n")
    return path


def twomem(args, out: Path, *extra: str, ok=(0,)) -> None:
    cmd = [args.exe, "run", str(ROOT / "input" / "default.nml"), *extra, *args.set, f"output.file={out}"]
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads))
    env.pop("OMP_WAIT_POLICY", None)
    if args.omp_wait != "default":
        env["OMP_WAIT_POLICY"] = args.omp_wait
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode not in ok:
        sys.exit(f"adaptivity: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr.strip()}\n"
                 f"{proc.stdout[-2000:]}")


def timed(args, out: Path, *extra: str) -> Path:
    """Run --repeat times (out with a suffix per run); the path of the run of median wall time."""
    runs = []
    for k in range(args.repeat):
        path = out.with_name(f"{out.stem}_run{k}{out.suffix}")
        twomem(args, path, *extra)
        runs.append((summary(path)["wall_time"], path))
    return sorted(runs)[len(runs) // 2][1]


def summary(path: Path) -> dict:
    with h5py.File(path) as f:
        return {k: v.item() for k, v in f["summary"].attrs.items()}


def adapt_steps(path: Path) -> dict:
    with h5py.File(path) as f:
        return {k: f["adapt"][k][()] for k in f["adapt"] if isinstance(f["adapt"][k], h5py.Dataset)}


def slope(n, eta) -> float:
    """Least-squares slope of log η against log N over the second half of the points."""
    n, eta = np.asarray(n, float), np.asarray(eta, float)
    k = len(n) // 2
    return float(np.polyfit(np.log(n[k:]), np.log(eta[k:]), 1)[0])


def table(head: list[str], rows: list[list]) -> None:
    print("| " + " | ".join(head) + " |")
    print("|" + " --- |" * len(head))
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")
    print()


def figure(uniform: list[dict], adapt: dict, radial: dict | None, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4.5), dpi=120, layout="constrained")
    FigureCanvasAgg(fig)
    ax, bx = fig.subplots(1, 2)
    nu = np.array([u["nv"] for u in uniform], float)
    ax.loglog(nu, [u["eta"] for u in uniform], "s-", color="tab:gray",
              label=f"uniform, η (slope {slope(nu, [u['eta'] for u in uniform]):.2f})")
    na = adapt["vertices"].astype(float)
    ax.loglog(na, adapt["eta"], "D-", color="k", ms=3, label=f"adaptive, η (slope {slope(na, adapt['eta']):.2f})")
    ax.loglog(na, adapt["eta"][0] * (na / na[0]) ** -0.5, ":", color="0.5", label=r"$N^{-1/2}$")
    tu = np.array([u["wall"] for u in uniform])
    bx.loglog(tu, [u["eta"] for u in uniform], "s-", color="tab:gray", label="uniform (one run per level)")
    bx.loglog(np.cumsum(adapt["wall_time"]), adapt["eta"], "D-", color="k", ms=3,
              label="adaptive (cumulative over the steps)")
    if radial is not None:
        nr = radial["vertices"].astype(float)
        ax.loglog(nr, radial["energy_error"], "^--", color="tab:red", ms=3, label="radial disk: error")
        ax.loglog(nr, radial["eta"], "v-", color="tab:red", ms=3, alpha=0.5, label="radial disk: η")
    ax.set_xlabel("vertices N")
    ax.set_ylabel("η, error")
    ax.set_title("η against N (pacman); η and error (radial disk)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    bx.set_xlabel("wall time (s)")
    bx.set_ylabel("η")
    bx.set_title("pacman: η against wall time", fontsize=10)
    bx.grid(True, which="both", alpha=0.3)
    bx.legend(fontsize=8)
    fig.savefig(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--h", type=float, default=0.2, help="Gmsh size of the initial mesh (default 0.2)")
    ap.add_argument("--levels", default="2,3,4,5,6", help="uniform refinement levels (default 2,3,4,5,6)")
    ap.add_argument("--theta", type=float, default=0.5, help="Dörfler fraction (default 0.5)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="an override for every run (repeatable), e.g. estimate.bound=sharp")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--omp-wait", choices=("passive", "active", "default"), default="passive",
                    help="OMP_WAIT_POLICY of every run (default passive; default: unset)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per timed case, median reported (default 1)")
    ap.add_argument("--check", type=int, default=3, help="last steps checked against a plain solve (default 3)")
    ap.add_argument("--no-radial", action="store_true", help="skip the radial disk run")
    ap.add_argument("-o", "--outdir", default=str(ROOT / "results" / "adaptivity"))
    args = ap.parse_args()
    if not Path(args.exe).is_file():
        sys.exit(f"adaptivity: {args.exe}: no such executable (build with scripts/bootstrap.sh)")
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    mesh = pacman(args.h, out / "pacman.msh")
    gmsh_case = ("mesh.domain=gmsh", f"mesh.file={mesh}")

    uniform = []
    for level in (int(x) for x in args.levels.split(",")):
        print(f"adaptivity: uniform, level {level}", file=sys.stderr)
        path = timed(args, out / f"uniform_{level}.h5", *gmsh_case, f"mesh.levels={level}", *PROBLEM)
        s = summary(path)
        uniform.append({"level": level, "nv": int(s["nv"]), "eta": s["eta_total"], "wall": s["wall_time"]})
    target = uniform[-1]["eta"]
    print(f"adaptivity: adaptive to eta <= {target:.4g}", file=sys.stderr)
    path = timed(args, out / "adaptive.h5", *gmsh_case, "mesh.levels=0", *PROBLEM, f"adapt.tol={target!r}",
                 f"adapt.theta={args.theta}", "adapt.max_steps=200")
    adapt = adapt_steps(path)
    s_adapt = summary(path)

    nu = [u["nv"] for u in uniform]
    table(["uniform level", "vertices", "η", "wall time (s)"],
          [[u["level"], u["nv"], f"{u['eta']:.4e}", f"{u['wall']:.2f}"] for u in uniform])
    print(f"Uniform: slope of log η against log N over the levels' second half: "
          f"{slope(nu, [u['eta'] for u in uniform]):.3f}.\n")
    cumulative = np.cumsum(adapt["wall_time"])
    table(["adaptive step", "vertices", "η", "η_disc", "η_lin", "η_alg", "step (s)", "cumulative (s)"],
          [[k + 1, int(adapt["vertices"][k]), f"{adapt['eta'][k]:.4e}", f"{adapt['eta_disc'][k]:.3e}",
            f"{adapt['eta_lin'][k]:.2e}", f"{adapt['eta_alg'][k]:.2e}", f"{adapt['wall_time'][k]:.2f}",
            f"{cumulative[k]:.2f}"] for k in range(len(adapt["eta"]))])
    rate = slope(adapt["vertices"], adapt["eta"])
    ratio_n = uniform[-1]["nv"] / adapt["vertices"][-1]
    ratio_t = s_adapt["wall_time"] / uniform[-1]["wall"]
    table(["to η ≤ " + f"{target:.4e}", "vertices", "wall time (s)", "slope (second half)"],
          [["uniform", uniform[-1]["nv"], f"{uniform[-1]['wall']:.2f}", f"{slope(nu, [u['eta'] for u in uniform]):.3f}"],
           ["adaptive", int(adapt["vertices"][-1]), f"{s_adapt['wall_time']:.2f}", f"{rate:.3f}"],
           ["uniform / adaptive", f"{ratio_n:.2f}", f"{1 / ratio_t:.2f}", ""]])

    checks = []
    n_steps = len(adapt["eta"])
    with h5py.File(path) as f:
        for k in range(max(1, n_steps - args.check), n_steps + 1):
            g = f[f"adapt/step_{k:03d}"]
            msh = write_msh(g["vertices"][()], g["triangles"][()], out / f"step_{k:03d}.msh")
            print(f"adaptivity: plain solve on step {k}'s mesh", file=sys.stderr)
            plain = out / f"plain_{k:03d}.h5"
            twomem(args, plain, "mesh.domain=gmsh", f"mesh.file={msh}", "mesh.levels=0", *PROBLEM)
            wall = summary(plain)["wall_time"]
            checks.append([k, int(adapt["vertices"][k - 1]), f"{adapt['wall_time'][k - 1]:.2f}", f"{wall:.2f}",
                           f"{adapt['wall_time'][k - 1] / wall:.2f}"])
    table(["step", "vertices", "step (s)", "plain solve on its mesh (s)", "ratio"], checks)

    radial = None
    if not args.no_radial:
        print("adaptivity: radial disk, adaptive", file=sys.stderr)
        rpath = out / "radial.h5"
        twomem(args, rpath, "mesh.levels=0", "mesh.coarse_h=0.25", "mesh.boundary_h=0.005", "problem.exact=radial",
               "output.xdmf=.false.", "adapt.tol=1e-3", f"adapt.theta={args.theta}", "adapt.max_steps=200")
        radial = adapt_steps(rpath)
        eff = radial["eta"] / radial["energy_error"]
        table(["radial step", "vertices", "η", "energy error", "effectivity"],
              [[k + 1, int(radial["vertices"][k]), f"{radial['eta'][k]:.4e}", f"{radial['energy_error'][k]:.4e}",
                f"{eff[k]:.3f}"] for k in range(len(eff))])
        print(f"Radial: slope of the energy error over the second half {slope(radial['vertices'], radial['energy_error']):.3f}, "
              f"of η {slope(radial['vertices'], radial['eta']):.3f}; effectivity {eff.min():.3f}–{eff.max():.3f}.\n")

    figure(uniform, adapt, radial, out / "adaptivity.png")
    (out / "adaptivity.json").write_text(json.dumps(
        {"uniform": uniform, "adaptive": {k: v.tolist() for k, v in adapt.items()},
         "adaptive_wall_time": s_adapt["wall_time"], "slope_adaptive": rate, "vertex_ratio": ratio_n,
         "time_ratio": ratio_t, "checks": checks,
         "radial": None if radial is None else {k: v.tolist() for k, v in radial.items()}}, indent=1))
    print(f"wrote {out / 'adaptivity.png'} and {out / 'adaptivity.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
