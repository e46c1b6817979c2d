"""A study's results as tables: one summary row per run, history rows in long format, CSV
files, and the markdown table that puts the paper's numbers beside ours.

Long format (one row per history record, the run's tag, method and mesh repeated) because that
is what a spreadsheet or pandas groups and filters without reshaping. In the CSV files a
quantity the run did not compute is ``nan`` (as in the result file) and one the run could not
provide at all (failed run, attribute absent from an older file) is empty.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import paper
from .result import Result
from .runner import Run

#: /summary attributes copied into summary.csv, in this order
SUMMARY = ("nt", "nv", "levels", "newton_iterations", "gmres_iterations",
           "newton_iterations_coarse", "gmres_iterations_coarse", "eta_total", "eta_disc",
           "eta_lin", "eta_alg", "energy_error", "effectivity", "wall_time", "peak_memory_kib")
#: /history columns in the order of docs/output.md; others follow alphabetically
HISTORY = ("newton_it", "gmres_it", "inner", "eta_disc", "eta_lin", "eta_alg", "eta_total",
           "energy_error", "lin_residual", "alg_residual", "active", "active_changed", "step",
           "wall_time")


@dataclass
class Outcome:
    """A finished run and its result file (None when the run wrote none or it is unusable)."""
    run: Run
    result: Result | None

    @property
    def failed(self) -> bool:
        """A non-zero exit (error, not converged) or no usable result."""
        return self.run.failed or self.result is None

    @property
    def status(self) -> str:
        if self.result is not None:
            return self.result.status
        return f"failed: {self.run.error}"

    def ident(self) -> dict:
        """The columns that say which run a row belongs to."""
        return {"tag": self.run.tag, "method": self.run.method, **self.run.params}

    def summary_row(self) -> dict:
        s = self.result.summary if self.result is not None else {}
        return {**self.ident(), **{k: s.get(k, "") for k in SUMMARY},
                "status": self.status,
                "exit_code": "" if self.run.exit_code is None else self.run.exit_code}

    def history_rows(self) -> list[dict]:
        if self.result is None or not self.result.history:
            return []
        h = self.result.history
        nt = self.result.summary.get("nt", "")
        columns = list(h)
        return [{**self.ident(), "nt": nt, **{c: h[c][i].item() for c in columns}}
                for i in range(len(next(iter(h.values()))))]


def history_columns(rows: list[dict], first: list[str]) -> list[str]:
    present = {k for row in rows for k in row} - set(first)
    return first + [c for c in HISTORY if c in present] + sorted(present - set(HISTORY))


def write_csv(path: Path, rows: list[dict], columns: list[str]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _number(v) -> str:
    if v == "" or v is None:
        return "—"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return "—" if not math.isfinite(v) else f"{v:.4g}"


def _with_paper(ours, theirs) -> str:
    text = _number(ours)
    return text if theirs is None else f"{text} ({_number(theirs)})"


def _markdown_cells(row: dict, mesh_nt: float, with_paper: bool) -> list[str]:
    """One table row; the paper's values are those of the mesh (mesh_nt triangles), so a run
    that failed still shows what the paper reached there."""
    i = paper.mesh_index(mesh_nt) if with_paper else None

    def ours_and_paper(quantity):
        theirs = paper.value(quantity, row["method"], mesh_nt) if with_paper else None
        return _with_paper(row[quantity], theirs)

    return [row["method"], _with_paper(row["nt"], None if i is None else paper.TRIANGLES[i]),
            ours_and_paper("newton_iterations"), ours_and_paper("gmres_iterations"),
            ours_and_paper("eta_total"), _number(row["energy_error"]),
            ours_and_paper("effectivity"), _number(row["wall_time"]), _short_status(row)]


def _short_status(row: dict) -> str:
    """The status, or for a run without a result only its exit code (the CSV has the why)."""
    if str(row["status"]).startswith("failed:"):
        return f"failed (exit {row['exit_code']})" if row["exit_code"] != "" else "not run"
    return row["status"].replace("|", "/")


def markdown(rows: list[dict], mesh_keys, with_paper: bool) -> str:
    """The summary as a markdown table; the paper's value in parentheses where it has one.
    mesh_keys are the columns that identify a mesh (the sweep's keys)."""
    head = ["method", "triangles", "Newton", "GMRES", "η", "energy error", "effectivity",
            "wall time (s)", "status"]
    if with_paper:
        head = [h + " (paper)" if h in ("triangles", "Newton", "GMRES", "η", "effectivity")
                else h for h in head]

    def mesh(row):
        return tuple(row[k] for k in mesh_keys)

    nt_of_mesh = {mesh(row): row["nt"] for row in rows if row["nt"] != ""}
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lines += ["| " + " | ".join(_markdown_cells(row, nt_of_mesh.get(mesh(row), math.nan),
                                                with_paper)) + " |" for row in rows]
    return "\n".join(lines)
