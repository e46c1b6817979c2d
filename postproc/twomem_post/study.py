"""``python -m twomem_post study CASE.nml -o DIR [MESHES] [--methods ...]``: one case over a
mesh sequence and several methods, gathered into tables and comparison figures.

MESHES is one of
  ``--levels 0,1,2``           mesh.levels = each value (one hierarchy, refined further)
  ``--coarse-h 0.25,0.122``    mesh.coarse_h = mesh.boundary_h = each value (separate meshes)
  ``--sweep KEY[+KEY]=V1,V2``  any key(s), all set to each value in turn
  ``--paper``                  the paper's three meshes and methods, with CASE =
                               input/paper_p1.nml: --coarse-h 0.25,0.122,0.0582 (2032, 7424,
                               34592 triangles against the paper's 2048, 7840, 34592) with
                               exact, inexact and adaptive (--methods still chooses others)
or nothing (the case's own mesh). Every mesh runs with every method (methods.py), plus
``newton.max_it`` (--max-it: the inexact method needs more than the default 100 steps on the
paper's finest mesh) and the --set overrides, in that order, so --set has the last word
except on output.file.

Writes DIR/runs/<tag>.h5 and .log per run (tag: method and mesh value, e.g. exact_h0.122),
DIR/summary.csv, DIR/history.csv and the figures of study_figures.py, prints a progress line
per finished run, the figure paths, and the summary as a markdown table (the paper's values in
parentheses on its case). Runs go --jobs at a time (default: one per core), the finest meshes
first, since a sweep is usually written coarse to fine and the longest runs should not start
last. With more than one job at a time, wall times include the competition for memory
bandwidth; use --jobs 1 for timings. A run that fails or does not converge is reported and the
study goes on; the exit status is then 1.

On a cluster, a job array runs the study one run per task (jobs/study_array.sbatch):
``--list`` prints the planned runs (index and tag), ``--task N`` runs only run N (exit 1 if it
fails), and ``--collect`` then builds the tables and figures from DIR/runs without running
anything, reading each run's exit code and time from the last line of its log.
"""
from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from . import methods
from . import paper, study_figures, tables
from .errors import PostError, ResultError
from .figure import subtitle
from .plot import FORMATS, output_writer
from .result import load
from .runner import Run, execute_all, find_twomem, recorded

#: mesh.coarse_h (= mesh.boundary_h) of input/paper_p1.nml giving the paper's three meshes
PAPER_COARSE_H = ("0.25", "0.122", "0.0582")
DEFAULT_MAX_IT = 1000
_KEY = re.compile(r"^[A-Za-z_]\w*\.[A-Za-z_]\w*$")


@dataclass
class Sweep:
    """The mesh sequence: keys all set to each value in turn; `short` names it in tags."""
    keys: tuple[str, ...]
    values: tuple[str, ...]
    short: str

    def tag(self, method: str, value: str) -> str:
        return method if not self.keys else f"{method}_{self.short}{value}"

    def overrides(self, value: str) -> tuple[str, ...]:
        return tuple(f"{k}={value}" for k in self.keys)


def _values(option: str, text: str) -> tuple[str, ...]:
    values = tuple(v.strip() for v in text.split(","))
    if not all(values):
        raise PostError(option, f"empty value in {text!r} (expected V1,V2,...)")
    if len(set(values)) != len(values):
        raise PostError(option, f"a value is repeated in {text!r}")
    if not all(re.fullmatch(r"[\w.+\-']+", v) for v in values):
        raise PostError(option, f"{text!r}: values may hold letters, digits, quotes and . + - _")
    return values


def parse_sweep(args) -> Sweep:
    if args.levels:
        return Sweep(("mesh.levels",), _values("--levels", args.levels), "L")
    if args.coarse_h:
        return Sweep(("mesh.coarse_h", "mesh.boundary_h"), _values("--coarse-h", args.coarse_h),
                     "h")
    if args.paper:
        return Sweep(("mesh.coarse_h", "mesh.boundary_h"), PAPER_COARSE_H, "h")
    if args.sweep:
        keys, sep, values = args.sweep.partition("=")
        key_list = tuple(keys.split("+"))
        if not sep or not all(_KEY.match(k) for k in key_list):
            raise PostError("--sweep", f"{args.sweep!r}: expected GROUP.KEY[+GROUP.KEY]=V1,V2,...")
        return Sweep(key_list, _values("--sweep", values), key_list[0].split(".")[1])
    return Sweep((), ("",), "")


def _check_overrides(overrides: list[str]) -> tuple[str, ...]:
    for o in overrides:
        key, sep, _ = o.partition("=")
        if not sep or not _KEY.match(key):
            raise PostError("--set", f"{o!r}: expected GROUP.KEY=VALUE")
    return tuple(overrides)


