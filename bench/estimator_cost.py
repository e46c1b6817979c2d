#!/usr/bin/env python3
"""What one evaluation of the a posteriori estimators costs, and the memory of the run around
it, against the number of vertices N: time per vertex per evaluation with RT1 and RT0 on 1 and
2 OpenMP threads, the speed-up, and the peak memory per vertex; a markdown table and a log–log
plot.

    .venv/bin/python bench/estimator_cost.py [--exe build/release/twomem] [--sizes 0.25:3,0.25:4,0.25:5,0.075:5]
                                             [--flux rt1,rt0] [--threads 1,2] [--repeat 1] [--steps S]
                                             [-o results/estimator_cost]

Each size COARSE_H:LEVELS is input/default.nml (radial on the disk, its exact error switched
off) with mesh.coarse_h and mesh.levels set; the default sizes have 2.2e4, 1.5e5, 1.0e6 and
4.1e6 vertices. Two runs per size, flux and thread count: the adaptive method (the estimators
drive its GMRES stopping test, here at every check: estimate.checks=all) from (g, 0, 0) for
one Newton step and for S (--steps; by default 8 below 5·10^5 vertices and 3 above), with the
fields, /estimators and the history written, as a real run writes them. From the results:
- first s/eval = /summary estimator_time of the one-step run (its single evaluation, with the
  fields of the output): the evaluation alone (residual lifting, both flux reconstructions,
  every element estimator), not the set-up (init), but with the first touch of its arrays;
- later s/eval = the S-step run's estimator_time minus the one-step run's, over the
  difference of their evaluation counts: an evaluation into arrays already in use, which is
  what every further Newton step of an adaptive run pays. Below 5·10^5 vertices an evaluation
  takes tens of milliseconds, and two of them (S = 3) are a small difference of two noisy
  totals (JSON: us_per_vertex_range, the spread over the repeats). On a virtual machine the
  first touch of fresh memory can be slow (docs/performance.md, *Measuring*), a large share of
  the first evaluation;
- µs/vertex = s/eval / N · 1e6; the speed-up is that of the later evaluations; on the most
  threads the later column adds the range over the repeats;
- peak KB/vertex = the whole run's peak resident memory (/performance: the largest phase peak)
  over N, in KiB; `KB/vertex added by the estimators` the same for the peak up to the
  estimator phase minus the peak before it (the mesh and the linear system).
With --repeat R each run is repeated and the median taken. The machine is shared: times are
noisy, compare medians; instruction counts (valgrind --tool=callgrind) are the stable measure.
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


def run(exe: str, coarse_h: str, levels: str, flux: str, threads: int, out: Path, steps: int = 1) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), f"mesh.coarse_h={coarse_h}", f"mesh.levels={levels}",
           "problem.exact=none", f"estimate.flux={flux}", "newton.linear=adaptive", "newton.initial=paper",
           "estimate.checks=all", f"newton.max_it={steps}", "output.xdmf=.false.", f"output.file={out}"]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    # exit 1: not converged within newton.max_it, which is what we ask for
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    with h5py.File(out) as f:
        s = dict(f["summary"].attrs)
        perf = dict(f["performance"].attrs)
    peaks = {k[:-len("_peak_mib")]: float(v) for k, v in perf.items() if k.endswith("_peak_mib")}
    before = max(peaks.get("mesh", 0.0), peaks.get("assembly", 0.0))
    return {"nv": int(s["nv"]), "evaluations": int(s["estimator_evaluations"]), "seconds": float(s["estimator_time"]),
            "peak_mib": max(peaks.values()), "estimators_mib": peaks.get("estimators", 0.0) - before}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--sizes", default="0.25:3,0.25:4,0.25:5,0.075:5")
    ap.add_argument("--flux", default="rt1,rt0")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--steps", type=int, default=0,
                    help="Newton steps of the second run (0: 8 below 5e5 vertices, 3 above)")
    ap.add_argument("-o", "--output", default=str(ROOT / "results" / "estimator_cost"))
    args = ap.parse_args()
    threads = [int(t) for t in args.threads.split(",")]
    fluxes = args.flux.split(",")
    out_dir = Path(args.output)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    # the table of docs/performance.md (bench/update_performance.py replaces it with this one);
    # the later evaluation on the most threads, the headline, with the range of the runs
    def thr(t: int) -> str:
        return f"{t} thread{'s' if t > 1 else ''}"

    head = ("| flux | vertices | "
            + " | ".join(f"first µs/vertex, {thr(t)} | later µs/vertex, {thr(t)}"
                         + (" (range of the runs)" if t == threads[-1] else "") for t in threads)
            + (" | speed-up (later)" if len(threads) > 1 else "")
            + " | peak KB/vertex (whole run) | KB/vertex added by the estimators |")
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes.split(","):
            coarse_h, levels = size.split(":")
            for flux in fluxes:
                per = {}
                for t in threads:
                    firsts, laters, peaks, added = [], [], [], []
                    for _ in range(args.repeat):
                        one = run(args.exe, coarse_h, levels, flux, t, Path(tmp) / "r.h5")
                        steps = args.steps or (8 if one["nv"] < 500_000 else 3)
                        longer = run(args.exe, coarse_h, levels, flux, t, Path(tmp) / "r.h5", steps=steps)
                        if longer["evaluations"] <= one["evaluations"]:
                            sys.exit(f"estimator_cost: {size} {flux}: {steps} Newton steps made no further evaluation")
                        firsts.append(one["seconds"] / one["evaluations"])
                        laters.append((longer["seconds"] - one["seconds"]) / (longer["evaluations"] - one["evaluations"]))
                        peaks.append(longer["peak_mib"])
                        added.append(longer["estimators_mib"])
                    per[t] = {"first": statistics.median(firsts), "later": statistics.median(laters),
                              "later_range": [min(laters), max(laters)], "steps": steps,
                              "peak_mib": statistics.median(peaks), "estimators_mib": statistics.median(added),
                              "nv": one["nv"]}
                nv = per[threads[0]]["nv"]
                row = {"flux": flux, "coarse_h": float(coarse_h), "levels": int(levels), "nv": nv,
                       "s_first": {t: per[t]["first"] for t in threads},
                       "s_later": {t: per[t]["later"] for t in threads},
                       "us_per_vertex_first": {t: 1e6 * per[t]["first"] / nv for t in threads},
                       "us_per_vertex": {t: 1e6 * per[t]["later"] / nv for t in threads},
                       "us_per_vertex_range": {t: [1e6 * v / nv for v in per[t]["later_range"]] for t in threads},
                       "steps": per[threads[0]]["steps"],
                       "peak_kb_per_vertex": 1024 * per[threads[-1]]["peak_mib"] / nv,
                       "estimators_kb_per_vertex": 1024 * per[threads[-1]]["estimators_mib"] / nv}
                rows.append(row)
                lo, hi = row["us_per_vertex_range"][threads[-1]]
                spread = f"({lo:.2f}–{hi:.2f})" if args.repeat > 1 else "(one run)"
                cells = " | ".join(f"{row['us_per_vertex_first'][t]:.2f} | {row['us_per_vertex'][t]:.2f}"
                                   + (f" {spread}" if t == threads[-1] else "") for t in threads)
                speed = (f" | {row['s_later'][threads[0]] / row['s_later'][threads[-1]]:.2f}"
                         if len(threads) > 1 else "")
                print(f"| {flux.upper()} | {nv} | {cells}{speed} | {row['peak_kb_per_vertex']:.2f} | "
                      f"{row['estimators_kb_per_vertex']:.2f} |", flush=True)
    (out_dir / "estimator_cost.json").write_text(json.dumps(rows, indent=1))
    plot(rows, threads, out_dir / "estimator_cost.png")
    print(f"wrote {out_dir / 'estimator_cost.json'} and {out_dir / 'estimator_cost.png'}")
    return 0


def plot(rows: list[dict], threads: list[int], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(11, 4.2))
    for flux, marker in (("rt1", "o"), ("rt0", "s")):
        sel = [r for r in rows if r["flux"] == flux]
        if not sel:
            continue
        n = [r["nv"] for r in sel]
        for t, style in zip(threads, ("--", "-")):
            have = [r for r in sel if t in r["us_per_vertex"]]
            ax_t.loglog([r["nv"] for r in have], [r["us_per_vertex"][t] for r in have], style, marker=marker,
                        label=f"{flux.upper()}, {t} thread{'s' if t > 1 else ''}")
        t = threads[-1]
        ax_t.loglog(n, [r["us_per_vertex_first"][t] for r in sel], ":", marker=marker, alpha=0.6,
                    label=f"{flux.upper()}, {t} thread{'s' if t > 1 else ''}, first evaluation")
        ax_m.loglog(n, [r["peak_kb_per_vertex"] for r in sel], "-", marker=marker, label=f"{flux.upper()}: whole run")
        ax_m.loglog(n, [max(r["estimators_kb_per_vertex"], 1e-3) for r in sel], ":", marker=marker,
                    label=f"{flux.upper()}: added by the estimators")
    ax_t.axhline(2.0, color="grey", lw=0.8)
    ax_t.axhline(1.0, color="grey", lw=0.8, ls=":")
    ax_t.set_xlabel("vertices N")
    ax_t.set_ylabel("µs per vertex per evaluation")
    ax_t.set_title("one further estimator evaluation (targets: RT1 2 µs, RT0 1 µs, 2 threads)", fontsize=9)
    ax_t.legend(fontsize=8)
    ax_m.axhline(1.5, color="grey", lw=0.8)
    ax_m.set_xlabel("vertices N")
    ax_m.set_ylabel("peak KiB per vertex")
    ax_m.set_title("memory (target: 1.5 KB per vertex at 1e6)", fontsize=9)
    ax_m.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
