#!/usr/bin/env python3
"""Resident memory of one run by phase: the largest VmRSS (read from /proc every 20 ms) before
the finest level's Newton steps, in each of those steps (told apart by the run's progress lines
`newton k ...`, each printed when step k ends, its checks and evaluations included) and after
them (the result's fields and the output); a markdown table in MiB and KiB per vertex.

    .venv/bin/python bench/memory_phases.py [--exe build/release/twomem] [--levels 5] [KEY=VALUE ...]

The run is input/default.nml (the adaptive method with RT1 estimators, the exact error and the
output) with mesh.levels set and any further KEY=VALUE overrides. Where the heap goes at the
largest of these moments: bench/memory_breakdown.py.
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def resident_mib(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("overrides", nargs="*", help="further KEY=VALUE overrides of input/default.nml")
    args = ap.parse_args()
    if not Path(args.exe).exists():
        sys.exit(f"memory_phases: {args.exe}: no such executable (build with scripts/bootstrap.sh)")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [args.exe, "run", str(ROOT / "input" / "default.nml"), f"mesh.levels={args.levels}",
               *args.overrides, f"output.file={Path(tmp) / 'result.h5'}"]
        # unbuffered, so that each line arrives when it is written and dates its phase
        env = dict(os.environ, GFORTRAN_UNBUFFERED_PRECONNECTED="y")
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        samples: list[tuple[float, float]] = []

        def poll() -> None:
            while proc.poll() is None:
                rss = resident_mib(proc.pid)
                if rss is not None:
                    samples.append((time.monotonic(), rss))
                time.sleep(0.02)

        poller = threading.Thread(target=poll)
        poller.start()
        lines = [(time.monotonic(), line.rstrip()) for line in proc.stdout]
        proc.wait()
        poller.join()
    if proc.returncode != 0:
        sys.exit(f"memory_phases: {' '.join(cmd)} exited {proc.returncode}:\n"
                 + "\n".join(line for _, line in lines[-20:]))
    match = re.search(r"(\d+) vertices", next((l for _, l in lines if l.startswith("summary:")), ""))
    if match is None:
        sys.exit("memory_phases: no summary line in the run's output")
    nv = int(match.group(1))
    # the finest level's steps (the coarser levels of nested iteration print one line each)
    steps = [(t, l) for t, l in lines if re.match(r"newton\s+\d+\s", l)]
    if not steps:
        sys.exit("memory_phases: no Newton progress lines (output.history must be on)")

    def peak(start: float | None, end: float | None) -> float:
        inside = [rss for t, rss in samples if (start is None or t >= start) and (end is None or t < end)]
        return max(inside, default=float("nan"))

    rows = [("before the finest level's Newton steps", peak(None, steps[0][0]))]
    for (start, _), (end, line) in zip(steps, steps[1:]):
        step = int(line.split()[1])
        rows.append((f"Newton step {step} on the finest level, its checks included", peak(start, end)))
    rows.append(("after the Newton steps: the result's fields and the output", peak(steps[-1][0], None)))
    print(f"resident peak by phase, {nv} vertices")
    print()
    print("| phase | MiB | KiB/vertex |")
    print("| --- | --- | --- |")
    for name, mib in rows:
        print(f"| {name} | {mib:.0f} | {mib * 1024 / nv:.2f} |")
    own = next((l for _, l in lines if l.startswith("wall time:")), "")
    print()
    print(f"the run's own account (its exact peak, which 20 ms samples can miss): {own}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
