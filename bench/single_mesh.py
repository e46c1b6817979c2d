#!/usr/bin/env python3
"""A user's own mesh solved as given (mesh.levels=0) against a red-refined mesh of the same
domain and size: Gmsh meshes of the "pacman" domain (the unit disk without its first quadrant:
a curved boundary and a re-entrant 270° corner), made here with the gmsh Python wheel.
Markdown tables on stdout, JSON beside them, progress on stderr.

    .venv/bin/python bench/single_mesh.py [--exe build/release/twomem] [--sizes 0.005,0.0016]
        [--flux rt1,rt0] [--threads 2] [--repeat 3] [--settle 3] [--omp-wait passive]
        [--whole | --whole-only] [--refine 3,4] [-o results/single_mesh]
    .venv/bin/python bench/single_mesh.py --write-mesh 0.005 results/meshes/pacman_0.005.msh

The gmsh wheel is an optional bench dependency, not one of twomem's: `.venv/bin/pip install -r
bench/requirements.txt` (or run the script with any Python that has gmsh, h5py and numpy); the
script says so and stops when it is missing. --sizes are Gmsh mesh sizes h (0.005: 1.1·10^5
vertices, 0.0016: 1.07·10^6). Tables:
- one estimator evaluation on the single mesh, per size and flux, as bench/estimator_cost.py
  does on the disk: the adaptive method from (g, 0, 0), every check evaluated
  (estimate.checks=all), one Newton step and S (8 below 5·10^5 vertices, 3 above); *first* is
  the one-step run's estimator_time per evaluation, *later* the difference of the two runs'
  estimator_time over the difference of their evaluation counts; *set-up s* the estimator phase
  (/performance) minus its evaluations; *peak KB/vertex* the S-step run's peak resident memory
  (KiB per vertex);
- with --whole (--whole-only: this table alone) the whole default adaptive run (problem
  f1 = −1, f2 = 0, no exact solution; RT1 estimators, output) on the single mesh and on
  red-refined peers of about as many vertices, the Gmsh mesh of size h·2^L refined L times
  (--refine, default L = 2 for h > 0.003, else 3), their runs interleaved: coarse triangles,
  vertices, finest Newton steps (+ those of the coarser levels: coarsened meshes below the
  single mesh, the refinement levels below a refined one), GMRES iterations per finest Newton
  step, *total s* the sum of the run's phases (/performance), *process s* the process's wall
  time as this script sees it (reading the mesh file included), µs per vertex of the total, the
  single mesh's µs/vertex over the peer's (medians, and the range of the ratios of each
  interleaved pair of runs: the robust measure on a shared machine), the solve and estimator
  phases, the estimators' evaluations and their µs per vertex per evaluation
  (/summary estimator_time), the peak resident memory (/summary peak_memory_kib) in bytes per
  vertex.
Medians of --repeat runs, each whole run after --settle seconds (a virtual machine's host takes
freed memory back within seconds). --omp-wait passive sets OMP_WAIT_POLICY for twomem: on a
machine other users load, libgomp's spinning barriers wait for descheduled threads.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ("problem.exact=none", "problem.f1=-1", "problem.f2=0")


def pacman(h: float, path: Path) -> Path:
    """The Gmsh mesh of size h of the unit disk minus its first quadrant, MSH 4.1."""
    try:
        import gmsh
    except ImportError:
        sys.exit("single_mesh: needs the gmsh Python wheel: .venv/bin/pip install -r bench/requirements.txt")
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


# OMP_WAIT_POLICY for twomem's runs (--omp-wait): on a machine other users load, libgomp's spinning
# barriers make a 2-thread run wait for a descheduled thread (a 7.6·10^3-vertex run took 7.6 s
# active, 0.33 s passive, beside two compilations)
WAIT_POLICY = ""
PHASES = ("mesh", "assembly", "solve", "estimators", "error", "output")


def run(exe: str, mesh: Path, levels: int, threads: int, out: Path, *args: str) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), "mesh.domain=gmsh", f"mesh.file={mesh}",
           f"mesh.levels={levels}", *PROBLEM, "output.xdmf=.false.", f"output.file={out}", *args]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    if WAIT_POLICY:
        env["OMP_WAIT_POLICY"] = WAIT_POLICY
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    with h5py.File(out) as f:
        s = dict(f["summary"].attrs)
        perf = dict(f["performance"].attrs)
        status = str(f.attrs.get("status", ""))
    out.unlink()
    peak = max(float(v) for k, v in perf.items() if k.endswith("_peak_mib"))
    return {"nv": int(s["nv"]), "nt": int(s["nt"]), "evaluations": int(s["estimator_evaluations"]),
            "seconds": float(s["estimator_time"]),
            "setup": float(perf.get("estimators_seconds", 0.0)) - float(s["estimator_time"]), "peak_mib": peak,
            "peak_kib": int(s["peak_memory_kib"]), "status": status,
            "phases": sum(float(perf.get(f"{p}_seconds", 0.0)) for p in PHASES), "elapsed": elapsed,
            "solve": float(perf.get("solve_seconds", 0.0)), "estimators": float(perf.get("estimators_seconds", 0.0)),
            "wall": float(s["wall_time"]), "newton": int(s["newton_iterations"]),
            "gmres": int(s["gmres_iterations"]), "newton_coarse": int(s.get("newton_iterations_coarse", 0)),
            "eta_alg_remainder": float(s.get("eta_alg_remainder", float("nan")))}


def estimator_rows(args, meshes: dict, tmp: Path) -> list[dict]:
    rows = []
    print("**One estimator evaluation on the single mesh** (the adaptive method from (g, 0, 0), every check "
          f"evaluated; {args.threads} threads, medians of {args.repeat})\n")
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
    """The whole default adaptive run on the single mesh and on its red-refined peer, the runs of
    the two interleaved (single, refined, single, ...) so that the machine's slow phases hit both."""
    rows = []
    print("**The whole adaptive run: the single mesh against a red-refined one of the same domain and "
          f"size** ({args.threads} threads, medians of {args.repeat} interleaved runs)\n")
    head = ("| mesh | coarse triangles | vertices | finest Newton steps (+ coarser) | GMRES per finest Newton step | "
            "total s | process s | µs/vertex | single / this (µs/vertex; range of the pairs) | solve s | estimators s | "
            "evaluations | estimator µs/vertex per evaluation | peak B/vertex |")
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    for h, mesh in meshes.items():
        refine = args.refine or [2 if h > 0.003 else 3]
        cases = [("single (levels=0)", mesh, 0)]
        for lv in refine:
            cases.append((f"refined (levels={lv})", pacman(h * 2**lv, tmp / f"pacman_{h * 2**lv:g}.msh"), lv))
        results = {name: [] for name, _, _ in cases}
        for i in range(args.repeat):
            for name, m, lv in cases:
                time.sleep(args.settle)
                results[name].append(run(args.exe, m, lv, args.threads, tmp / "w.h5"))
                r = results[name][-1]
                print(f"single_mesh: h = {h:g} {name} run {i + 1}: {r['phases']:.2f} s, {r['newton']} Newton steps, "
                      f"{r['status']}", file=sys.stderr, flush=True)
        pair = []
        for name, m, lv in cases:
            rs = results[name]
            nv = rs[0]["nv"]
            med = {k: statistics.median(r[k] for r in rs)
                   for k in ("phases", "elapsed", "solve", "estimators", "seconds", "peak_kib")}
            evals = rs[0]["evaluations"]
            row = {"h": h, "mesh": name, "levels": lv, "coarse_nt": rs[0]["nt"] // 4**lv, "nv": nv,
                   "newton": rs[0]["newton"], "newton_coarse": rs[0]["newton_coarse"],
                   "gmres_per_newton": rs[0]["gmres"] / max(rs[0]["newton"], 1),
                   "total_s": med["phases"], "total_s_all": [r["phases"] for r in rs], "process_s": med["elapsed"],
                   "us_per_vertex": 1e6 * med["phases"] / nv, "solve_s": med["solve"],
                   "estimators_s": med["estimators"], "evaluations": evals,
                   "estimator_us_per_vertex_evaluation": 1e6 * med["seconds"] / max(evals, 1) / nv,
                   "peak_bytes_per_vertex": med["peak_kib"] * 1024 / nv,
                   "status": sorted({r["status"] for r in rs})}
            pair.append(row)
        single = results[cases[0][0]]
        for row, (name, _, _) in zip(pair[1:], cases[1:]):
            # the single mesh's µs/vertex over this one's, medians, and per interleaved pair of runs
            row["single_over_refined"] = pair[0]["us_per_vertex"] / row["us_per_vertex"]
            row["single_over_refined_runs"] = [(a["phases"] / pair[0]["nv"]) / (b["phases"] / row["nv"])
                                               for a, b in zip(single, results[name])]
        for row in pair:
            ratio = (f"{row['single_over_refined']:.2f} ({min(row['single_over_refined_runs']):.2f}–"
                     f"{max(row['single_over_refined_runs']):.2f})" if "single_over_refined" in row else "–")
            print(f"| {row['mesh']} | {row['coarse_nt']} | {row['nv']} | {row['newton']} (+{row['newton_coarse']}) | "
                  f"{row['gmres_per_newton']:.1f} | {row['total_s']:.2f} | {row['process_s']:.2f} | "
                  f"{row['us_per_vertex']:.2f} | {ratio} | {row['solve_s']:.2f} | {row['estimators_s']:.2f} | "
                  f"{row['evaluations']} | {row['estimator_us_per_vertex_evaluation']:.2f} | "
                  f"{row['peak_bytes_per_vertex']:.0f} |", flush=True)
        rows += pair
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--sizes", default="0.005,0.0016")
    ap.add_argument("--flux", default="rt1,rt0")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--settle", type=float, default=3.0, help="seconds to wait before each whole run (default 3)")
    ap.add_argument("--whole", action="store_true", help="also the whole default adaptive run, single vs refined")
    ap.add_argument("--whole-only", action="store_true", help="only the whole runs (no estimator table)")
    ap.add_argument("--refine", type=lambda t: [int(x) for x in t.split(",")], default=None,
                    help="refinements of the peers, comma list (default 2 for h > 0.003, 3 below): the peer "
                         "is the Gmsh mesh of size h·2^L refined L times")
    ap.add_argument("-o", "--output", default=str(ROOT / "results" / "single_mesh"))
    ap.add_argument("--omp-wait", choices=("active", "passive"), default=None,
                    help="OMP_WAIT_POLICY for twomem (passive on a loaded machine)")
    ap.add_argument("--write-mesh", nargs=2, metavar=("H", "FILE"),
                    help="only write the Gmsh mesh of size H to FILE (for bench/petsc_vi.py --mesh) and stop")
    args = ap.parse_args()
    if args.write_mesh:
        h, path = float(args.write_mesh[0]), Path(args.write_mesh[1])
        path.parent.mkdir(parents=True, exist_ok=True)
        pacman(h, path)
        print(f"single_mesh: wrote {path}", file=sys.stderr)
        return 0
    global WAIT_POLICY
    WAIT_POLICY = args.omp_wait or ""
    out_dir = Path(args.output)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        meshes = {float(h): pacman(float(h), tmp / f"pacman_{h}.msh") for h in args.sizes.split(",")}
        result = {}
        if not args.whole_only:
            result["estimators"] = estimator_rows(args, meshes, tmp)
        if args.whole or args.whole_only:
            print()
            result["whole"] = whole_rows(args, meshes, tmp)
    (out_dir / "single_mesh.json").write_text(json.dumps(result, indent=1))
    print(f"single_mesh: wrote {out_dir / 'single_mesh.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
