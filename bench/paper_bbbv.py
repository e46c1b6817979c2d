#!/usr/bin/env python3
"""The paper's case `bbbv` at its three mesh sizes: energy error and Newton steps of the exact
method next to the paper's values, with run time and peak memory.

    .venv/bin/python bench/paper_bbbv.py [--exe build/release/twomem]

The paper reports η_disc and the effectivity index, not the error; its implied energy error is
η_disc / effectivity (its Figs. 3 and 7, postproc/twomem_post/paper.py): 0.0261/1.038, 0.01301/1.035,
0.00605/1.034.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
# coarse_h of our ungraded two-level meshes, the paper's triangles, implied error, Newton steps
SIZES = [(0.25, 2048, 0.0261 / 1.038, 8), (0.122, 7840, 0.01301 / 1.035, 15),
         (0.0582, 34592, 0.00605 / 1.034, 28)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exe", default=str(ROOT / "build" / "release" / "twomem"))
    args = ap.parse_args()
    print(f"{'triangles':>10} {'paper':>7} {'error':>10} {'paper':>10} {'diff':>7} "
          f"{'Newton':>7} {'paper':>6} {'time [s]':>9} {'memory [MiB]':>13}")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for h, nt_paper, err_paper, newton_paper in SIZES:
            out = Path(tmp) / f"bbbv_{h}.h5"
            cmd = [args.exe, "run", str(ROOT / "input" / "paper_p1.nml"), f"mesh.coarse_h={h}",
                   f"mesh.boundary_h={h}", f"output.file={out}"]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(proc.stdout[-2000:], proc.stderr, file=sys.stderr)
                return proc.returncode
            with h5py.File(out) as f:
                s = dict(f["summary"].attrs)
            diff = s["energy_error"] / err_paper - 1
            worst = max(worst, abs(diff))
            print(f"{s['nt']:>10} {nt_paper:>7} {s['energy_error']:>10.5f} {err_paper:>10.5f} "
                  f"{100 * diff:>+6.1f}% {s['newton_iterations']:>7} {newton_paper:>6} "
                  f"{s['wall_time']:>9.2f} {s['peak_memory_kib'] / 1024:>13.1f}")
    print(f"largest relative difference in the energy error: {100 * worst:.1f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
