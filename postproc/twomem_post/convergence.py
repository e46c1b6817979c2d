"""Convergence figures of one result, from its /history rows.

``history_newton``, ``history_gmres``
    the solver's own stopping quantities, the relative linearization and algebraic residuals,
    against the Newton step (rows with inner = 0) and against cumulative GMRES iterations (all
    rows, when GMRES ran).
``estimators_newton``, ``estimators_gmres``
    η_total, η_disc, η_lin, η_alg and the energy error, the same two ways: the paper's Fig. 5
    (estimators along the Newton steps) and Fig. 4 (along the algebraic iterations, here all
    steps one after the other). Residuals and estimators are apart because they are different
    quantities (relative residuals of the algebraic system; energy-norm errors) that a shared
    axis would suggest comparing. Without estimators (all NaN) these figures show the energy
    error alone and say so.
``effectivity``
    η_total / energy error along the Newton steps (the paper's Fig. 7, left), when both exist.

Dotted vertical lines on the GMRES axis mark where Newton steps end, up to 40 steps; beyond
that they would only grey the plot. Markers are drawn up to 80 rows for the same reason.
"""
from __future__ import annotations

import numpy as np
from matplotlib.ticker import MaxNLocator

from .figure import (ENERGY_NORM, QUANTITIES, Writer, new_figure, readable_log, set_title,
                     subtitle)
from .result import Result

RESIDUALS = ("lin_residual", "alg_residual")
ETAS = ("eta_total", "eta_disc", "eta_lin", "eta_alg")
ERRORS = ETAS + ("energy_error",)
MAX_NEWTON_LINES = 40
MAX_MARKED_ROWS = 80


def newton_rows(h: dict[str, np.ndarray]) -> np.ndarray:
    """Rows recorded at completed Newton steps (inner = 0; all rows in files without it)."""
    if "inner" not in h:
        return np.arange(len(h["newton_it"]))
    return np.flatnonzero(h["inner"] == 0)


def gmres_ran(h: dict[str, np.ndarray]) -> bool:
    return "gmres_it" in h and bool((h["gmres_it"] > 0).any())


def _positive(a: np.ndarray) -> np.ndarray:
    a = a.astype(float)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


def series(h: dict[str, np.ndarray], columns, rows) -> list[tuple[str, np.ndarray]]:
    """(column, values) of the columns present with at least one positive finite value."""
    out = []
    for col in columns:
        if col in h:
            v = _positive(h[col][rows])
            if np.isfinite(v).any():
                out.append((col, v))
    return out


def _draw(ax, x: np.ndarray, lines: list[tuple[str, np.ndarray]]) -> None:
    marked = len(x) <= MAX_MARKED_ROWS
    for col, v in lines:
        label, colour, marker, ls = QUANTITIES[col]
        ok = np.isfinite(v)  # a gap (NaN in row 0's alg_residual) must not break the line
        ax.semilogy(x[ok], v[ok], color=colour, marker=marker if marked else None, ms=3.5,
                    lw=1.2, ls=ls, label=label)


def _newton_lines(ax, h: dict[str, np.ndarray]) -> None:
    """Dotted vertical lines where Newton steps k >= 1 end (cumulative GMRES iterations)."""
    ends = [i for i in newton_rows(h) if h["newton_it"][i] > 0]
    if len(ends) > MAX_NEWTON_LINES:
        return
    for n, i in enumerate(ends):
        ax.axvline(h["gmres_it"][i], color="0.45", ls=":", lw=0.8,
                   label="end of a Newton step" if n == 0 else None)


def _finish(ax, r: Result, along: str, ylabel: str, what: str) -> None:
    if along == "newton":
        ax.set_xlabel(r"Newton step $k$")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    else:
        _newton_lines(ax, r.history)
        ax.set_xlabel("cumulative GMRES iterations")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    readable_log(ax, "y")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="major", lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="best")
    set_title(ax, what, subtitle(r.case, r.status))