def plan(sweep: Sweep, method_names: list[str], outdir: Path, max_it: int,
         overrides: tuple[str, ...]) -> list[Run]:
    """Every (mesh value, method) pair as a Run, mesh-major in the order given."""
    runs = []
    for value in sweep.values:
        for m in method_names:
            tag = sweep.tag(m, value)
            runs.append(Run(tag=tag, method=m, params={k: value for k in sweep.keys},
                            overrides=(*methods.METHODS[m], f"newton.max_it={max_it}",
                                       *sweep.overrides(value), *overrides),
                            result=outdir / "runs" / f"{tag}.h5",
                            log=outdir / "runs" / f"{tag}.log"))
    return runs


def _finished(outcome: tables.Outcome, n: int, total: int, out) -> None:
    run, r = outcome.run, outcome.result
    if r is None:
        line = f"FAILED (exit {run.exit_code}): {run.error}"
    else:
        s = r.summary
        line = (f"{r.status}, {s.get('nt', '?')} triangles, {s.get('newton_iterations', '?')} "
                f"Newton, {s.get('gmres_iterations', '?')} GMRES")
    print(f"[{n}/{total}] {run.tag}: {line} ({run.seconds:.1f} s)", file=out, flush=True)


def run_study(case: Path, runs: list[Run], exe: Path, jobs: int, out) -> list[tables.Outcome]:
    """Execute the runs (finest first), load each result as it finishes, report progress;
    return the outcomes in plan order."""
    done: dict[str, tables.Outcome] = {}

    def on_done(run: Run) -> None:
        result = None
        if run.result.exists():
            try:
                result = load(run.result)
            except ResultError as exc:
                run.error = f"unusable result: {exc.why}"
        elif not run.error:
            run.error = f"no result file {run.result}"
        done[run.tag] = tables.Outcome(run, result)
        _finished(done[run.tag], len(done), len(runs), out)

    execute_all(exe, case, list(reversed(runs)), jobs, on_done)
    return [done[run.tag] for run in runs]


def write_tables(outdir: Path, sweep: Sweep, outcomes: list[tables.Outcome]) -> list[dict]:
    ident = ["tag", "method", *sweep.keys]
    summary = [o.summary_row() for o in outcomes]
    tables.write_csv(outdir / "summary.csv", summary,
                     ident + list(tables.SUMMARY) + ["status", "exit_code"])
    history = [row for o in outcomes for row in o.history_rows()]
    tables.write_csv(outdir / "history.csv", history,
                     tables.history_columns(history, ident + ["nt"]))
    return summary


def draw(outcomes, method_names, w, with_paper: bool, second_line: str) -> None:
    if not any(o.result is not None for o in outcomes):
        w.note("no run produced a result: figures skipped")
        return
    study_figures.plot_iterations(outcomes, method_names, w, with_paper, second_line)
    study_figures.plot_work_precision(outcomes, w, second_line)
    study_figures.plot_estimators(outcomes, method_names, w, with_paper, second_line)


def _inputs(args) -> tuple[Path, Sweep, list[str], tuple[str, ...]]:
    """The case, mesh sequence, methods and overrides, all checked before anything runs."""
    case = Path(args.case)
    if not case.is_file():
        raise PostError(case, "no such case file")
    if args.jobs < 1 or args.max_it < 1:
        raise PostError("--jobs" if args.jobs < 1 else "--max-it", "must be at least 1")
    sweep = parse_sweep(args)
    try:
        names = methods.parse(args.methods or ",".join(methods.PAPER_METHODS))
    except ValueError as exc:
        raise PostError("--methods", str(exc)) from None
    return case, sweep, names, _check_overrides(args.overrides)


def collect(runs: list[Run], out) -> list[tables.Outcome]:
    """The outcomes of runs executed earlier (--task, e.g. by a job array), from their logs
    and result files, with the same progress lines as a study that runs them."""
    outcomes = []
    for n, run in enumerate(runs, start=1):
        recorded(run)
        result = None
        if run.exit_code is not None and run.result.exists():
            try:
                result = load(run.result)
            except ResultError as exc:
                run.error = f"unusable result: {exc.why}"
        elif run.exit_code is not None and not run.error:
            run.error = f"no result file {run.result}"
        outcomes.append(tables.Outcome(run, result))
        _finished(outcomes[-1], n, len(runs), out)
    return outcomes


