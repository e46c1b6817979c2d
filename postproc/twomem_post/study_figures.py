"""The figures of a study: how the methods compare over the mesh sequence.

``iterations``
    the paper's Fig. 6: Newton steps against the number of triangles; GMRES iterations in each
    Newton step on the mesh nearest the paper's 7840 triangles; cumulated GMRES iterations
    against the number of triangles.
``work_precision``
    wall time of each run against its energy error (against η when the error is unknown): the
    cost of a given accuracy, the practical verdict on a method.
``estimators``
    η and its components at convergence against the number of triangles, one panel per method
    (the paper's Fig. 3), with the energy error.
``effectivity``
    η / energy error at convergence against the number of triangles (the paper's Fig. 7, right).

Every method keeps one colour and marker (methods.STYLE). Ours are solid lines with filled
markers; on the paper's case ('bbbv') the published values of the same method are drawn beside
them with open markers (paper.py), dashed, or dotted on ``estimators`` where the energy error is
the dashed line. The paper's curves are drawn for every method asked for, so the adaptive
method's targets show even while our adaptive runs fail.
"""
from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from . import paper
from .convergence import ETAS, gmres_ran, newton_rows
from .figure import ENERGY_NORM, QUANTITIES, Writer, new_figure, readable_log, set_title
from .methods import STYLE
from .tables import Outcome

PAPER_LABEL = "paper (Dabaghi, Martin, Vohralík 2020)"


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def by_method(outcomes: list[Outcome]) -> dict[str, list[Outcome]]:
    """The runs with a result, per method, sorted by the number of triangles."""
    groups: dict[str, list[Outcome]] = defaultdict(list)
    for o in outcomes:
        if o.result is not None and _finite(o.result.summary.get("nt")):
            groups[o.run.method].append(o)
    return {m: sorted(g, key=lambda o: o.result.summary["nt"]) for m, g in groups.items()}


def _column(group: list[Outcome], key: str) -> tuple[np.ndarray, np.ndarray]:
    nt = np.array([o.result.summary["nt"] for o in group], dtype=float)
    v = np.array([o.result.summary.get(key, math.nan) for o in group], dtype=float)
    return nt, v


def _ours(ax, method: str, x, y, ms: float = 5) -> None:
    colour, marker = STYLE[method]
    ax.plot(x, y, color=colour, marker=marker, ms=ms, lw=1.5, label=method)


def _theirs(ax, method: str, x, y, ms: float = 5) -> None:
    colour, marker = STYLE[method]
    ax.plot(x, y, color=colour, marker=marker, ms=ms, lw=1.0, ls="--", mfc="none")


def _legend(fig, methods, with_paper: bool) -> None:
    """One legend below the panels: a colour per method, then which style is whose."""
    handles = [Line2D([], [], color=STYLE[m][0], marker=STYLE[m][1], lw=1.5, label=m)
               for m in methods]
    if with_paper:
        handles += [Line2D([], [], color="k", marker="o", lw=1.5, label="this study"),
                    Line2D([], [], color="k", marker="o", mfc="none", lw=1.0, ls="--",
                           label=PAPER_LABEL)]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8,
               frameon=False)


def _per_step_gmres(o: Outcome) -> tuple[np.ndarray, np.ndarray]:
    """(Newton step k >= 1, GMRES iterations spent in step k) from the Newton rows."""
    h = o.result.history
    rows = newton_rows(h)
    k, g = h["newton_it"][rows], h["gmres_it"][rows].astype(float)
    return k[1:], np.diff(g)


def _nearest(group: list[Outcome], nt: float) -> Outcome:
    return min(group, key=lambda o: abs(math.log(o.result.summary["nt"] / nt)))