def _figure(r: Result, w: Writer, name: str, columns, along: str, ylabel: str, what: str):
    """One log-scale figure of the columns along Newton steps or GMRES iterations."""
    h = r.history
    rows = newton_rows(h) if along == "newton" else np.arange(len(h["newton_it"]))
    lines = series(h, columns, rows)
    if not lines:
        w.note(f"no positive {' or '.join(columns)} in /history: {name}.{w.fmt} skipped")
        return
    x = h["newton_it" if along == "newton" else "gmres_it"][rows]
    fig = new_figure()
    ax = fig.add_subplot()
    _draw(ax, x, lines)
    _finish(ax, r, along, ylabel, what)
    w.save(fig, name)


def plot_residuals(r: Result, w: Writer, along: str) -> None:
    where = "the Newton steps" if along == "newton" else "the GMRES iterations"
    _figure(r, w, f"history_{along}", RESIDUALS, along, "relative residual",
            f"linearization and algebraic residuals along {where}")


def plot_estimators(r: Result, w: Writer, along: str, with_eta: bool) -> None:
    where = "the Newton steps" if along == "newton" else "the GMRES iterations"
    what = "estimators and energy error" if with_eta else "energy error (no estimators)"
    _figure(r, w, f"estimators_{along}", ERRORS, along,
            "energy-norm error, estimator" if with_eta else "energy-norm error",
            f"{what} along {where}")


def effectivity(h: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(Newton step, η / energy error) at the Newton rows; NaN where either is unknown."""
    rows = newton_rows(h)
    eta, err = h["eta_total"][rows].astype(float), h["energy_error"][rows].astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        eff = np.where(np.isfinite(eta) & np.isfinite(err) & (err > 0), eta / err, np.nan)
    return h["newton_it"][rows], eff


def plot_effectivity(r: Result, w: Writer) -> None:
    k, eff = effectivity(r.history)
    fig = new_figure()
    ax = fig.add_subplot()
    ax.plot(k, eff, marker="o" if len(k) <= MAX_MARKED_ROWS else None, ms=4, lw=1.2,
            color="tab:purple", label=rf"$\eta/{ENERGY_NORM}$")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="exact estimate")
    ax.set_xlabel(r"Newton step $k$")
    ax.set_ylabel(rf"effectivity index $\eta/{ENERGY_NORM}$")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    finite = eff[np.isfinite(eff)]
    if finite.max() > 20 * finite.min():  # early iterates far off: a log scale keeps 1 readable
        ax.set_yscale("log")
        readable_log(ax, "y")
    else:
        ax.set_ylim(bottom=0)
    ax.grid(True, which="both", lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="best")
    last = f"{eff[-1]:.3f} at the last step" if np.isfinite(eff[-1]) else "last step unknown"
    set_title(ax, f"effectivity of the estimator ({last})", subtitle(r.case, r.status))
    w.save(fig, "effectivity")


def plot_convergence(r: Result, w: Writer) -> None:
    """Every convergence figure the history has data for; one note per figure skipped."""
    h = r.history
    if not h or "newton_it" not in h:
        w.note(f"no /history{'' if not h else '/newton_it'}: convergence figures skipped")
        return
    along = ("newton", "gmres") if gmres_ran(h) else ("newton",)
    if len(along) == 1:
        w.note(f"no GMRES iterations in /history: history_gmres.{w.fmt} and "
               f"estimators_gmres.{w.fmt} skipped")
    for a in along:
        plot_residuals(r, w, a)
    all_rows = np.arange(len(h["newton_it"]))
    with_eta = bool(series(h, ETAS, all_rows))
    if with_eta or series(h, ["energy_error"], all_rows):
        if not with_eta:
            w.note("no estimators in /history (absent or NaN): estimator figures show the "
                   "energy error only")
        for a in along:
            plot_estimators(r, w, a, with_eta)
    else:
        w.note(f"no estimators or energy error in /history: estimators_*.{w.fmt} skipped")
    if "eta_total" in h and "energy_error" in h and np.isfinite(effectivity(h)[1]).any():
        plot_effectivity(r, w)
    else:
        w.note(f"eta_total or energy_error unknown in /history: effectivity.{w.fmt} skipped")
