"""Figures of one twomem result file: ``python -m twomem_post plot RESULT.h5 -o DIR``.

Each figure is its own file in DIR (``--format png`` or ``pdf``); the paths written are printed
on stdout, one a line, and a figure whose data the file lacks is skipped with a one-line note on
stderr. Figures (6 x 4.5 in at 120 dpi, small enough to commit):

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
    estimate η_K / |K|^½ and the actual error side by side on one shared colour scale;
    ``estimator`` instead when only the estimate exists.
``history_newton``
    the relative residuals, the energy error and the estimators that are not NaN against the
    Newton step (rows with inner = 0), log scale.
``history_gmres``
    (when GMRES ran) the same against cumulative GMRES iterations over all rows, inner rows
    included, a dotted line where each Newton step ends (the paper's Figs. 3-5).
``effectivity``
    (when the history has both η and the energy error) η / |||u − u_h||| along the iterations.

Contact set: a vertex is in contact when u1 − u2 <= max(λ, tol), tol = 1e-12·max(|u1|, |u2|),
i.e. it is in the active set of the min C-function (the set the run's log counts as "contact"),
or the membranes touch there to round-off with λ = 0. A fixed gap tolerance alone is not
enough: after a GMRES solve to 1e-10 the gap at contact vertices reaches 5e-11·max|u|
(input/paper_p1.nml with newton.linear=gmres: 26 of 504 contact vertices have gaps above
1e-12·max|u|, while the smallest gap off the contact set is 2e-6).
The contact set drawn is the union of the triangles whose three vertices are in contact.

An unreadable or non-twomem file raises :class:`ResultError`; the command line reports it as
``twomem_post: error: <file>: <why>`` and exits with status 2.
"""
from __future__ import annotations

import math
import os
import re
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib import colormaps
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
import matplotlib.tri as mtri

FIGSIZE = (6.0, 4.5)
ERROR_CMAP = colormaps["viridis"].with_extremes(under="0.82")
WIDE_FIGSIZE = (9.0, 4.5)
DPI = 120
#: decades shown at most on the log colour scale of the error maps
LOG_DECADES = 4
#: element values below this fraction of the largest are round-off ("exact on K")
NEGLIGIBLE = 1e-10
#: relative gap tolerance of the contact set (times max |u|)
CONTACT_RTOL = 1e-12

#: history columns drawn on the convergence figures, in drawing order: label, marker
HISTORY_COLUMNS = {
    "lin_residual": (r"$\|R_{\mathrm{lin}}\|/\|F\|$", "o"),
    "alg_residual": (r"$\|B-AX\|/\|B\|$", "s"),
    "energy_error": (r"$|\!|\!|u-u_h|\!|\!|$", "^"),
    "eta_total": (r"$\eta$", "D"),
    "eta_disc": (r"$\eta_{\mathrm{disc}}$", "v"),
    "eta_lin": (r"$\eta_{\mathrm{lin}}$", "<"),
    "eta_alg": (r"$\eta_{\mathrm{alg}}$", ">"),
}


class ResultError(Exception):
    """A result file that cannot be read or is not a twomem result."""

    def __init__(self, path, why: str):
        super().__init__(f"{path}: {why}")
        self.path = str(path)
        self.why = why


@dataclass
class Result:
    """What the figures need from a result file; None where the file lacks it."""
    path: str
    case: str
    status: str
    xy: np.ndarray | None = None
    triangles: np.ndarray | None = None
    u1: np.ndarray | None = None
    u2: np.ndarray | None = None
    lam: np.ndarray | None = None
    error: np.ndarray | None = None
    eta: np.ndarray | None = None
    history: dict[str, np.ndarray] = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------
# reading

def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return _text(value.reshape(())[()])
    return str(value)


def case_name(input_text: str | None, fallback: str) -> str:
    """The case from the input echo's first line ``! twomem input: case 'NAME' ...``."""
    if input_text:
        m = re.search(r"!\s*twomem input:\s*case\s+'([^']*)'", input_text)
        if m and m.group(1):
            return m.group(1)
    return fallback


def _dataset(f: h5py.File, name: str, ndim: int, cols: int | None = None):
    if name not in f:
        return None
    obj = f[name]
    if not isinstance(obj, h5py.Dataset):
        raise ValueError(f"/{name} is not a dataset")
    a = obj[()]
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "fiub" or a.ndim != ndim \
            or (cols is not None and a.shape[1] != cols):
        shape = getattr(a, "shape", "?")
        want = f"(n, {cols})" if cols else "(n)"
        raise ValueError(f"/{name} has shape {shape} and type {getattr(a, 'dtype', type(a))}, "
                         f"expected numbers of shape {want}")
    return a