def _panel_counts(ax, groups, methods, key: str, with_paper: bool, ylabel: str) -> None:
    top = 0.0
    for method in methods:
        ref = paper.curve(key, method) if with_paper else None
        if ref:
            _theirs(ax, method, *ref)
            top = max(top, max(ref[1]))
        if method not in groups:
            continue
        nt, v = _column(groups[method], key)
        if key == "gmres_iterations" and not (v > 0).any():
            continue  # a direct solver: no GMRES to count
        _ours(ax, method, nt, v)
        top = max(top, np.nanmax(v, initial=0.0))
    ax.set_xlabel("number of triangles")
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 1.08 * top if top > 0 else 1.0)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, lw=0.3, alpha=0.6)


def _panel_per_step(ax, groups, methods, with_paper: bool) -> str:
    """GMRES iterations per Newton step on our mesh nearest the paper's 7840 triangles (the
    paper's own steps beside them when that mesh matches); returns what is shown."""
    runs = {m: _nearest(groups[m], paper.PER_STEP_TRIANGLES) for m in methods if m in groups}
    runs = {m: o for m, o in runs.items() if gmres_ran(o.result.history)}
    nt = min((o.result.summary["nt"] for o in runs.values()),
             key=lambda n: abs(math.log(n / paper.PER_STEP_TRIANGLES)), default=None)
    matches = with_paper and nt is not None and paper.mesh_index(nt) == \
        paper.TRIANGLES.index(paper.PER_STEP_TRIANGLES)
    counts = [1.0]
    for method in methods:
        ref = paper.GMRES_PER_STEP.get(method) if matches else None
        if ref:
            _theirs(ax, method, np.arange(1, len(ref) + 1), ref, ms=3)
            counts += list(ref)
        if method in runs:
            k, g = _per_step_gmres(runs[method])
            _ours(ax, method, k, g, ms=3.5)
            counts += list(g)
    if max(counts) >= 10 * max(1.0, min(counts)):  # the exact method's first step: 255 vs 30
        ax.set_yscale("log")
        readable_log(ax, "y")
    else:
        ax.set_ylim(0, 1.08 * max(counts))
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(r"Newton step $k$")
    ax.set_ylabel("GMRES iterations in the step")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="both", lw=0.3, alpha=0.6)
    return "(no GMRES run)" if nt is None else f"per Newton step, {int(nt)} triangles"


def plot_iterations(outcomes, methods, w: Writer, with_paper: bool, second_line: str) -> None:
    """The paper's Fig. 6 for the methods asked for (the paper's curve even where ours failed)."""
    groups = by_method(outcomes)
    fig = new_figure((13.0, 4.6))
    ax_newton, ax_step, ax_gmres = fig.subplots(1, 3)
    _panel_counts(ax_newton, groups, methods, "newton_iterations", with_paper, "Newton steps")
    ax_newton.set_title("Newton steps", fontsize=10)
    ax_step.set_title("GMRES iterations " + _panel_per_step(ax_step, groups, methods, with_paper),
                      fontsize=10)
    _panel_counts(ax_gmres, groups, methods, "gmres_iterations", with_paper,
                  "cumulated GMRES iterations")
    ax_gmres.set_title("cumulated GMRES iterations", fontsize=10)
    _legend(fig, methods, with_paper)
    set_title(fig, "iterations of the methods over the mesh sequence", second_line)
    w.save(fig, "iterations")


def _precision(groups) -> tuple[str, str] | None:
    """The accuracy to plot work against: the energy error, else η, else nothing."""
    for key, label in (("energy_error", f"energy error ${ENERGY_NORM}$"),
                       ("eta_total", r"estimator $\eta$ (energy error unknown)")):
        if any(np.isfinite(_column(g, key)[1]).any() for g in groups.values()):
            return key, label
    return None


def _label_meshes(ax, points: list[tuple[int, float, float]]) -> None:
    """Each mesh's number of triangles once, above its slowest run."""
    slowest: dict[int, tuple[float, float]] = {}
    for n, x, y in points:
        if math.isfinite(x) and math.isfinite(y) and y > slowest.get(n, (0.0, -math.inf))[1]:
            slowest[n] = (x, y)
    for n, (x, y) in slowest.items():
        ax.annotate(f"{n}", (x, y), textcoords="offset points", xytext=(0, 6), ha="center",
                    fontsize=7, color="0.3")