def run_task(case: Path, runs: list[Run], task: int, exe: Path, out) -> int:
    """--task N: only the N-th run of the plan (0-based, the order --list prints), so that a
    job array runs a study one run per task; --collect gathers them afterwards."""
    if not 0 <= task < len(runs):
        raise PostError("--task", f"{task} is not a run of this study (it has runs 0 to {len(runs) - 1})")
    run = runs[task]
    print(f"study: run {task} of {len(runs)} ({run.tag}) of {case} with {exe}", file=out, flush=True)
    outcome, = run_study(case.resolve(), [run], exe, 1, out)
    return 1 if outcome.failed else 0


def study(args, out=None, err=None) -> int:
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    case, sweep, names, overrides = _inputs(args)
    outdir = Path(args.outdir)
    runs = plan(sweep, names, outdir, args.max_it, overrides)
    if args.list:
        for n, run in enumerate(runs):
            print(n, run.tag, file=out)
        return 0
    if args.task is not None:
        return run_task(case, runs, args.task, find_twomem(args.twomem), out)
    w = output_writer(outdir, args.fmt, out, err)  # an unusable DIR fails before any run
    if args.collect:
        print(f"study: {len(runs)} runs of {case} collected from {outdir / 'runs'}", file=out, flush=True)
        outcomes = collect(runs, out)
        how = "collected"
    else:
        exe = find_twomem(args.twomem)
        jobs = min(args.jobs, len(runs))
        print(f"study: {len(runs)} runs of {case} with {exe}, {jobs} at a time", file=out, flush=True)
        outcomes = run_study(case.resolve(), runs, exe, jobs, out)
        how = f"{jobs} at a time"

    summary = write_tables(outdir, sweep, outcomes)
    print(outdir / "summary.csv", outdir / "history.csv", sep="\n", file=out)
    with_paper = any(o.result is not None and paper.is_paper_case(o.result.input_text)
                     for o in outcomes)
    draw(outcomes, names, w, with_paper, subtitle(case.stem, f"{len(runs)} runs, {how}"))
    print("\n" + tables.markdown(summary, sweep.keys, with_paper), file=out)
    return _report_failures(outcomes, err)


def _report_failures(outcomes, err) -> int:
    bad = [o for o in outcomes if o.failed]
    if bad:
        listed = ", ".join(f"{o.run.tag} ({'not run' if o.run.exit_code is None else f'exit {o.run.exit_code}'})"
                           for o in bad)
        print(f"twomem_post: {len(bad)} of {len(outcomes)} runs did not succeed: {listed}; "
              f"see their logs in runs/", file=err)
    return 1 if bad else 0


def add_parser(sub) -> None:
    p = sub.add_parser("study", help="one case over meshes and methods: CSV tables and figures",
                       description="Run twomem over a mesh sequence and methods, gather "
                                   "summary.csv and history.csv, draw the comparison figures.")
    p.add_argument("case", help="twomem case file (namelist)")
    p.add_argument("-o", "--outdir", required=True, metavar="DIR",
                   help="directory for runs/, the CSV files and the figures (created if needed)")
    meshes = p.add_mutually_exclusive_group()
    meshes.add_argument("--levels", metavar="L1,L2,...", help="mesh.levels of each mesh")
    meshes.add_argument("--coarse-h", metavar="H1,H2,...",
                        help="mesh.coarse_h = mesh.boundary_h of each mesh")
    meshes.add_argument("--sweep", metavar="KEY[+KEY]=V1,V2,...",
                        help="any key(s), e.g. mesh.coarse_h+mesh.boundary_h=0.25,0.122")
    meshes.add_argument("--paper", action="store_true",
                        help="the paper's meshes (--coarse-h 0.25,0.122,0.0582) and methods")
    p.add_argument("--methods", metavar="M1,M2,...",
                   help=f"of {', '.join(methods.METHODS)} (default: "
                        f"{','.join(methods.PAPER_METHODS)})")
    p.add_argument("--set", action="append", default=[], dest="overrides",
                   metavar="GROUP.KEY=VALUE", help="override passed to every run (repeatable)")
    p.add_argument("--max-it", type=int, default=DEFAULT_MAX_IT, metavar="N",
                   help=f"newton.max_it of every run (default {DEFAULT_MAX_IT})")
    p.add_argument("-j", "--jobs", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="runs at a time (default: the number of cores)")
    p.add_argument("--twomem", metavar="PATH",
                   help="executable (default: $TWOMEM_EXE, else build/release/twomem)")
    p.add_argument("--format", choices=FORMATS, default="png", dest="fmt",
                   help="figure file format (default png)")
    split = p.add_mutually_exclusive_group()
    split.add_argument("--list", action="store_true",
                       help="print the planned runs (index and tag) and run nothing")
    split.add_argument("--task", type=int, metavar="N",
                       help="run only run N of --list (a job array task); no tables")
    split.add_argument("--collect", action="store_true",
                       help="run nothing: tables and figures from the runs --task made")
    p.set_defaults(func=study)
