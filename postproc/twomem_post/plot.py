"""``python -m twomem_post plot RESULT.h5 -o DIR [--format png|pdf]``: every figure of one result.

Each figure is its own file in DIR (6 x 4.5 in at 120 dpi, 9 in wide for side-by-side panels;
small enough to commit); the paths written are printed on stdout, one a line, and a figure
whose data the file lacks is skipped with a one-line note on stderr. The maps (u1, u2,
membranes, lambda, contact, error) are described in :mod:`twomem_post.maps`, the convergence
figures (history_*, estimators_*, effectivity) in :mod:`twomem_post.convergence`, an adaptive
run's (adapt_convergence, adapt_mesh) in :mod:`twomem_post.adapt`.

An unreadable or non-twomem file raises :class:`ResultError`; the command line reports it as
``twomem_post: error: <file>: <why>`` and exits with status 2.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from . import maps
from .adapt import plot_adapt
from .convergence import plot_convergence
from .figure import Writer
from .errors import ResultError
from .result import Result, load, one_line

FORMATS = ("png", "pdf")


def output_writer(outdir, fmt: str, out, err) -> Writer:
    """A Writer into outdir, created if needed; ResultError when it cannot be written to."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r} ({' or '.join(FORMATS)})")
    try:
        Path(outdir).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResultError(outdir, f"cannot create the output directory ({one_line(exc)})") from None
    if not os.access(outdir, os.W_OK):
        raise ResultError(outdir, "output directory is not writable")
    return Writer(outdir, fmt, out, err)


def plot_maps(r: Result, w: Writer) -> None:
    """The maps the file has data for; one note per group skipped."""
    if r.xy is None:
        w.note("no /mesh: maps skipped (u1, u2, membranes, lambda, contact, error)")
        return
    if len(r.triangles) == 0:
        w.note("/mesh has no triangles: maps skipped")
        return
    missing = [n for n, a in (("u1", r.u1), ("u2", r.u2), ("lambda", r.lam)) if a is None]
    if missing:
        w.note(f"no /solution/{', '.join(missing)}: figures of "
               f"{'these fields' if len(missing) > 1 else 'this field'} skipped")
    if r.u1 is not None:
        maps.plot_field(r, r.u1, r"$u_1$", "u1", w)
    if r.u2 is not None:
        maps.plot_field(r, r.u2, r"$u_2$", "u2", w)
    if r.u1 is not None and r.u2 is not None:
        maps.plot_membranes(r, w)
    if r.lam is not None:
        maps.plot_lambda(r, w)
    if r.u1 is not None and r.u2 is not None:
        maps.plot_contact(r, w)
    if r.error is None and r.eta is None:
        w.note(f"no /error/energy (exact solution unknown) nor /estimators/eta_total: "
               f"error.{w.fmt} skipped")
    else:
        maps.plot_error(r, w)


def plot(path, outdir, fmt: str = "png", out=None, err=None) -> list[Path]:
    """Draw every figure the result file has data for into outdir; return the paths written.

    Raises ResultError for an unreadable or non-twomem file and for an unusable outdir.
    """
    r = load(path)
    w = output_writer(outdir, fmt, sys.stdout if out is None else out,
                      sys.stderr if err is None else err)
    plot_maps(r, w)
    plot_convergence(r, w)
    plot_adapt(r, w)
    return w.written


def add_parser(sub) -> None:
    p = sub.add_parser("plot", help="figures of one result file (fields, contact, errors, "
                                    "estimators, convergence)",
                       description="Draw each figure of one result file into DIR and print the "
                                   "paths written.")
    p.add_argument("result", help="twomem result file (HDF5)")
    p.add_argument("-o", "--outdir", required=True, metavar="DIR",
                   help="directory for the figures (created if needed)")
    p.add_argument("--format", choices=FORMATS, default="png", dest="fmt",
                   help="figure file format (default png)")
    p.set_defaults(func=lambda args: (plot(args.result, args.outdir, args.fmt), 0)[1])
