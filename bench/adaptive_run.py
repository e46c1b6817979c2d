#!/usr/bin/env python3
"""The whole adaptive run as a user starts it: `twomem run input/default.nml` (the adaptive
method with multigrid GMRES and guaranteed RT1 estimators, the exact error, the output), with
any overrides, repeated; a one-row markdown table of the ranges over the runs.

    .venv/bin/python bench/adaptive_run.py [--exe build/release/twomem] [--threads 2] [--repeat 3]
                                           [--settle 5] [KEY=VALUE ...]

`mesh.levels=5` gives the 10^6-vertex run of docs/performance.md. Columns: the finest mesh's
vertices, the number of runs, the run's wall time (the sum of its phases, as its `wall time:`
line prints it), the solve and estimator phases (`/performance`), the number of estimator
evaluations and their own time (`/summary` estimator_time: the evaluations without the
estimators' set-up), the peak resident memory (`/summary` peak_memory_kib) in MiB and bytes per
vertex, and the final energy error and bound η. Each run waits `--settle` seconds first: a
virtual machine's host takes freed memory back within seconds, and a run that follows another
at once may find it still backed (docs/performance.md, *Measuring*).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
PHASES = ("mesh", "assembly", "solve", "estimators", "error", "output")


def run_once(exe: str, overrides: list[str], out: Path, threads: int) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), *overrides, "output.xdmf=.false.", f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS=str(threads)))
    if proc.returncode != 0:
        sys.exit(f"adaptive_run: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr.strip()}")
    with h5py.File(out) as f:
        s, perf = dict(f["summary"].attrs), dict(f["performance"].attrs)
    out.unlink()
    return {"nv": int(s["nv"]), "wall": sum(float(perf.get(f"{p}_seconds", 0.0)) for p in PHASES),
            "solve": float(perf["solve_seconds"]), "estimators": float(perf.get("estimators_seconds", 0.0)),
            "evaluations": int(s["estimator_evaluations"]), "evaluations_s": float(s["estimator_time"]),
            "peak_mib": int(s["peak_memory_kib"]) / 1024, "energy_error": float(s["energy_error"]),
            "eta": float(s["eta_total"])}


def span(values: list, fmt: str) -> str:
    """'lo–hi' in the given format, or one value where all runs agree to that format."""
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--settle", type=float, default=5.0, help="seconds to wait before each run (default 5)")
    ap.add_argument("overrides", nargs="*", help="KEY=VALUE overrides of input/default.nml")
    args = ap.parse_args()
    if not Path(args.exe).exists():
        sys.exit(f"adaptive_run: {args.exe}: no such executable (build with scripts/bootstrap.sh)")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            time.sleep(args.settle)
            runs.append(run_once(args.exe, args.overrides, Path(tmp) / f"run{i}.h5", args.threads))
            print(f"adaptive_run: run {i + 1}: {runs[-1]['wall']:.2f} s", file=sys.stderr, flush=True)
    nv = runs[0]["nv"]
    col = {k: [r[k] for r in runs] for k in runs[0]}
    print(f"input/default.nml {' '.join(args.overrides)}, {args.threads} threads, {args.repeat} runs "
          f"{args.settle:g} s apart")
    print("| vertices | runs | wall s | solve s | estimators s | evaluations | evaluations s | peak MiB "
          "| B/vertex | energy error | η |")
    print("| --- " * 11 + "|")
    print(f"| {nv} | {len(runs)} | {span(col['wall'], '.2f')} | {span(col['solve'], '.2f')} | "
          f"{span(col['estimators'], '.2f')} | {span(col['evaluations'], 'd')} | {span(col['evaluations_s'], '.2f')} | "
          f"{span(col['peak_mib'], '.1f')} | {span([m * 2**20 / nv for m in col['peak_mib']], '.0f')} | "
          f"{span(col['energy_error'], '.5e')} | {span(col['eta'], '.5e')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
