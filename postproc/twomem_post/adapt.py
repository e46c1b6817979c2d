"""The figures of an adaptive run (``/adapt``, docs/output.md): the estimate η, its parts and the
exact error where known, against the number of vertices N on log-log axes with the reference
slopes N^(-1/2) (the optimal rate of P1 elements in two dimensions, what adaptive refinement
should reach) and N^(-1/3); and the final mesh, whose grading shows where the estimators
asked for refinement."""
from __future__ import annotations

import numpy as np

from .figure import QUANTITIES, new_figure, set_title, subtitle
from .result import Result

#: `/adapt` datasets drawn against `vertices`, in the legend's order
CURVES = ("eta", "eta_disc", "energy_error")


def slope(n: np.ndarray, values: np.ndarray) -> float:
    """Least-squares slope of log(values) against log(n) over the second half of the points
    (the asymptotic rate, without the first steps' pre-asymptotic ones)."""
    keep = np.isfinite(values) & (values > 0)
    n, values = n[keep], values[keep]
    half = n[len(n) // 2:], values[len(values) // 2:]
    if len(half[0]) < 2:
        return float("nan")
    return float(np.polyfit(np.log(half[0]), np.log(half[1]), 1)[0])


def plot_adapt_convergence(r: Result, w) -> None:
    a = r.adapt
    n = a["vertices"].astype(float)
    fig = new_figure()
    ax = fig.add_subplot()
    for name in CURVES:
        if name not in a or not np.any(np.isfinite(a[name])):
            continue
        key = "eta_total" if name == "eta" else name
        label, colour, marker, style = QUANTITIES[key]
        rate = slope(n, a[name])
        ax.loglog(n, a[name], style, color=colour, marker=marker, ms=4,
                  label=f"{label} (slope {rate:.2f})" if np.isfinite(rate) else label)
    # reference slopes through the first estimate
    ref = a["eta"][0]
    for power, style in ((-0.5, ":"), (-1 / 3, "-.")):
        ax.loglog(n, ref * (n / n[0]) ** power, style, color="0.5", lw=1,
                  label=rf"$N^{{{'-1/2' if power == -0.5 else '-1/3'}}}$")
    ax.set_xlabel("vertices N")
    ax.set_ylabel("estimate, error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    set_title(ax, f"adaptive refinement: {len(n)} steps", subtitle(r.case, r.status))
    w.save(fig, "adapt_convergence")


def plot_adapt_mesh(r: Result, w) -> None:
    fig = new_figure()
    ax = fig.add_subplot()
    ax.triplot(r.xy[:, 0], r.xy[:, 1], r.triangles, lw=0.2, color="k")
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    set_title(ax, f"final adapted mesh: {len(r.xy)} vertices, {len(r.triangles)} triangles",
              subtitle(r.case, r.status))
    w.save(fig, "adapt_mesh")


def plot_adapt(r: Result, w) -> None:
    """Both figures when the file has ``/adapt`` (the mesh one when it has ``/mesh`` too)."""
    if not r.adapt:
        return
    plot_adapt_convergence(r, w)
    if r.xy is not None and len(r.triangles):
        plot_adapt_mesh(r, w)
