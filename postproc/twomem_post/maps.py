"""Maps of one result on its mesh: u1, u2, the membranes along a cut, λ, the contact set and
the element errors.

``u1``, ``u2``
    filled contour maps of the membranes on the finest mesh.
``membranes``
    u1 and u2 along the cut y = 0 (the mid-height of the mesh when y = 0 misses it), the contact
    set shaded: the classic picture of the two membranes touching.
``lambda``
    the action-reaction force λ as a filled map, the contact set outlined (a diverging colour
    map centred at 0 when λ has negative values, as a non-converged iterate may).
``contact``
    the gap u1 − u2 as a filled map, the contact set filled grey.
``error``
    (with /error/energy) the element energy error as a density, |||u − u_h|||_K / |K|^½ (the
    root-mean-square energy-gradient error on K, independent of the element size, so graded and
    uniform meshes read alike), on a log colour scale of at most 4 decades that starts at the
    smallest value above round-off; elements below it (u_h exact on K up to round-off, e.g. in
    the contact set of the 'radial' case) are light grey. With /estimators/eta_total as well, the
    estimate η_K / |K|^½ and the actual error side by side on one shared colour scale, so the
    two distributions compare colour for colour (the paper's Fig. 8); ``estimator`` instead when
    only the estimate exists.

The contact set is :mod:`twomem_post.geometry`'s.
"""
from __future__ import annotations

import math

import numpy as np
from matplotlib import colormaps
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
import matplotlib.tri as mtri

from .figure import ENERGY_NORM, FIGSIZE, WIDE_FIGSIZE, Writer, fmt as _fmt, new_figure, set_title, subtitle
from .geometry import contact_triangles, contact_vertices, region_outline, triangle_areas
from .result import Result

ERROR_CMAP = colormaps["viridis"].with_extremes(under="0.82")
#: decades shown at most on the log colour scale of the error maps
LOG_DECADES = 4
#: element values below this fraction of the largest are round-off ("exact on K")
NEGLIGIBLE = 1e-10


def _title(target, r: Result, what: str) -> None:
    set_title(target, what, subtitle(r.case, r.status))


def triangulation(r: Result) -> mtri.Triangulation:
    return mtri.Triangulation(r.xy[:, 0], r.xy[:, 1], r.triangles)


def _field_levels(z: np.ndarray, n: int = 20) -> np.ndarray:
    """n equal bands from the smallest to the largest finite value of z."""
    lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
    if not hi > lo:  # constant field: one band around the value
        pad = max(abs(lo) * 1e-3, 1e-12)
        return np.array([lo - pad, hi + pad])
    # round-off across zero (lambda = -7e-16 beside 0.1) would start the scale below zero
    if lo < 0.0 < hi and -lo <= 1e-9 * hi:
        lo = 0.0
    elif hi > 0.0 > lo and hi <= 1e-9 * -lo:
        hi = 0.0
    return np.linspace(lo, hi, n + 1)


def _contourf(fig, ax, r: Result, z: np.ndarray, levels: np.ndarray, cmap: str, label: str):
    """tricontourf of z (clipped into the level range) with a colour bar ticked at round values."""
    cs = ax.tricontourf(_masked_triangulation(r, z), np.clip(z, levels[0], levels[-1]),
                        levels=levels, cmap=cmap)
    cbar = fig.colorbar(cs, ax=ax, label=label, shrink=0.9)
    if len(levels) > 2:
        cbar.locator = MaxNLocator(nbins=8)
        cbar.update_ticks()
    return cs


def _masked_triangulation(r: Result, z: np.ndarray) -> mtri.Triangulation:
    tri = triangulation(r)
    bad = ~np.isfinite(z)
    if bad.any():
        tri.set_mask(bad[r.triangles].any(axis=1))
    return tri


def _map_axes(ax, r: Result) -> None:
    ax.set_xlim(r.xy[:, 0].min(), r.xy[:, 0].max())
    ax.set_ylim(r.xy[:, 1].min(), r.xy[:, 1].max())
    ax.set_aspect("equal")
    ax.xaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.set_xlabel(r"$x$")
    ax.set_ylabel(r"$y$")



def plot_field(r: Result, z: np.ndarray, symbol: str, name: str, w: Writer, cmap="viridis") -> None:
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        w.note(f"{name} has no finite values: {name}.{w.fmt} skipped")
        return
    fig = new_figure()
    ax = fig.add_subplot()
    _contourf(fig, ax, r, z, _field_levels(finite), cmap, symbol)
    _map_axes(ax, r)
    _title(ax, r, f"{symbol}: min {_fmt(finite.min())}, max {_fmt(finite.max())}")
    w.save(fig, name)


