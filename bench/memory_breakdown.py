#!/usr/bin/env python3
"""Where the memory of a run goes at its peak: heaptrack records every heap allocation of one
run, and the allocations still live at the moment of the largest heap are grouped by the part of
the code that made them; a markdown table in MiB and KiB per vertex.

    .venv/bin/python bench/memory_breakdown.py [--exe build/release/twomem] [--levels 5] [KEY=VALUE ...]

The run is input/default.nml (the adaptive method with RT1 estimators, the exact error and the
output) with mesh.levels set and any further KEY=VALUE overrides. heaptrack (Debian package
`heaptrack`) is installed by this script if missing, for the benchmark only. An allocation
belongs to the group that claims the innermost "routine < caller" pair of its call stack (so a
factorization inside UMFPACK counts for the twomem routine that asked for it); one that no group
claims is listed as `other` with its routine, and rows under half a MiB are summed in one line.
heaptrack counts the heap only: the resident peak that a run reports (`time: ... peak MiB`) also
has the program, its libraries and the stacks, some tens of MiB more. Under heaptrack the run
takes about twice as long; its memory is that of a normal run.
"""
import argparse
import collections
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (group, patterns): an allocation belongs to the first group with a pattern in the innermost
#: "routine < caller" pair of its stack that any group claims (see `classify`)
GROUPS = [
    ("estimator evaluation: σ_disc per triangle, the evaluated iterate's nodal fields",
     ["estimate_estimators_MOD_init <", "estimate_estimators_MOD_evaluate", "app_observer_MOD_refresh <"]),
    ("algebraic flux: σ on its meshes, P2 projections, coarse problem and factorization",
     ["estimate_alg_flux_MOD_init", "estimate_alg_flux_MOD_compute"]),
    ("patch factors, shape classes, colourings", ["estimate_patch_classes", "estimate_shapes", "estimate_coloring"]),
    ("mesh hierarchy (every level)", ["mesh_hierarchy"]),
    ("multigrid preconditioner: both hierarchies, transfers, V-cycle vectors, elimination vectors",
     ["newton_elimination", "linalg_multigrid", "coarsen <", "linalg_chebyshev", "linalg_galerkin",
      "linalg_csr_MOD_transposed"]),
    ("GMRES: Krylov basis and current iterate", ["linalg_gmres"]),
    ("Newton: iterate, right-hand side, C-function rows, system, residual",
     ["newton_solver_MOD_newton_solve <", "newton_system", "newton_residual", "app_levels_MOD_solve_levels <"]),
    ("discrete problem: stiffness, loads, mass", ["fem_discrete_MOD_discrete_init < app_"]),
    ("exact error: cached exact part, per-step values", ["fem_error", "app_observer_MOD_observe <"]),
]


def ensure_heaptrack() -> str:
    exe = shutil.which("heaptrack")
    if exe is None:
        print("memory_breakdown: installing heaptrack (apt-get) for this benchmark", file=sys.stderr)
        subprocess.run(["apt-get", "install", "-y", "-qq", "heaptrack"], check=True)
        exe = shutil.which("heaptrack")
    if exe is None or shutil.which("heaptrack_print") is None:
        sys.exit("memory_breakdown: heaptrack and heaptrack_print are needed (apt-get install heaptrack)")
    return exe


def frames(stack: str) -> list[str]:
    """The twomem (and UMFPACK) frames of one flame-graph stack, outermost first, without the
    gfortran module prefix, the compiler's clone suffixes and the source location."""
    keep = []
    for frame in stack.split(";"):
        name = frame.split(" (")[0]
        if "__twomem_" in name or name == "coarsen" or name.startswith("umfpack"):
            keep.append(name.replace("__twomem_", "").replace(".constprop.0", "").replace(".isra.0", ""))
    return keep


def classify(stack: str) -> str:
    """The group of one allocation: its "routine < caller" pairs from the innermost outwards,
    the first that a group's pattern matches (so a factorization inside UMFPACK belongs to the
    twomem routine that asked for it)."""
    tw = frames(stack)
    for i in range(len(tw) - 1, 0, -1):
        pair = f"{tw[i]} < {tw[i - 1]}"
        for group, patterns in GROUPS:
            if any(p in pair for p in patterns):
                return group
    return "other: " + (" < ".join(reversed(tw[-2:])) or "outside twomem")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("overrides", nargs="*", help="further KEY=VALUE overrides of input/default.nml")
    args = ap.parse_args()
    heaptrack = ensure_heaptrack()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        cmd = [heaptrack, "-o", str(out / "run"), args.exe, "run", str(ROOT / "input" / "default.nml"),
               f"mesh.levels={args.levels}", *args.overrides, f"output.file={out / 'result.h5'}"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"memory_breakdown: {' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr.strip()}")
        match = re.search(r"(\d+) vertices", proc.stdout.split("summary:")[-1])
        if match is None:
            sys.exit("memory_breakdown: no summary line in the run's output")
        nv = int(match.group(1))
        data = next(out.glob("run*"))
        stacks = out / "peak.stacks"
        subprocess.run(["heaptrack_print", "-f", str(data), "--flamegraph-cost-type", "peak", "-F", str(stacks)],
                       check=True, capture_output=True)
        sizes: dict[str, int] = collections.defaultdict(int)
        for line in stacks.read_text().splitlines():
            stack, _, count = line.rpartition(" ")
            sizes[classify(stack)] += int(count)
    total = sum(sizes.values())
    print(f"heap at its peak: {total / 2**20:.0f} MiB, {total / 1024 / nv:.2f} KiB per vertex ({nv} vertices)")
    print()
    print("| part | MiB | KiB/vertex | share |")
    print("| --- | --- | --- | --- |")
    small = 0
    for group, size in sorted(sizes.items(), key=lambda item: -item[1]):
        if size < 2**20 / 2:
            small += size
            continue
        print(f"| {group} | {size / 2**20:.0f} | {size / 1024 / nv:.3f} | {100 * size / total:.1f}% |")
    if small:
        print(f"| everything under half a MiB | {small / 2**20:.1f} | {small / 1024 / nv:.3f} | "
              f"{100 * small / total:.1f}% |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