def plot_work_precision(outcomes, w: Writer, second_line: str) -> None:
    groups = by_method(outcomes)
    precision = _precision(groups)
    if precision is None:
        w.note(f"no energy error or estimator in any run: work_precision.{w.fmt} skipped")
        return
    key, xlabel = precision
    fig = new_figure()
    ax = fig.add_subplot()
    points = []
    for method, group in groups.items():
        nt, err = _column(group, key)
        t = _column(group, "wall_time")[1]
        _ours(ax, method, err, t)
        points += [(int(n), e, s) for n, e, s in zip(nt, err, t)]
    _label_meshes(ax, points)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.margins(0.1)
    readable_log(ax, "x")
    readable_log(ax, "y")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("wall time of the run (s)")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=8, loc="best", title="grey labels: triangles", title_fontsize=7)
    set_title(ax, "work against precision", second_line)
    w.save(fig, "work_precision")


def _has_estimators(groups) -> bool:
    return any(np.isfinite(_column(g, "eta_total")[1]).any() for g in groups.values())


def _panel_estimators(ax, group, method: str, with_paper: bool) -> None:
    """η, its components and the error at convergence for one method, log-log."""
    for key in ETAS + ("energy_error",):
        label, colour, marker, ls = QUANTITIES[key]
        if group:
            nt, v = _column(group, key)
            if np.isfinite(v).any():
                ax.loglog(nt, v, color=colour, marker=marker, ls=ls, ms=4, label=label)
        ref = paper.curve(key, method) if with_paper else None
        if ref:
            ax.loglog(*ref, color=colour, marker=marker, ls=":", ms=4, mfc="none")
    ax.set_title(method if group else f"{method} (no result)", fontsize=10)
    readable_log(ax, "x")
    ax.set_xlabel("number of triangles")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)


def plot_estimators(outcomes, methods, w: Writer, with_paper: bool, second_line: str) -> None:
    """The paper's Fig. 3 (one panel per method) and Fig. 7, right (effectivity)."""
    groups = by_method(outcomes)
    if not _has_estimators(groups):
        w.note(f"no estimators in any /summary: estimators.{w.fmt} and effectivity.{w.fmt} "
               f"skipped")
        return
    fig = new_figure((4.2 * len(methods) + 0.6, 4.6))
    axes = fig.subplots(1, len(methods), sharey=True, squeeze=False)[0]
    for ax, method in zip(axes, methods):
        _panel_estimators(ax, groups.get(method), method, with_paper)
    axes[0].set_ylabel("energy-norm error, estimator")
    handles = [Line2D([], [], color=c, marker=m, ls=ls, label=label)
               for label, c, m, ls in (QUANTITIES[k] for k in ETAS + ("energy_error",))]
    if with_paper:
        handles.append(Line2D([], [], color="k", ls=":", marker="o", mfc="none", label=PAPER_LABEL))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8,
               frameon=False)
    set_title(fig, "estimators and energy error at convergence", second_line)
    w.save(fig, "estimators")
    _plot_effectivity(groups, methods, w, with_paper, second_line)


def _plot_effectivity(groups, methods, w: Writer, with_paper: bool, second_line: str) -> None:
    fig = new_figure()
    ax = fig.add_subplot()
    for method in methods:
        ref = paper.curve("effectivity", method) if with_paper else None
        if ref:
            _theirs(ax, method, *ref)
        if method in groups:
            nt, eff = _column(groups[method], "effectivity")
            if np.isfinite(eff).any():
                _ours(ax, method, nt, eff)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    readable_log(ax, "x")
    ax.set_xlabel("number of triangles")
    ax.set_ylabel(rf"effectivity index $\eta/{ENERGY_NORM}$")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=8, loc="best")
    set_title(ax, "effectivity at convergence" + (" (dashed: paper)" if with_paper else ""),
              second_line)
    w.save(fig, "effectivity")