def plot_membranes(r: Result, w: Writer) -> None:
    tri = triangulation(r)
    ymin, ymax = r.xy[:, 1].min(), r.xy[:, 1].max()
    ycut = 0.0 if ymin <= 0.0 <= ymax else 0.5 * (ymin + ymax)
    x = np.linspace(r.xy[:, 0].min(), r.xy[:, 0].max(), 801)
    y = np.full_like(x, ycut)
    v1 = mtri.LinearTriInterpolator(tri, r.u1)(x, y)
    v2 = mtri.LinearTriInterpolator(tri, r.u2)(x, y)
    inside = ~(np.ma.getmaskarray(v1) | np.ma.getmaskarray(v2))
    if not inside.any():
        w.note(f"the cut y = {ycut:g} misses the mesh: membranes.{w.fmt} skipped")
        return
    v1, v2 = np.ma.filled(v1, np.nan), np.ma.filled(v2, np.nan)
    fig = new_figure()
    ax = fig.add_subplot()
    ax.fill_between(x, v2, v1, where=inside, color="0.85", lw=0, label="gap")
    ax.plot(x, v1, color="tab:blue", lw=1.8, label=r"$u_1$ (upper membrane)")
    ax.plot(x, v2, color="tab:orange", lw=1.8, ls="--", label=r"$u_2$ (lower membrane)")
    if r.lam is not None:
        # in the contact set where the interpolated vertex indicator is 1: inside a contact
        # triangle or on an edge of one (a cut along mesh edges sees both neighbours alike)
        indicator = contact_vertices(r.u1, r.u2, r.lam).astype(float)
        c = np.ma.filled(mtri.LinearTriInterpolator(tri, indicator)(x, y), 0.0)
        on = c >= 1.0 - 1e-9
        for n, (a, b) in enumerate(_runs(on)):
            ax.axvspan(x[a], x[b], color="tab:red", alpha=0.12, lw=0,
                       label="contact set" if n == 0 else None)
    ax.set_xlabel(rf"$x$ (cut $y = {ycut:g}$)")
    ax.set_ylabel(r"$u_1,\ u_2$")
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, lw=0.3, alpha=0.5)
    _title(ax, r, f"the two membranes along $y = {ycut:g}$")
    w.save(fig, "membranes")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True values."""
    m = np.concatenate([[False], mask, [False]]).astype(int)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return list(zip(starts, ends))


def plot_lambda(r: Result, w: Writer) -> None:
    lam = r.lam
    finite = lam[np.isfinite(lam)]
    if finite.size == 0:
        w.note(f"lambda has no finite values: lambda.{w.fmt} skipped")
        return
    fig = new_figure()
    ax = fig.add_subplot()
    levels, cmap = _field_levels(finite), "YlOrRd"
    if levels[0] < 0.0 < levels[-1]:  # a non-converged iterate: the sign matters, zero is white
        m = max(-levels[0], levels[-1])
        levels, cmap = np.linspace(-m, m, 21), "RdBu_r"
    _contourf(fig, ax, r, lam, levels, cmap, r"$\lambda$")
    _map_axes(ax, r)
    what = rf"$\lambda$: min {_fmt(finite.min())}, max {_fmt(finite.max())}"
    if r.u1 is not None and r.u2 is not None:
        cv = contact_vertices(r.u1, r.u2, lam)
        seg = region_outline(r.triangles, contact_triangles(r.triangles, cv), r.xy)
        ax.add_collection(LineCollection(seg, colors="k", linewidths=0.9))
        fig.legend(handles=[Line2D([], [], color="k", lw=0.9,
                                   label=f"boundary of the contact set ({int(cv.sum())} vertices)")],
                   fontsize=8, loc="outside lower center", frameon=False)
    else:
        w.note(f"no /solution/u1 or u2: contact set not drawn on lambda.{w.fmt}")
    _title(ax, r, what)
    w.save(fig, "lambda")


def plot_contact(r: Result, w: Writer) -> None:
    gap = r.u1 - r.u2
    finite = gap[np.isfinite(gap)]
    if finite.size == 0:
        w.note(f"u1 - u2 has no finite values: contact.{w.fmt} skipped")
        return
    cv = contact_vertices(r.u1, r.u2, r.lam)
    ct = contact_triangles(r.triangles, cv)
    fig = new_figure()
    ax = fig.add_subplot()
    _contourf(fig, ax, r, gap, _field_levels(finite), "viridis", r"$u_1 - u_2$")
    if ct.any():
        ctri = triangulation(r)
        ctri.set_mask(~ct)
        ax.tripcolor(ctri, np.zeros(len(r.triangles)), cmap="Greys", vmin=-1, vmax=1,
                     shading="flat", edgecolors="none")
    fig.legend(handles=[Patch(color="0.5", label=f"contact set ({int(cv.sum())} vertices, "
                                                  f"{int(ct.sum())} triangles)")],
               fontsize=8, loc="outside lower center", frameon=False)
    _map_axes(ax, r)
    _title(ax, r, r"gap $u_1 - u_2$ and contact set")
    w.save(fig, "contact")


def _log_norm(*arrays: np.ndarray) -> tuple[LogNorm, bool]:
    """One LogNorm for all arrays, from the smallest value that is not round-off (at most
    LOG_DECADES decades below the largest) to the largest; says whether values lie below."""
    pos = np.concatenate([a[np.isfinite(a) & (a > 0)] for a in arrays])
    if pos.size == 0:
        return LogNorm(1e-16, 1.0), True
    vmax = float(pos.max())
    vmin = max(float(pos[pos > NEGLIGIBLE * vmax].min()), vmax * 10.0 ** -LOG_DECADES)
    if not vmax > vmin:
        vmin, vmax = vmax / 10, vmax * 10
    clipped = any(bool((np.isfinite(a) & (a < vmin)).any()) for a in arrays)
    return LogNorm(vmin, vmax), clipped


def _error_panels(r: Result) -> list[tuple[np.ndarray, str]]:
    """(density value_K / |K|^½, label) of the estimate and of the actual error, as present."""
    area = triangle_areas(r.xy, r.triangles)
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.where(area > 0, np.sqrt(area), np.nan)
        panels = []
        if r.eta is not None:
            panels.append((r.eta / sq, r"estimate $\eta_K/|K|^{1/2}$"))
        if r.error is not None:
            panels.append((r.error / sq, ("actual " if r.eta is not None else "")
                           + rf"${ENERGY_NORM}_K/|K|^{{1/2}}$"))
    return panels


def _error_title(r: Result, both: bool) -> str:
    if both:
        what = "estimated and actual energy error per element (shared scale)"
    elif r.error is not None:
        what = rf"energy error per element, ${ENERGY_NORM}_K/|K|^{{1/2}}$"
    else:
        what = r"estimated error per element, $\eta_K/|K|^{1/2}$"
    totals = []
    if r.eta is not None:
        totals.append(rf"$\eta$ = {_fmt(math.sqrt(np.nansum(r.eta ** 2)))}")
    if r.error is not None:
        totals.append(rf"${ENERGY_NORM}$ = {_fmt(math.sqrt(np.nansum(r.error ** 2)))}")
    return what + "\n" + ", ".join(totals)


def plot_error(r: Result, w: Writer) -> None:
    """Element error (and estimate) densities, value_K / |K|^½, on one log colour scale."""
    panels = _error_panels(r)
    both = len(panels) == 2
    norm, clipped = _log_norm(*(p[0] for p in panels))
    fig = new_figure(WIDE_FIGSIZE if both else FIGSIZE)
    axes = fig.subplots(1, len(panels), sharex=True, sharey=True, squeeze=False)[0]
    for ax, (values, label) in zip(axes, panels):
        # values below the scale (round-off, exact on K) get the grey "under" colour; NaN: a hole
        finite = np.isfinite(values)
        tri = triangulation(r)
        if not finite.all():
            tri.set_mask(~finite)
        shown = np.where(finite & (values >= norm.vmin), values, 0.5 * norm.vmin)
        pc = ax.tripcolor(tri, shown, norm=norm, cmap=ERROR_CMAP, shading="flat",
                          edgecolors="none")
        _map_axes(ax, r)
        if both:
            ax.set_title(label, fontsize=10)
    if both:
        axes[1].set_ylabel("")
    cbar = fig.colorbar(pc, ax=list(axes), shrink=0.9, extend="min" if clipped else "neither")
    cbar.set_label(r"element value $/\ |K|^{1/2}$" if both else panels[0][1])
    _title(fig if both else axes[0], r, _error_title(r, both))
    w.save(fig, "error" if r.error is not None else "estimator")
