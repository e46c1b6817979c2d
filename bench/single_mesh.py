#!/usr/bin/env python3
"""The estimators on a user's own mesh solved as given (mesh.levels=0): Gmsh meshes of the
"pacman" domain (the unit disk without its first quadrant: a curved boundary and a re-entrant
270° corner), made here with the gmsh Python wheel, against red-refined meshes of the same
domain and size. Markdown tables on stdout, JSON beside them.

    python bench/single_mesh.py [--exe build/release/twomem] [--sizes 0.005,0.0016] [--flux rt1,rt0]
                                [--threads 2] [--repeat 3] [--whole] [-o results/single_mesh]

The gmsh wheel is not a dependency of twomem: `.venv/bin/pip install gmsh` (or run the script
with any Python that has gmsh, h5py and numpy). --sizes are Gmsh mesh sizes h (0.005: 1.1e5
vertices, 0.0016: 1.1e6). Per size and flux, as bench/estimator_cost.py does on the disk:
- first / later µs per vertex per evaluation: the adaptive method from (g, 0, 0), every check
  evaluated (estimate.checks=all), one Newton step and S (8 below 5e5 vertices, 3 above); the
  first is the one-step run's estimator_time per evaluation, a later one the difference of the
  two runs' estimator_time over the difference of their evaluation counts;
- set-up s: the run's estimator phase (/performance) minus its evaluations (estimator_time):
  the estimators' init, shape classes, signatures, colouring;
- peak KB/vertex: the whole run's peak resident memory over the vertices.
With --whole also the whole default adaptive run (problem f1 = −1, f2 = 0, no exact solution)
on the single mesh and on a red-refined one of the same domain with about as many vertices
(the Gmsh mesh of size h·2^L refined L times, L = 2 or 3): wall time and peak memory per
vertex, Newton steps, the estimators' share. Medians of --repeat runs: the machine is shared,
compare medians.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ("problem.exact=none", "problem.f1=-1", "problem.f2=0")


def pacman(h: float, path: Path) -> Path:
    """The Gmsh mesh of size h of the unit disk minus its first quadrant, MSH 4.1."""
    try:
        import gmsh
    except ImportError:
        sys.exit("single_mesh: needs the gmsh Python wheel (.venv/bin/pip install gmsh)")
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    occ = gmsh.model.occ
    disk = occ.addDisk(0, 0, 0, 1, 1)
    quad = occ.addRectangle(0, 0, 0, 2, 2)
    cut, _ = occ.cut([(2, disk)], [(2, quad)])
    occ.synchronize()
    gmsh.model.mesh.setSize(gmsh.model.getEntities(0), h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    boundary = [t for _, t in gmsh.model.getBoundary(cut, oriented=False)]
    gmsh.model.addPhysicalGroup(2, [cut[0][1]], 1, name="domain")
    gmsh.model.addPhysicalGroup(1, boundary, 2, name="boundary")
    gmsh.model.mesh.generate(2)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(str(path))
    gmsh.finalize()
    return path


def run(exe: str, mesh: Path, levels: int, threads: int, out: Path, *args: str) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), "mesh.domain=gmsh", f"mesh.file={mesh}",
           f"mesh.levels={levels}", *PROBLEM, "output.xdmf=.false.", f"output.file={out}", *args]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    with h5py.File(out) as f:
        s = dict(f["summary"].attrs)
        perf = dict(f["performance"].attrs)
    peak = max(float(v) for k, v in perf.items() if k.endswith("_peak_mib"))
    return {"nv": int(s["nv"]), "evaluations": int(s["estimator_evaluations"]), "seconds": float(s["estimator_time"]),
            "setup": float(perf.get("estimators_seconds", 0.0)) - float(s["estimator_time"]), "peak_mib": peak,
            "wall": float(s["wall_time"]), "newton": int(s["newton_iterations"]),
            "eta_alg_remainder": float(s.get("eta_alg_remainder", float("nan")))}


def estimator_rows(args, meshes: dict, tmp: Path) -> list[dict]:
    rows = []
    head = "| flux | vertices | first µs/vertex | later µs/vertex | set-up s | peak KB/vertex |"
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    adaptive = ("newton.linear=adaptive", "newton.initial=paper", "estimate.checks=all")
    for h, mesh in meshes.items():
        for flux in args.flux.split(","):
            firsts, laters, setups, peaks = [], [], [], []
            for _ in range(args.repeat):
                one = run(args.exe, mesh, 0, args.threads, tmp / "r.h5", f"estimate.flux={flux}", *adaptive,
                          "newton.max_it=1")
                steps = 8 if one["nv"] < 500_000 else 3
                more = run(args.exe, mesh, 0, args.threads, tmp / "r.h5", f"estimate.flux={flux}", *adaptive,
                           f"newton.max_it={steps}")
                if more["evaluations"] <= one["evaluations"]:
                    sys.exit(f"single_mesh: h = {h} {flux}: {steps} Newton steps made no further evaluation")
                firsts.append(one["seconds"] / one["evaluations"])
                laters.append((more["seconds"] - one["seconds"]) / (more["evaluations"] - one["evaluations"]))
                setups.append(one["setup"])
                peaks.append(more["peak_mib"])
            nv = one["nv"]
            row = {"h": h, "flux": flux, "nv": nv, "threads": args.threads,
                   "us_per_vertex_first": 1e6 * statistics.median(firsts) / nv,
                   "us_per_vertex": 1e6 * statistics.median(laters) / nv,
                   "us_per_vertex_range": [1e6 * min(laters) / nv, 1e6 * max(laters) / nv],
                   "setup_s": statistics.median(setups), "peak_kb_per_vertex": 1024 * statistics.median(peaks) / nv}
            rows.append(row)
            print(f"| {flux} | {nv} | {row['us_per_vertex_first']:.2f} | {row['us_per_vertex']:.2f} | "
                  f"{row['setup_s']:.2f} | {row['peak_kb_per_vertex']:.2f} |", flush=True)
    return rows


def whole_rows(args, meshes: dict, tmp: Path) -> list[dict]:
    rows = []
    head = ("| mesh | vertices | Newton steps | wall s | µs/vertex | estimators s | peak KB/vertex |")
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    for h, mesh in meshes.items():
        levels = 2 if h > 0.003 else 3
        coarse = pacman(h * 2**levels, tmp / f"pacman_{h * 2**levels:g}.msh")
        for name, m, l in (("single (levels=0)", mesh, 0), (f"refined (levels={levels})", coarse, levels)):
            results = [run(args.exe, m, l, args.threads, tmp / "w.h5") for _ in range(args.repeat)]
            nv = results[0]["nv"]
            wall = statistics.median(r["wall"] for r in results)
            est = statistics.median(r["seconds"] + r["setup"] for r in results)
            peak = statistics.median(r["peak_mib"] for r in results)
            row = {"h": h, "mesh": name, "nv": nv, "newton": results[0]["newton"], "wall_s": wall,
                   "us_per_vertex": 1e6 * wall / nv, "estimators_s": est, "peak_kb_per_vertex": 1024 * peak / nv}
            rows.append(row)
            print(f"| {name} | {nv} | {row['newton']} | {wall:.2f} | {row['us_per_vertex']:.1f} | {est:.2f} | "
                  f"{row['peak_kb_per_vertex']:.2f} |", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--sizes", default="0.005,0.0016")
    ap.add_argument("--flux", default="rt1,rt0")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--whole", action="store_true", help="also the whole default adaptive run, single vs refined")
    ap.add_argument("-o", "--output", default=str(ROOT / "results" / "single_mesh"))
    args = ap.parse_args()
    out_dir = Path(args.output)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        meshes = {float(h): pacman(float(h), tmp / f"pacman_{h}.msh") for h in args.sizes.split(",")}
        result = {"estimators": estimator_rows(args, meshes, tmp)}
        if args.whole:
            print()
            result["whole"] = whole_rows(args, meshes, tmp)
    (out_dir / "single_mesh.json").write_text(json.dumps(result, indent=1))
    print(f"wrote {out_dir / 'single_mesh.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