def load(path) -> Result:
    """Read what the figures need; raise ResultError when the file is not a usable result."""
    path = str(path)
    if not os.path.exists(path):
        raise ResultError(path, "no such file")
    if os.path.isdir(path):
        raise ResultError(path, "is a directory")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ResultError(path, f"not a readable HDF5 file ({_one_line(exc)})") from None
    try:
        with f:
            return _read(f, path)
    except ResultError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError) as exc:
        raise ResultError(path, _one_line(exc)) from None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _read(f: h5py.File, path: str) -> Result:
    groups = [g for g in ("mesh", "solution", "history", "error") if g in f]
    if not groups and "input" not in f.attrs and "version" not in f.attrs:
        raise ResultError(path, "not a twomem result (no /mesh, /solution, /history or "
                                "'input' attribute)")
    input_text = _text(f.attrs["input"]) if "input" in f.attrs else None
    status = _text(f.attrs["status"]) if "status" in f.attrs else "status unknown"
    r = Result(path=path, case=case_name(input_text, Path(path).stem), status=status)

    r.xy = _dataset(f, "mesh/vertices", 2, 2)
    r.triangles = _dataset(f, "mesh/triangles", 2, 3)
    if (r.xy is None) != (r.triangles is None):
        raise ValueError("/mesh has vertices or triangles but not both")
    if r.xy is not None:
        nv = len(r.xy)
        if r.triangles.dtype.kind not in "iu":
            raise ValueError("/mesh/triangles is not an integer array")
        if len(r.triangles) and (r.triangles.min() < 0 or r.triangles.max() >= nv):
            raise ValueError(f"/mesh/triangles refers to vertices outside 0..{nv - 1}")
        r.xy = r.xy.astype(float)
        r.triangles = r.triangles.astype(np.int64)
    for attr, name, size in (("u1", "solution/u1", "nv"), ("u2", "solution/u2", "nv"),
                             ("lam", "solution/lambda", "nv"), ("error", "error/energy", "nt"),
                             ("eta", "estimators/eta_total", "nt")):
        a = _dataset(f, name, 1)
        if a is None:
            continue
        if r.xy is not None:
            n = len(r.xy) if size == "nv" else len(r.triangles)
            if len(a) != n:
                raise ValueError(f"/{name} has {len(a)} values, the mesh has {n} "
                                 f"{'vertices' if size == 'nv' else 'triangles'}")
        setattr(r, attr, a.astype(float))

    if "history" in f:
        rows = None
        for name, obj in f["history"].items():
            if not isinstance(obj, h5py.Dataset):
                continue
            a = _dataset(f, f"history/{name}", 1)
            if rows is not None and len(a) != rows:
                raise ValueError(f"/history/{name} has {len(a)} rows, other columns {rows}")
            rows = len(a)
            r.history[name] = a
    return r


# ----------------------------------------------------------------------------------------------
# geometry and contact set

def triangulation(r: Result) -> mtri.Triangulation:
    return mtri.Triangulation(r.xy[:, 0], r.xy[:, 1], r.triangles)


