#!/usr/bin/env python3
"""How the solver's cost grows with the mesh: time per phase, iterations and memory against
the number of vertices, from about 10^4 to 4.5·10^6, as a table and log–log plots.

    .venv/bin/python bench/scaling.py [--levels 2,3,4,5,6] [--cases membranes,bbbv] [--cfun min,fb]
                                      [--method gmres] [--threads 2] [--repeat 3] [--settle 5]
                                      [-o results/scaling]

Every run is the unit disk with a coarse mesh of 1262 vertices (coarse_h = 0.1, boundary
vertices 0.02 apart, the same coarse mesh at every size) refined `levels` times, nested
iteration (the default), the multigrid preconditioner (the default) and no estimators: the
solve, everything but the estimators. The cases: `membranes` (μ1 = 2, μ2 = 0.5,
f1 = −2, f2 = 1, g = 0.05: a large contact zone) and `bbbv` (the paper's, with its known
solution; its exact error is not computed here, as it is not part of a solve). Times are the
run's own phase clock (`/performance` of the result file), the median over `--repeat` runs;
memory is the peak resident set of the run. Columns: Newton steps and GMRES iterations on the
finest level, their ratio, seconds per phase, the total without estimators, µs per vertex of
that total, the user CPU time of all threads per vertex (getrusage of the child: the
computation without the kernel's part), peak MiB and bytes per vertex, and the kernel's CPU
time, in seconds and as a share of the run's (system over user + system), which is mostly the
zeroing of pages the run touches for the first time: on a virtual machine whose first touch of
fresh memory is slow, it is what bends the time per vertex at the largest sizes. The peer run
that tells the host's part from the solver's: after each run, a separate process writes as
many fresh bytes as the run's peak once (one thread, 4-KiB pages) and reports its own kernel CPU
seconds (`touch kernel s`, median; `touch s/GiB` per GiB written). Where the two kernel times
agree, the run's kernel time is the host's price of its peak, paid by any program of that size.
Both wait `--settle` seconds first: a virtual machine's host takes freed memory back within a
few seconds, and a process that touches memory another one has just freed may pay only a
fraction of the price (docs/performance.md, *Measuring*).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "membranes": ["problem.exact=none", "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1",
                  "problem.g=0.05"],
    "bbbv": ["problem.exact=bbbv"],
}
PHASES = ("mesh", "assembly", "solve", "output")


def run_once(exe: str, overrides: list[str], out: Path, threads: int) -> dict:
    cmd = [exe, "run", str(ROOT / "input" / "default.nml"), *overrides, "estimate.enabled=.false.",
           "output.history=.false.", "output.xdmf=.false.", f"output.file={out}"]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    user, system = after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime
    if proc.returncode != 0:
        sys.exit(f"scaling: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr.strip()}")
    with h5py.File(out) as f:
        perf = dict(f["performance"].attrs)
        summary = dict(f["summary"].attrs)
    out.unlink()
    return {"nv": int(summary["nv"]), "newton": int(summary["newton_iterations"]),
            "gmres": int(summary["gmres_iterations"]),
            "newton_coarse": int(summary["newton_iterations_coarse"]),
            "gmres_coarse": int(summary["gmres_iterations_coarse"]),
            **{p: float(perf[f"{p}_seconds"]) for p in PHASES},
            "peak_mib": max(float(v) for k, v in perf.items() if k.endswith("_peak_mib")),
            "user_s": user, "kernel_s": system, "kernel_share": system/max(user + system, 1e-9)}


# The peer of the kernel column: write `n` fresh bytes once, 1 MiB at a time into an anonymous
# mapping (4-KiB pages as the run's heap, where numpy would ask for huge pages), and report the
# kernel CPU seconds of that alone (the interpreter's start is not counted).
TOUCH = """
import mmap, resource, sys
n = int(sys.argv[1])
chunk = bytes([1]) * 2**20
before = resource.getrusage(resource.RUSAGE_SELF).ru_stime
memory = mmap.mmap(-1, n)
for _ in range(n // len(chunk)):
    memory.write(chunk)
memory.write(chunk[:n % len(chunk)])
print(resource.getrusage(resource.RUSAGE_SELF).ru_stime - before)
"""


def touch_once(mib: float) -> float:
    proc = subprocess.run([sys.executable, "-c", TOUCH, str(int(mib * 2**20))], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"scaling: the first-touch peer run of {mib:.0f} MiB failed:\n{proc.stderr.strip()}")
    return float(proc.stdout)


def measure(args, case: str, cfun: str, levels: int, tmp: Path) -> dict:
    overrides = [f"mesh.coarse_h={args.coarse_h}", f"mesh.boundary_h={args.boundary_h}", f"mesh.levels={levels}",
                 f"newton.cfun={cfun}", f"newton.linear={args.method}", *CASES[case], *args.set]
    runs = []
    for i in range(args.repeat):
        time.sleep(args.settle)
        run = run_once(args.exe, overrides, tmp / f"{case}_{cfun}_{levels}_{i}.h5", args.threads)
        time.sleep(args.settle)
        run["touch_kernel_s"] = touch_once(run["peak_mib"])
        runs.append(run)
    row = dict(runs[0])
    for key in (*PHASES, "peak_mib", "user_s", "kernel_s", "kernel_share", "touch_kernel_s"):
        row[key] = statistics.median(r[key] for r in runs)
    row["total"] = sum(row[p] for p in PHASES)
    row.update(case=case, cfun=cfun, levels=levels)
    return row


def table(rows: list[dict]) -> str:
    lines = ["| case | cfun | vertices | Newton | GMRES | GMRES/Newton | mesh s | assembly s | solve s | output s "
             "| total s | µs/vertex | user CPU µs/vertex | peak MiB | B/vertex | kernel CPU s | kernel CPU "
             "| touch kernel s | touch s/GiB |",
             "| --- " * 19 + "|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['cfun']} | {r['nv']} | {r['newton']} | {r['gmres']} | "
                     f"{r['gmres'] / max(1, r['newton']):.1f} | {r['mesh']:.3f} | {r['assembly']:.3f} | "
                     f"{r['solve']:.3f} | {r['output']:.3f} | {r['total']:.3f} | {1e6 * r['total'] / r['nv']:.2f} | "
                     f"{1e6 * r['user_s'] / r['nv']:.2f} | {r['peak_mib']:.0f} | {r['peak_mib'] * 2**20 / r['nv']:.0f} | "
                     f"{r['kernel_s']:.2f} | {100 * r['kernel_share']:.0f}% | {r['touch_kernel_s']:.2f} | "
                     f"{r['touch_kernel_s'] / (r['peak_mib'] / 1024):.2f} |")
    return "\n".join(lines)


def plot(rows: list[dict], out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for key in sorted({(r["case"], r["cfun"]) for r in rows}):
        sel = [r for r in rows if (r["case"], r["cfun"]) == key]
        nv = [r["nv"] for r in sel]
        label = f"{key[0]}, {key[1]}"
        axes[0].loglog(nv, [r["total"] for r in sel], "o-", label=f"{label}: total")
        axes[0].loglog(nv, [r["solve"] for r in sel], "s--", label=f"{label}: solve")
        line, = axes[1].semilogx(nv, [1e6 * r["total"] / r["nv"] for r in sel], "o-", label=f"{label}: wall")
        axes[1].semilogx(nv, [1e6 * r["user_s"] / r["nv"] for r in sel], "^:", color=line.get_color(),
                         label=f"{label}: user CPU (all threads)")
        axes[2].loglog(nv, [r["peak_mib"] for r in sel], "o-", label=label)
    nv_all = sorted({r["nv"] for r in rows})
    # the host's price of fresh memory, from the peer runs (the same at every case's peak, nearly)
    peer = {r["nv"]: r for r in rows}
    axes[1].semilogx(nv_all, [1e6 * peer[n]["touch_kernel_s"] / n for n in nv_all], "k--",
                     label="peer: kernel CPU to touch the same peak once")
    axes[0].loglog(nv_all, [1e-6 * n for n in nv_all], "k:", label="1 µs per vertex")
    axes[0].set(xlabel="vertices", ylabel="seconds", title="time without estimators")
    axes[1].set(xlabel="vertices", ylabel="µs per vertex", title="time per vertex")
    axes[1].set_ylim(bottom=0)
    axes[2].set(xlabel="vertices", ylabel="MiB", title="peak memory")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    # the legend goes above the curves, in room made for it (the peer's line runs along the bottom)
    axes[1].set_ylim(top=1.6 * max(1e6 * max(r["total"], r["user_s"]) / r["nv"] for r in rows))
    axes[1].legend(fontsize=6, loc="upper center", ncol=2)
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", default="2,3,4,5,6")
    ap.add_argument("--coarse-h", type=float, default=0.1)
    ap.add_argument("--boundary-h", type=float, default=0.02)
    ap.add_argument("--cases", default="membranes,bbbv")
    ap.add_argument("--cfun", default="min,fb")
    ap.add_argument("--method", default="gmres", choices=["gmres", "direct", "adaptive"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--settle", type=float, default=5.0,
                    help="seconds to wait before each run and each peer touch (default 5)")
    ap.add_argument("--set", action="append", default=[], metavar="GROUP.KEY=VALUE",
                    help="extra override for every run (repeatable)")
    ap.add_argument("-o", "--out", default=str(ROOT / "results" / "scaling"))
    args = ap.parse_args()
    if not Path(args.exe).exists():
        sys.exit(f"scaling: {args.exe}: no such executable (build with scripts/bootstrap.sh)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases.split(","):
            for cfun in args.cfun.split(","):
                for levels in (int(x) for x in args.levels.split(",")):
                    rows.append(measure(args, case, cfun, levels, Path(tmp)))
                    print(f"scaling: {case} {cfun} levels {levels}: {rows[-1]['nv']} vertices, "
                          f"{rows[-1]['total']:.2f} s", file=sys.stderr, flush=True)
    print(f"threads {args.threads}, method {args.method}, median of {args.repeat} runs, "
          f"{args.settle:g} s settling before each run and peer touch")
    print(table(rows))
    (out / "scaling.json").write_text(json.dumps(rows, indent=1))
    plot(rows, out / "scaling.png")
    print(f"figure: {out / 'scaling.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
