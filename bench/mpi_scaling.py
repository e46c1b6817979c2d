#!/usr/bin/env python3
"""Distributed runs: strong and weak scaling on 1 to 4 MPI ranks, the messages they send, and a
per-phase model of computation and communication that extrapolates to 64–1024 ranks.

    .venv/bin/python bench/mpi_scaling.py [--ranks 1,2,3,4] [--levels 5] [--repeat 3]
                                          [--weak-levels 4] [-o results/mpi_scaling]

Every run is the unit disk of bench/scaling.py (coarse_h = 0.1, boundary vertices 0.02 apart,
1262 coarse vertices), case `membranes`, Newton-min, GMRES with the multigrid preconditioner,
nested iteration, no estimators, one OpenMP thread per rank (with 2 cores, 3 and 4 ranks are
oversubscribed: their times say little, their message counts are exact). Rows:

* strong: the same mesh (`--levels`, 1.1M vertices at 5) on 1..4 ranks, plus the threaded run
  (1 rank × 2 threads) it competes with;
* weak: about the same number of vertices per rank: the coarse mesh size h/sqrt(P) refined
  `--weak-levels` times;
* messages: a run per rank count with Open MPI's monitoring components (pml and coll
  `monitoring`), which count every message and byte each rank sends, point to point (halo sums)
  and in collectives (reductions of the inner products and norms, the gather of the coarsest
  level to rank 0 and the scatter back, broadcasts of the set-up).

The model (printed with its inputs) predicts the solve time of N vertices on P ranks as

    T(N, P) = t_v N/P                                   compute, t_v measured on one rank
            + I [m_h (α + b_h(N/P)/β)]                   halo exchanges, I = GMRES iterations
            + I [m_r 2 log2(P) α]                        allreduces (recursive doubling)
            + I [m_c (2 α log2 P + 2·8 n_g/β + t_c(n_g))] coarsest level: gather, solve, scatter
            + t_s n_c                                   nested start on the coarse mesh

with m_h, m_r, m_c the messages per GMRES iteration and b_h the halo bytes per exchange,
measured here (b_h scaled with the interface length, √(N/P)), n_c the coarse mesh's vertices
and n_g the unknowns of the level gathered to rank 0, t_c one triangular solve of that size (measured by bench/coarse_solve.py with SciPy's SuperLU on
twomem's meshes of that size; twomem uses UMFPACK, a solver of the same kind), and α, β the
network's latency and bandwidth: given, not measured (a 2-core machine has no network); the
defaults are typical of an HDR InfiniBand cluster (1.5 µs, 12 GB/s). The output phase, where
rank 0 gathers and writes the whole result, is estimated beside it from the measured result
size per vertex (gather at β, write at --write-bandwidth).

A coarse mesh of more than 2000 vertices (multigrid's coarse_size) gets algebraic (smoothed
aggregation) levels below it, built within each rank, so that what rank 0 gathers and solves
is n_g ≤ 2000 unknowns however many ranks there are; their halo exchanges are measured by a
second monitored run on 2 ranks whose coarse mesh is that large (--alg-coarse-h), which gives
m_h, m_c and b_h for those rows. A coarse mesh of more than 3000 vertices is also solved whole
on every rank as the nested start (coarsened further, docs/method.md §5): t_s, the seconds
per coarse vertex of the solves on the coarsened meshes (what every rank repeats; the coarse
mesh itself is then solved distributed), is measured by a one-rank run on that mesh.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
CASE = ["problem.exact=none", "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1", "problem.g=0.05",
        "newton.linear=gmres", "gmres.precond=mg", "newton.cfun=min", "estimate.enabled=.false.",
        "output.history=.false.", "output.xdmf=.false."]
PHASES = ("mesh", "assembly", "solve", "output")
COARSE_SIZE = 2000      # multigrid's coarse_size: larger coarse meshes get algebraic levels
COARSENED_START = 3000  # larger coarse meshes are solved whole on every rank as the nested start


def mpi_env(threads: int) -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS=str(threads), OMPI_ALLOW_RUN_AS_ROOT="1",
                OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def run(exe: str, ranks: int, threads: int, overrides: list[str], out: Path, monitor: Path | None = None,
        accept: tuple[int, ...] = (0,)) -> dict:
    cmd = ["mpirun", "-n", str(ranks), "--oversubscribe", "--bind-to", "none"]
    if monitor is not None:
        cmd += ["--mca", "pml_monitoring_enable", "2", "--mca", "pml_monitoring_enable_output", "3",
                "--mca", "pml_monitoring_filename", str(monitor)]
    cmd += [exe, "run", str(ROOT / "input" / "default.nml"), *CASE, *overrides, f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=mpi_env(threads))
    if proc.returncode not in accept:
        sys.exit(f"mpi_scaling: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}")
    with h5py.File(out) as f:
        perf = dict(f["performance"].attrs)
        s = dict(f["summary"].attrs)
    size = out.stat().st_size
    out.unlink()
    return {"nv": int(s["nv"]), "newton": int(s["newton_iterations"]), "gmres": int(s["gmres_iterations"]),
            "gmres_all": int(s["gmres_iterations"]) + int(s["gmres_iterations_coarse"]),
            **{p: float(perf[f"{p}_seconds"]) for p in PHASES},
            "peak_mib": max(float(v) for k, v in perf.items() if k.endswith("_peak_mib")), "file_bytes": size,
            "coarsened_s": sum(float(m.group(1)) for m in re.finditer(r"nested: coarsened mesh .*?([0-9.]+) s$",
                                                                      proc.stdout, re.M))}


def median_run(args, ranks: int, threads: int, overrides: list[str], tmp: Path) -> dict:
    runs = [run(args.exe, ranks, threads, overrides, tmp / f"r{ranks}_{threads}_{i}.h5") for i in range(args.repeat)]
    row = dict(runs[0])
    for key in (*PHASES, "peak_mib"):
        row[key] = statistics.median(r[key] for r in runs)
    row["total"] = sum(row[p] for p in PHASES)
    row.update(ranks=ranks, threads=threads)
    return row


def mesh(coarse_h: float, levels: int) -> list[str]:
    return [f"mesh.coarse_h={coarse_h:.6g}", f"mesh.boundary_h={coarse_h / 5:.6g}", f"mesh.levels={levels}"]


def read_monitoring(prefix: Path) -> list[dict]:
    """Per rank: point-to-point messages and bytes sent (user messages, 'E' lines) and to how
    many peers, and the collective traffic on twomem's communicator (the DUP of
    MPI_COMM_WORLD): one-to-all (broadcasts, scatters), all-to-one (gathers, reductions to
    rank 0) and all-to-all (allreduces)."""
    ranks = []
    for path in sorted(glob.glob(f"{prefix}.*.prof"), key=lambda q: int(q.split(".")[-2])):
        r = {"p2p_msgs": 0, "p2p_bytes": 0, "peers": 0, "o2a_msgs": 0, "o2a_bytes": 0, "a2o_msgs": 0,
             "a2o_bytes": 0, "a2a_msgs": 0, "a2a_bytes": 0}
        in_dup = False
        for line in Path(path).read_text().splitlines():
            fields = line.split("\t")
            if fields[0] == "E":
                r["p2p_bytes"] += int(fields[3].split()[0])
                r["p2p_msgs"] += int(fields[4].split()[0])
                r["peers"] += 1
            elif fields[0] == "D":
                in_dup = "DUP FROM 0" in line
            elif in_dup and fields[0] in ("O2A", "A2O", "A2A"):
                key = fields[0].lower()
                r[f"{key}_bytes"] += int(fields[2].split()[0])
                r[f"{key}_msgs"] += int(fields[3].split()[0])
        ranks.append(r)
    if not ranks:
        sys.exit(f"mpi_scaling: no monitoring output {prefix}.*.prof (Open MPI's monitoring components?)")
    return ranks


def table(rows: list[dict], title: str, base: dict) -> str:
    lines = [f"**{title}**", "",
             "| ranks × threads | vertices | Newton | GMRES | mesh s | assembly s | solve s | output s | total s "
             "| speed-up (solve) | efficiency | peak MiB (largest rank) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if title.startswith("weak"):
            speed = base["solve"] / r["solve"]
            eff = speed
        else:
            speed = base["solve"] / r["solve"]
            eff = speed / (r["ranks"] * r["threads"])
        lines.append(f"| {r['ranks']} × {r['threads']} | {r['nv']} | {r['newton']} | {r['gmres']} | {r['mesh']:.2f} | "
                     f"{r['assembly']:.2f} | {r['solve']:.2f} | {r['output']:.2f} | {r['total']:.2f} | {speed:.2f} | "
                     f"{eff:.2f} | {r['peak_mib']:.0f} |")
    return "\n".join(lines)


def coarse_solve_fit(args, targets: list[int]) -> tuple[dict, float, float]:
    """Seconds of one coarse triangular solve against the coarse vertex count, measured by
    bench/coarse_solve.py (SciPy's SuperLU on twomem's disk meshes; run by --coarse-python, which
    needs scipy) at about the sizes the model needs, and the least-squares fit t = c n^p."""
    proc = subprocess.run([args.coarse_python, str(ROOT / "bench" / "coarse_solve.py"), args.exe,
                           ",".join(str(n) for n in targets)], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"mpi_scaling: bench/coarse_solve.py failed (scipy for {args.coarse_python}? "
                 f"bench/setup_petsc.sh installs it):\n{proc.stderr.strip()}")
    points = {int(k): float(v) for k, v in json.loads(proc.stdout).items()}
    xs = [math.log(n) for n in points]
    ys = [math.log(t) for t in points.values()]
    mx, my = statistics.mean(xs), statistics.mean(ys)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    return points, math.exp(my - slope * mx), slope


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--ranks", default="1,2,3,4")
    ap.add_argument("--levels", type=int, default=5, help="strong scaling: refinements of the 1262-vertex mesh")
    ap.add_argument("--weak-levels", type=int, default=4, help="weak scaling: refinements per rank count")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--alpha", type=float, default=1.5e-6, help="network latency per message, s")
    ap.add_argument("--beta", type=float, default=12e9, help="network bandwidth per link, bytes/s")
    ap.add_argument("--write-bandwidth", type=float, default=1e9, help="rank 0's file write bandwidth, bytes/s")
    ap.add_argument("--target", type=float, default=1e8, help="vertices of the predicted runs")
    ap.add_argument("--predict", default="64,128,256,512,1024")
    ap.add_argument("--alg-coarse-h", type=float, default=0.029,
                    help="coarse mesh size of the monitored run with algebraic levels (about 1.5e4 coarse vertices)")
    ap.add_argument("--alg-levels", type=int, default=2, help="its refinements")
    ap.add_argument("--coarse-python", default="/usr/bin/python3", help="a Python with scipy, for bench/coarse_solve.py")
    ap.add_argument("-o", "--out", default=str(ROOT / "results" / "mpi_scaling"))
    args = ap.parse_args()
    ranks = [int(x) for x in args.ranks.split(",")]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        strong = [median_run(args, p, 1, mesh(0.1, args.levels), tmp) for p in ranks]
        strong.append(median_run(args, 1, 2, mesh(0.1, args.levels), tmp))
        print("mpi_scaling: strong scaling done", file=sys.stderr, flush=True)
        weak = [median_run(args, p, 1, mesh(0.1 / math.sqrt(p), args.weak_levels), tmp) for p in ranks]
        print("mpi_scaling: weak scaling done", file=sys.stderr, flush=True)
        msgs = {}
        for p in ranks[1:]:
            prefix = tmp / f"mon{p}"
            r = run(args.exe, p, 1, mesh(0.1, args.levels), tmp / "mon.h5", monitor=prefix)
            msgs[p] = {"ranks": read_monitoring(prefix), "its": r["gmres_all"], "nv": r["nv"]}
        prefix = tmp / "monalg"
        r = run(args.exe, 2, 1, mesh(args.alg_coarse_h, args.alg_levels), tmp / "monalg.h5", monitor=prefix)
        alg = {"ranks": read_monitoring(prefix), "its": r["gmres_all"], "nv": r["nv"]}
        start = run(args.exe, 1, 1, mesh(args.alg_coarse_h, 0), tmp / "start.h5")
        print("mpi_scaling: message counts done", file=sys.stderr, flush=True)
        predict = [int(x) for x in args.predict.split(",")]
        points, c_fit, p_fit = coarse_solve_fit(
            args, sorted({min(COARSE_SIZE, max(1262, 15 * p)) for p in predict} | {1262, COARSE_SIZE}))

    report.append(table(strong, f"strong scaling, {strong[0]['nv']} vertices", strong[0]))
    report.append(table(weak, f"weak scaling, {weak[0]['nv']} vertices per rank at 1 rank", weak[0]))
    lines = ["**messages, whole run** (largest count over the ranks; collectives on twomem's communicator)", "",
             "| ranks | GMRES its (all levels) | p2p msgs | p2p MB | peers | p2p msgs / it | bytes / p2p msg "
             "| allreduces / it | gathers to rank 0 / it | KB gathered / it |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for p, m in msgs.items():
        it, rk = m["its"], m["ranks"]
        top = {k: max(r[k] for r in rk) for k in rk[0]}
        # Open MPI's coll monitoring counts operations: A2O at the root (gathers and reductions
        # to rank 0, with their bytes), A2A at every rank (allreduces)
        gathers, gathered = rk[0]["a2o_msgs"], rk[0]["a2o_bytes"]
        lines.append(f"| {p} | {it} | {top['p2p_msgs']} | {top['p2p_bytes'] / 1e6:.2f} | {top['peers']} | "
                     f"{top['p2p_msgs'] / it:.1f} | {top['p2p_bytes'] / max(1, top['p2p_msgs']):.0f} | "
                     f"{top['a2a_msgs'] / it:.1f} | {gathers / it:.2f} | {gathered / it / 1e3:.1f} |")
    report.append("\n".join(lines))

    # --- the model ---------------------------------------------------------------------------
    one = strong[0]
    t_v = one["solve"] / one["nv"]                      # s per vertex, one thread, iterations included
    its = one["gmres_all"]                              # mesh-independent: taken from the run
    p_meas = max(msgs)
    big, two = msgs[p_meas], msgs[min(msgs)]
    top = {k: max(r[k] for r in big["ranks"]) for k in big["ranks"][0]}
    n_meas = big["nv"] / p_meas
    m_h = top["p2p_msgs"] / big["its"] / max(1, top["peers"])   # exchanges per iteration and neighbour
    b_h = top["p2p_bytes"] / max(1, top["p2p_msgs"])            # bytes per halo message
    m_r = two["ranks"][0]["a2a_msgs"] / two["its"]               # allreduces per iteration
    m_c = two["ranks"][0]["a2o_msgs"] / two["its"]               # gathers (coarse solves) per iteration
    peers = 6                                                    # a 2-D partition's neighbours
    top_a = {k: max(r[k] for r in alg["ranks"]) for k in alg["ranks"][0]}
    m_h_a = top_a["p2p_msgs"] / alg["its"] / max(1, top_a["peers"])
    b_h_a = top_a["p2p_bytes"] / max(1, top_a["p2p_msgs"])
    n_meas_a = alg["nv"] / 2
    m_c_a = alg["ranks"][0]["a2o_msgs"] / alg["its"]
    n_c_a = round(alg["nv"] / 4 ** args.alg_levels)
    t_s = start["coarsened_s"] / start["nv"]
    lines = ["**model inputs**", "",
             f"- compute: t_v = {t_v * 1e6:.3f} µs per vertex for the whole solve on one thread "
             f"({one['nv']} vertices, {its} GMRES iterations on all levels, {one['newton']} Newton steps finest)",
             f"- halo: {m_h:.1f} exchanges per GMRES iteration and neighbour, {b_h:.0f} bytes per message at "
             f"{n_meas:.0f} vertices per rank (measured on {p_meas} ranks), scaled by √(N/P); {peers} neighbours",
             f"- reductions: {m_r:.1f} allreduces per GMRES iteration (all of the run's, over its GMRES iterations)",
             f"- coarsest level: {m_c:.2f} gathers to rank 0 and scatters back per GMRES iteration (the count "
             f"includes the few gathers of the set-up and the output); one triangular solve of n_c unknowns "
             f"t_c = {c_fit:.3g} n_c^{p_fit:.2f} s, fitted to "
             + ", ".join(f"{t * 1e3:.2f} ms at {n}" for n, t in points.items())
             + " (bench/coarse_solve.py: SuperLU on twomem's disk meshes)",
             f"- algebraic levels (coarse mesh of about {n_c_a} vertices refined {args.alg_levels} times, "
             f"{alg['nv']} vertices, 2 ranks, {alg['its']} GMRES iterations on all levels): {m_h_a:.1f} exchanges per "
             f"GMRES iteration and neighbour, {b_h_a:.0f} bytes per message at {n_meas_a:.0f} vertices per rank, "
             f"{m_c_a:.2f} gathers to rank 0 per iteration, of at most {COARSE_SIZE} unknowns",
             f"- nested start on a coarse mesh above {COARSENED_START} vertices, solved on every rank: "
             f"t_s = {t_s * 1e6:.2f} µs per coarse vertex ({start['nv']} vertices, {start['coarsened_s']:.3f} s "
             "on its coarsened meshes, one thread)",
             f"- network: α = {args.alpha * 1e6:.1f} µs, β = {args.beta / 1e9:.0f} GB/s (assumed, not measured)"]
    report.append("\n".join(lines))

    lines = [f"**predicted solve time for {args.target:.0e} vertices** (a coarse mesh of 30 triangles per rank, "
             "at least 1262 vertices; the iteration counts measured here)", "",
             "| ranks | vertices per rank | coarse vertices | gathered unknowns | compute s | halo s | reductions s "
             "| coarsest level s | coarse start s | total s | parallel efficiency |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    serial = t_v * args.target
    for p in predict:
        n = args.target / p
        n_c_p = max(1262, 15 * p)
        algebraic = n_c_p > COARSE_SIZE
        n_g = COARSE_SIZE if algebraic else n_c_p
        mh, bh, nm, mc = (m_h_a, b_h_a, n_meas_a, m_c_a) if algebraic else (m_h, b_h, n_meas, m_c)
        b = bh * math.sqrt(n / nm)
        comp = t_v * n
        halo = its * mh * peers * (args.alpha + b / args.beta)
        red = its * m_r * 2 * math.log2(p) * args.alpha
        coarse = its * mc * (2 * args.alpha * math.log2(p) + 2 * 8 * n_g / args.beta + c_fit * n_g ** p_fit)
        start_s = t_s * n_c_p if n_c_p > COARSENED_START else 0.0
        total = comp + halo + red + coarse + start_s
        lines.append(f"| {p} | {n:.3g} | {n_c_p} | {n_g} | {comp:.2f} | {halo:.3f} | {red:.3f} | {coarse:.3f} | "
                     f"{start_s:.3f} | {total:.2f} | {serial / p / total:.2f} |")
    per_vertex = one["file_bytes"] / one["nv"]
    total_bytes = per_vertex * args.target
    lines.append("")
    lines.append(f"Output (not in the table): the result holds {per_vertex:.0f} bytes per vertex (mesh and fields, "
                 f"measured), {total_bytes / 1e9:.1f} GB at {args.target:.0e} vertices, all gathered to rank 0 "
                 f"({total_bytes / args.beta:.1f} s at β) and written by it ({total_bytes / args.write_bandwidth:.1f} s "
                 f"at {args.write_bandwidth / 1e9:.0f} GB/s), whatever the rank count; rank 0 needs that much memory.")
    report.append("\n".join(lines))
    text = "\n\n".join(report)
    print(text)
    (out / "mpi_scaling.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