def triangle_areas(xy: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p0, p1, p2 = (xy[triangles[:, i]] for i in range(3))
    d1, d2 = p1 - p0, p2 - p0
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def contact_vertices(u1: np.ndarray, u2: np.ndarray, lam: np.ndarray | None) -> np.ndarray:
    """Vertices in contact: u1 − u2 <= max(λ, tol), tol = 1e-12·max|u| (see the module doc)."""
    scale = max(float(np.nanmax(np.abs(u1), initial=0.0)), float(np.nanmax(np.abs(u2), initial=0.0)))
    bound = np.full(u1.shape, CONTACT_RTOL * scale)
    if lam is not None:
        bound = np.fmax(bound, lam)
    with np.errstate(invalid="ignore"):
        return (u1 - u2) <= bound


def contact_triangles(triangles: np.ndarray, vertex_in_contact: np.ndarray) -> np.ndarray:
    return vertex_in_contact[triangles].all(axis=1)


def region_outline(triangles: np.ndarray, selected: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Segments (n, 2, 2) bounding the union of the selected triangles (edges used once)."""
    t = triangles[selected]
    if len(t) == 0:
        return np.zeros((0, 2, 2))
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[count == 1]
    return xy[boundary]


# ----------------------------------------------------------------------------------------------
# figure helpers

def _figure(size=FIGSIZE) -> Figure:
    fig = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)  # Agg, never a display
    return fig


def _subtitle(r: Result) -> str:
    status = textwrap.shorten(r.status, width=70, placeholder="...")
    return f"case '{r.case}', {status}"


def _title(fig_or_ax, r: Result, what: str) -> None:
    text = f"{what}\n{_subtitle(r)}"
    if isinstance(fig_or_ax, Figure):
        fig_or_ax.suptitle(text, fontsize=10)
    else:
        fig_or_ax.set_title(text, fontsize=10)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


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


class Writer:
    """Saves figures into one directory, reports paths and notes."""

    def __init__(self, outdir, fmt: str, out, err):
        self.outdir = Path(outdir)
        self.fmt = fmt
        self.out, self.err = out, err
        self.written: list[Path] = []

    def save(self, fig: Figure, name: str) -> None:
        path = self.outdir / f"{name}.{self.fmt}"
        fig.savefig(path, format=self.fmt, dpi=DPI)
        self.written.append(path)
        print(path, file=self.out)

    def note(self, text: str) -> None:
        print(f"twomem_post: note: {text}", file=self.err)


# ----------------------------------------------------------------------------------------------
# the figures

def plot_field(r: Result, z: np.ndarray, symbol: str, name: str, w: Writer, cmap="viridis") -> None:
    fig = _figure()
    ax = fig.add_subplot()
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        w.note(f"{name} has no finite values: {name}.{w.fmt} skipped")
        return
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
    fig = _figure()
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
    fig = _figure()
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
    fig = _figure()
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


def plot_error(r: Result, w: Writer) -> None:
    """Element error (and estimate) densities, value_K / |K|^½, on a log colour scale."""
    area = triangle_areas(r.xy, r.triangles)
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.where(area > 0, np.sqrt(area), np.nan)
        panels = []
        if r.eta is not None:
            panels.append((r.eta / sq, r"estimate $\eta_K/|K|^{1/2}$"))
        if r.error is not None:
            panels.append((r.error / sq, (r"actual " if r.eta is not None else "")
                           + r"$|\!|\!|u-u_h|\!|\!|_K/|K|^{1/2}$"))
    both = len(panels) == 2
    norm, clipped = _log_norm(*(p[0] for p in panels))
    fig = _figure(WIDE_FIGSIZE if both else FIGSIZE)
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
    if both:
        what = r"estimated and actual energy error per element (shared scale)"
    elif r.error is not None:
        what = r"energy error per element, $|\!|\!|u-u_h|\!|\!|_K/|K|^{1/2}$"
    else:
        what = r"estimated error per element, $\eta_K/|K|^{1/2}$"
    totals = []
    if r.eta is not None:
        totals.append(rf"$\eta$ = {_fmt(math.sqrt(np.nansum(r.eta ** 2)))}")
    if r.error is not None:
        totals.append(rf"$|\!|\!|u-u_h|\!|\!|$ = {_fmt(math.sqrt(np.nansum(r.error ** 2)))}")
    what += "\n" + ", ".join(totals)
    _title(fig if both else axes[0], r, what)
    w.save(fig, "error" if r.error is not None else "estimator")


def _positive(a: np.ndarray) -> np.ndarray:
    a = a.astype(float)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


def _history_series(h: dict[str, np.ndarray], rows: np.ndarray):
    """(column, label, marker, values) for the columns present with a positive finite value."""
    for col, (label, marker) in HISTORY_COLUMNS.items():
        if col in h:
            v = _positive(h[col][rows])
            if np.isfinite(v).any():
                yield col, label, marker, v


def _inner(h: dict[str, np.ndarray]) -> np.ndarray:
    n = len(h["newton_it"])
    return h["inner"].astype(int) if "inner" in h else np.zeros(n, dtype=int)


def plot_history_newton(r: Result, w: Writer) -> None:
    h = r.history
    rows = np.flatnonzero(_inner(h) == 0)
    series = list(_history_series(h, rows))
    if not series:
        w.note(f"no positive residuals or errors in /history: history_newton.{w.fmt} skipped")
        return
    k = h["newton_it"][rows]
    fig = _figure()
    ax = fig.add_subplot()
    for col, label, marker, v in series:
        ax.semilogy(k, v, marker=marker, ms=4, lw=1.2, label=label)
    ax.set_xlabel(r"Newton step $k$")
    ax.set_ylabel("relative residual, error, estimator")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="major", lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="best")
    _title(ax, r, "convergence of the Newton iteration")
    w.save(fig, "history_newton")


def _newton_lines(ax, h: dict[str, np.ndarray]) -> None:
    """Dotted vertical lines where Newton steps k >= 1 end (cumulative GMRES iterations)."""
    ends = np.flatnonzero((_inner(h) == 0) & (h["newton_it"] > 0))
    for n, i in enumerate(ends):
        ax.axvline(h["gmres_it"][i], color="0.45", ls=":", lw=0.8,
                   label="end of a Newton step" if n == 0 else None)


def plot_history_gmres(r: Result, w: Writer) -> None:
    h = r.history
    rows = np.arange(len(h["gmres_it"]))
    series = list(_history_series(h, rows))
    if not series:
        w.note(f"no positive residuals or errors in /history: history_gmres.{w.fmt} skipped")
        return
    x = h["gmres_it"]
    fig = _figure()
    ax = fig.add_subplot()
    for col, label, marker, v in series:
        ax.semilogy(x, v, marker=marker, ms=3.5, lw=1.1, label=label)
    _newton_lines(ax, h)
    ax.set_xlabel("cumulative GMRES iterations")
    ax.set_ylabel("relative residual, error, estimator")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    ax.grid(True, which="major", axis="y", lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="best")
    _title(ax, r, "convergence along the GMRES iterations")
    w.save(fig, "history_gmres")


def plot_effectivity(r: Result, w: Writer) -> bool:
    h = r.history
    gmres = "gmres_it" in h and bool((h["gmres_it"] > 0).any())
    rows = np.arange(len(h["newton_it"])) if gmres else np.flatnonzero(_inner(h) == 0)
    eta, err = h["eta_total"][rows].astype(float), h["energy_error"][rows].astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        eff = np.where(np.isfinite(eta) & np.isfinite(err) & (err > 0), eta / err, np.nan)
    if not np.isfinite(eff).any():
        return False
    fig = _figure()
    ax = fig.add_subplot()
    x = h["gmres_it"][rows] if gmres else h["newton_it"][rows]
    ax.plot(x, eff, marker="o", ms=4, lw=1.2, color="tab:purple",
            label=r"$\eta/|\!|\!|u-u_h|\!|\!|$")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="exact estimate")
    if gmres:
        _newton_lines(ax, h)
    ax.set_xlabel("cumulative GMRES iterations" if gmres else r"Newton step $k$")
    ax.set_ylabel(r"effectivity index $\eta/|\!|\!|u-u_h|\!|\!|$")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    finite = eff[np.isfinite(eff)]
    if finite.max() > 20 * finite.min():  # early iterates far off: a log scale keeps 1 readable
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0)
    ax.grid(True, lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="best")
    _title(ax, r, "effectivity of the estimator")
    w.save(fig, "effectivity")
    return True


# ----------------------------------------------------------------------------------------------
# driver

def plot(path, outdir, fmt: str = "png", out=None, err=None) -> list[Path]:
    """Draw every figure the result file has data for into outdir; return the paths written.

    Raises ResultError for an unreadable or non-twomem file and for an unusable outdir.
    """
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    if fmt not in ("png", "pdf"):
        raise ValueError(f"unknown format {fmt!r} (png or pdf)")
    r = load(path)
    try:
        Path(outdir).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResultError(outdir, f"cannot create the output directory ({_one_line(exc)})") from None
    if not os.access(outdir, os.W_OK):
        raise ResultError(outdir, "output directory is not writable")
    w = Writer(outdir, fmt, out, err)

    if r.xy is None:
        w.note("no /mesh: maps skipped (u1, u2, membranes, lambda, contact, error)")
    elif len(r.triangles) == 0:
        w.note("/mesh has no triangles: maps skipped")
    else:
        missing = [n for n, a in (("u1", r.u1), ("u2", r.u2), ("lambda", r.lam)) if a is None]
        if missing:
            w.note(f"no /solution/{', '.join(missing)}: figures of "
                   f"{'these fields' if len(missing) > 1 else 'this field'} skipped")
        if r.u1 is not None:
            plot_field(r, r.u1, r"$u_1$", "u1", w)
        if r.u2 is not None:
            plot_field(r, r.u2, r"$u_2$", "u2", w)
        if r.u1 is not None and r.u2 is not None:
            plot_membranes(r, w)
        if r.lam is not None:
            plot_lambda(r, w)
        if r.u1 is not None and r.u2 is not None:
            plot_contact(r, w)
        if r.error is None and r.eta is None:
            w.note(f"no /error/energy (exact solution unknown): error.{w.fmt} skipped")
        else:
            plot_error(r, w)

    h = r.history
    if not h:
        w.note("no /history: convergence figures skipped")
    elif "newton_it" not in h:
        w.note("no /history/newton_it: convergence figures skipped")
    else:
        plot_history_newton(r, w)
        if "gmres_it" in h and (h["gmres_it"] > 0).any():
            plot_history_gmres(r, w)
        if "eta_total" in h and "energy_error" in h:
            if not plot_effectivity(r, w):
                w.note(f"eta_total or energy_error all NaN: effectivity.{w.fmt} skipped")
    return w.written


def add_parser(sub) -> None:
    p = sub.add_parser("plot", help="figures of one result file (fields, contact, error, history)",
                       description="Draw each figure of one result file into DIR and print the "
                                   "paths written.")
    p.add_argument("result", help="twomem result file (HDF5)")
    p.add_argument("-o", "--outdir", required=True, metavar="DIR",
                   help="directory for the figures (created if needed)")
    p.add_argument("--format", choices=("png", "pdf"), default="png", dest="fmt")
    p.set_defaults(func=lambda args: (plot(args.result, args.outdir, args.fmt), 0)[1])
