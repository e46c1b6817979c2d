"""What every figure shares: size, titles, how each quantity is drawn, and saving.

Figures are made with the Agg canvas directly (never pyplot), so plotting works without a
display and leaves no global state behind. A quantity keeps its label, colour and marker on
every figure (η_lin is the same orange curve on the Newton, GMRES and study figures), and a
residual takes the colour of its estimator (linearization orange, algebraic green), so figures
read side by side.
"""
from __future__ import annotations

import textwrap
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

FIGSIZE = (6.0, 4.5)
WIDE_FIGSIZE = (9.0, 4.5)
DPI = 120

ENERGY_NORM = r"|\!|\!|u-u_h|\!|\!|"
#: history columns as drawn on the convergence figures: label, colour, marker, line style
QUANTITIES = {
    "lin_residual": (r"$\|R_{\mathrm{lin}}\|/\|F\|$", "tab:orange", "o", "-"),
    "alg_residual": (r"$\|B-AX\|/\|B\|$", "tab:green", "s", "-"),
    "eta_total": (r"$\eta$", "k", "D", "-"),
    "eta_disc": (r"$\eta_{\mathrm{disc}}$", "tab:blue", "v", "-"),
    "eta_lin": (r"$\eta_{\mathrm{lin}}$", "tab:orange", "<", "-"),
    "eta_alg": (r"$\eta_{\mathrm{alg}}$", "tab:green", ">", "-"),
    "energy_error": (rf"${ENERGY_NORM}$", "tab:red", "^", "--"),
}


def new_figure(size=FIGSIZE) -> Figure:
    fig = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)  # Agg, never a display
    return fig


def subtitle(case: str, status: str) -> str:
    """Second title line: which case, and whether it converged."""
    return f"case '{case}', {textwrap.shorten(status, width=70, placeholder='...')}"


def set_title(fig_or_ax, what: str, second_line: str) -> None:
    text = f"{what}\n{second_line}" if second_line else what
    if isinstance(fig_or_ax, Figure):
        fig_or_ax.suptitle(text, fontsize=10)
    else:
        fig_or_ax.set_title(text, fontsize=10)


def fmt(v: float) -> str:
    return f"{v:.4g}"


def readable_log(ax, which: str) -> None:
    """Plain tick labels (0.02, 0.05) on a log axis spanning under three decades, where
    matplotlib labels one or two powers of ten, or minor ticks in overlapping scientific
    notation. Call after plotting."""
    lo, hi = ax.get_xlim() if which == "x" else ax.get_ylim()
    if not 0 < lo < hi or hi / lo >= 1000:
        return
    axis = ax.xaxis if which == "x" else ax.yaxis
    # the narrower the range, the denser the steps; under a factor 3, evenly spaced values
    if hi / lo >= 10:
        axis.set_major_locator(LogLocator(subs=(1, 2, 5)))
    elif hi / lo >= 3:
        axis.set_major_locator(LogLocator(subs=(1, 2, 3, 5)))
    else:
        axis.set_major_locator(MaxNLocator(5))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


class Writer:
    """Saves figures into one directory: prints each path on `out`, notes on `err`."""

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
