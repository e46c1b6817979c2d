"""Regenerate the stress table of docs/robustness.md: every case of stress_lib by every method,
judged as in test_stress.py, written between the table markers of the document.

    TWOMEM_EXE=build/release/twomem .venv/bin/python tests/stress/table.py [--print]

--print writes the table to standard output instead. Exits 1 if any outcome is unacceptable
(the table then says which and why).
"""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
os.environ.setdefault("TWOMEM_SOURCE_DIR", str(HERE.parents[1]))
os.environ.setdefault("TWOMEM_TEST_TMP", str(HERE.parents[1] / "build" / "stress-table"))
os.environ.setdefault("TWOMEM_EXE", str(HERE.parents[1] / "build" / "release" / "twomem"))
sys.path.insert(0, str(HERE))

import stress_lib as sl  # noqa: E402

BEGIN, END = "<!-- stress table: begin (tests/stress/table.py) -->", "<!-- stress table: end -->"


def cell(o: sl.Outcome, problems: list[str]) -> str:
    if problems:
        return "**FAIL**: " + "; ".join(problems).replace("|", "/")
    if o.converged:
        its = f"{o.newton} N" + (f", {o.gmres} G" if o.linear != "direct" else "")
        if o.linear == "adaptive":
            return f"ok, {its}, E-err/η {o.error / (o.bound / sl.ADAPTIVE_FACTOR):.0e}"
        what = "res" if o.bound == sl.RESIDUAL_BOUND else "err"
        return f"ok, {its}, {what} {o.error:.0e}" + (" (ref.)" if what == "res" else "")
    return f"exit 1: {o.status.removeprefix('not converged: ')} ({o.newton} N)"


def main() -> int:
    rows, bad = [], 0
    for case in sl.CASES:
        runs, ref = sl.run_all(case)
        cells = []
        for linear, cfun in sl.METHODS:
            o = runs[(linear, cfun)]
            problems = sl.judge(o, ref)
            bad += bool(problems)
            cells.append(cell(o, problems))
            print(f"{case.name} {linear}/{cfun}: {cells[-1]}", file=sys.stderr)
        rows.append(f"| `{case.name}`: {case.what} | " + " | ".join(cells) + " |")
    head = "| case | " + " | ".join(f"{lin} {c}" for lin, c in sl.METHODS) + " |"
    table = "\n".join([head, "|" + " --- |" * (len(sl.METHODS) + 1), *rows])
    if "--print" in sys.argv:
        print(table)
    else:
        doc = HERE.parents[1] / "docs" / "robustness.md"
        text = doc.read_text()
        start, end = text.index(BEGIN) + len(BEGIN), text.index(END)
        doc.write_text(text[:start] + "\n" + table + "\n" + text[end:])
        print(f"table written to {doc}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
