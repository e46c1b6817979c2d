"""Tests of `python -m twomem_post plot`: synthetic result files built with h5py (synthetic.py),
the stored regression reference, and a tiny real result when the executable is found (--twomem
discovery: TWOMEM_EXE, else build/release/twomem).

Run: .venv/bin/python -m pytest -q postproc/tests
"""
from __future__ import annotations

import io
import struct
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from synthetic import env_with_package, make_result

POSTPROC = Path(__file__).resolve().parents[1]
REPO = POSTPROC.parent
if str(POSTPROC) not in sys.path:  # works without the editable install too
    sys.path.insert(0, str(POSTPROC))

from twomem_post import geometry, maps, plot as tp, result as tr  # noqa: E402
from twomem_post.__main__ import main  # noqa: E402
from twomem_post.errors import EnvironmentFailure, ResultError  # noqa: E402
from twomem_post.runner import find_twomem  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAPS = {"u1", "u2", "membranes", "lambda", "contact"}
NEWTON = {"history_newton", "estimators_newton"}
GMRES = {"history_gmres", "estimators_gmres"}
HISTORY = NEWTON | GMRES


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE, f"{path} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def run_plot(path, outdir, fmt="png"):
    out, err = io.StringIO(), io.StringIO()
    written = tp.plot(path, outdir, fmt, out=out, err=err)
    return written, out.getvalue(), err.getvalue()


def names(written) -> set[str]:
    return {Path(p).stem for p in written}


def check_pngs(written):
    for p in written:
        p = Path(p)
        assert p.is_file() and p.stat().st_size > 1000, p
        w, h = png_size(p)
        assert 300 < w <= 1200 and 300 < h <= 700, (p, w, h)


# ----------------------------------------------------------------------------------------------
# figures

def test_result_without_estimators(tmp_path):
    """What twomem writes today: estimator columns NaN, no /estimators."""
    f = make_result(tmp_path / "r.h5")
    written, out, err = run_plot(f, tmp_path / "figs" / "sub")  # outdir created, parents too
    assert names(written) == MAPS | {"error"} | HISTORY
    check_pngs(written)
    assert out.splitlines() == [str(p) for p in written]
    notes = err.splitlines()  # each absence said in one line
    assert len(notes) == 2 and "energy error only" in notes[0] and "effectivity" in notes[1]


def test_every_figure_with_estimators(tmp_path):
    f = make_result(tmp_path / "r.h5", estimators=True)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert names(written) == MAPS | {"error", "effectivity"} | HISTORY
    check_pngs(written)
    assert err == ""
    w, h = png_size(tmp_path / "figs" / "error.png")
    assert w > 1.6 * h  # estimate and error side by side
    w1, h1 = png_size(tmp_path / "figs" / "u1.png")
    assert w1 < 1.6 * h1


def test_estimator_figures_show_the_estimators(tmp_path):
    """The lines drawn are the history's estimator columns, at the rows the axis asks for."""
    f = make_result(tmp_path / "r.h5", estimators=True)
    r = tr.load(f)
    h = r.history
    drawn = {}

    class Keep(tp.Writer):
        def save(self, fig, name):
            drawn[name] = {line.get_label(): line.get_xydata() for line in fig.axes[0].lines}

    from twomem_post import convergence
    convergence.plot_convergence(r, Keep(tmp_path, "png", io.StringIO(), io.StringIO()))
    newton = np.flatnonzero(h["inner"] == 0)
    eta = drawn["estimators_newton"][r"$\eta_{\mathrm{lin}}$"]
    assert np.array_equal(eta[:, 0], h["newton_it"][newton])
    assert np.allclose(eta[:, 1], h["eta_lin"][newton])
    along_gmres = drawn["estimators_gmres"][r"$\eta$"]
    assert np.array_equal(along_gmres[:, 0], h["gmres_it"])  # inner rows included
    k, eff = drawn["effectivity"][r"$\eta/|\!|\!|u-u_h|\!|\!|$"].T
    assert np.allclose(eff, h["eta_total"][newton] / h["energy_error"][newton])


def test_direct_solver_without_exact_solution(tmp_path):
    f = make_result(tmp_path / "r.h5", error=False, gmres=False)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert names(written) == MAPS | NEWTON  # estimators_newton: the history's energy error
    check_pngs(written)
    assert "error.png skipped" in err and not (tmp_path / "figs" / "error.png").exists()
    assert "no GMRES iterations" in err


def test_estimator_without_exact_solution(tmp_path):
    f = make_result(tmp_path / "r.h5", estimators=True, error=False)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert "estimator" in names(written) and "error" not in names(written)
    check_pngs(written)


def test_shared_colour_scale_covers_both(tmp_path):
    eta = np.array([1e-3, 2e-2, 0.0])
    err = np.array([5e-4, 1e-3, 1e-18])
    norm, clipped = maps._log_norm(eta, err)
    assert norm.vmax == pytest.approx(2e-2) and norm.vmin == pytest.approx(5e-4)
    assert clipped  # 0 and round-off lie below the scale


@pytest.mark.parametrize("what", ["mesh", "solution", "history", "u2", "everything"])
def test_missing_datasets_are_skipped(tmp_path, what):
    kw = {"mesh": dict(mesh=False, error=False),
          "solution": dict(solution=()),
          "history": dict(history=False),
          "u2": dict(solution=("u1", "lambda")),
          "everything": dict(mesh=False, error=False, solution=(), history=False)}[what]
    f = make_result(tmp_path / "r.h5", **kw)
    written, out, err = run_plot(f, tmp_path / "figs")
    check_pngs(written)
    got = names(written)
    expect = {"mesh": HISTORY,
              "solution": {"error"} | HISTORY,
              "history": MAPS | {"error"},
              "u2": {"u1", "lambda", "error"} | HISTORY,
              "everything": set()}[what]
    assert got == expect
    assert err, "a skipped figure is noted"
    for line in err.splitlines():
        assert line.startswith("twomem_post: note: ")


def test_nan_and_constant_fields_do_not_crash(tmp_path):
    f = make_result(tmp_path / "r.h5")
    with h5py.File(f, "a") as h:
        u1 = h["solution/u1"][()]
        u1[0] = np.nan
        h["solution/u1"][...] = u1
        h["solution/lambda"][...] = 0.0
        h["history/lin_residual"][...] = np.nan
    written, out, err = run_plot(f, tmp_path / "figs")
    assert {"u1", "lambda", "history_newton"} <= names(written)
    check_pngs(written)


def test_non_converged_iterate(tmp_path):
    """Negative lambda (diverging colour map) and an effectivity far from 1 (log scale)."""
    f = make_result(tmp_path / "r.h5", estimators=True)
    with h5py.File(f, "a") as h:
        h.attrs["status"] = "not converged: iteration limit newton.max_it reached"
        h["solution/lambda"][...] = h["solution/lambda"][()] - 0.4
        e = h["history/energy_error"][()]
        h["history/eta_total"][...] = e * np.geomspace(300.0, 1.2, len(e))
    written, out, err = run_plot(f, tmp_path / "figs")
    assert {"lambda", "effectivity"} <= names(written)
    check_pngs(written)


def test_pdf_format(tmp_path):
    f = make_result(tmp_path / "r.h5")
    rc = main(["plot", str(f), "-o", str(tmp_path / "figs"), "--format", "pdf"])
    assert rc == 0
    pdfs = sorted((tmp_path / "figs").glob("*.pdf"))
    assert {p.stem for p in pdfs} == MAPS | {"error"} | HISTORY
    for p in pdfs:
        assert p.read_bytes()[:5] == b"%PDF-"


# ----------------------------------------------------------------------------------------------
# helpers

def test_case_name():
    assert tr.case_name("! twomem input: case 'paper_p1' from 'x.nml'\n&mesh\n/", "f") == "paper_p1"
    assert tr.case_name("&mesh\n/", "fallback") == "fallback"
    assert tr.case_name(None, "fallback") == "fallback"


def test_contact_set_tolerates_solver_round_off():
    u1 = np.array([0.1, 0.1, 0.1, 0.2])
    u2 = np.array([0.1, 0.1 - 2e-12, 0.1 - 1e-6, 0.0])
    lam = np.array([0.5, 0.3, 0.0, 0.0])
    # gap 2e-12 with lambda > 0: in contact; gap 1e-6 with lambda = 0: not
    assert geometry.contact_vertices(u1, u2, lam).tolist() == [True, True, False, False]
    # without lambda only the gap tolerance (1e-12 max|u|) counts
    assert geometry.contact_vertices(u1, u2, None).tolist() == [True, False, False, False]


def test_region_outline_of_two_triangles():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    seg = geometry.region_outline(tri, np.array([True, True]), xy)
    assert seg.shape == (4, 2, 2)  # the square's sides, not the shared diagonal
    assert geometry.region_outline(tri, np.array([False, False]), xy).shape == (0, 2, 2)


# ----------------------------------------------------------------------------------------------
# command line and errors

def test_command_line(tmp_path):
    f = make_result(tmp_path / "r.h5", case="cli_case")
    outdir = tmp_path / "figs"
    proc = subprocess.run([sys.executable, "-m", "twomem_post", "plot", str(f), "-o", str(outdir)],
                          capture_output=True, text=True, cwd=tmp_path, env=env_with_package(), timeout=300)
    assert proc.returncode == 0, proc.stderr
    paths = proc.stdout.splitlines()
    assert {Path(p).stem for p in paths} == MAPS | {"error"} | HISTORY
    check_pngs(paths)
    assert all(Path(p).parent == outdir for p in paths)


def test_broken_file_command_line(tmp_path):
    bad = tmp_path / "broken.h5"
    bad.write_bytes(b"this is not HDF5\n" * 10)
    proc = subprocess.run([sys.executable, "-m", "twomem_post", "plot", str(bad), "-o",
                           str(tmp_path / "figs")], capture_output=True, text=True, cwd=tmp_path,
                          env=env_with_package(), timeout=300)
    assert proc.returncode == 2
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"twomem_post: error: {bad}: "), proc.stderr
    assert proc.stdout == ""


def _not_twomem(path: Path):
    with h5py.File(path, "w") as f:
        f["data"] = np.arange(3)


def _truncated(path: Path):
    make_result(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])


def _inconsistent(path: Path):
    make_result(path)
    with h5py.File(path, "a") as f:
        del f["solution/u1"]
        f["solution/u1"] = np.zeros(3)


def _bad_connectivity(path: Path):
    make_result(path)
    with h5py.File(path, "a") as f:
        t = f["mesh/triangles"][()]
        t[0, 0] = 999
        f["mesh/triangles"][...] = t


@pytest.mark.parametrize("make", [None, lambda p: p.write_bytes(b""), _not_twomem, _truncated,
                                  _inconsistent, _bad_connectivity, lambda p: p.mkdir()],
                         ids=["missing", "empty", "not-twomem", "truncated", "inconsistent",
                              "bad-connectivity", "directory"])
def test_unusable_file_exits_2_with_one_line(tmp_path, capsys, make):
    path = tmp_path / "bad.h5"
    if make is not None:
        make(path)
    rc = main(["plot", str(path), "-o", str(tmp_path / "figs")])
    captured = capsys.readouterr()
    assert rc == 2
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(f"twomem_post: error: {path}: ")
    assert captured.out == ""
    assert not list((tmp_path).glob("figs/*"))


# ----------------------------------------------------------------------------------------------
# real results

def _plot_real(path: Path, outdir: Path):
    written, out, err = run_plot(path, outdir)
    got = names(written)
    assert MAPS | NEWTON <= got
    check_pngs(written)
    return got


def test_stored_reference_result(tmp_path):
    ref = REPO / "tests" / "regression" / "reference" / "radial_small.h5"
    if not ref.exists():
        pytest.skip("no stored reference result")
    assert "error" in _plot_real(ref, tmp_path / "figs")


def twomem_or_skip() -> Path:
    try:
        return find_twomem()
    except EnvironmentFailure as exc:
        pytest.skip(f"no twomem executable ({exc.why})")


@pytest.mark.parametrize("linear", ["direct", "gmres"])
def test_real_result(tmp_path, linear):
    """Smoke test on a tiny result of the real program (default case: exact solution known)."""
    result = tmp_path / "r.h5"
    proc = subprocess.run([str(twomem_or_skip()), "run", str(REPO / "input" / "default.nml"),
                           "mesh.levels=0", f"newton.linear={linear}", "gmres.precond=ilu0",
                           f"output.file={result}"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr
    got = _plot_real(result, tmp_path / "figs")
    assert "error" in got
    assert (GMRES <= got) == (linear == "gmres")


def _add_adapt(path: Path, rate: float = -0.5, steps: int = 8):
    n = (100 * 1.5 ** np.arange(steps)).astype(np.int32)
    with h5py.File(path, "a") as f:
        f["adapt/vertices"] = n
        f["adapt/eta"] = 0.1 * (n / n[0]) ** rate
        f["adapt/eta_disc"] = 0.09 * (n / n[0]) ** rate
        f["adapt/energy_error"] = np.full(steps, np.nan)
        f["adapt/wall_time"] = np.ones(steps)
    return n


def test_adaptive_run_figures(tmp_path):
    path = make_result(tmp_path / "a.h5", error=False)
    n = _add_adapt(path)
    written, _, _ = run_plot(path, tmp_path / "figs")
    assert {"adapt_convergence", "adapt_mesh"} <= names(written)
    check_pngs([p for p in written if Path(p).stem.startswith("adapt")])
    r = tr.load(path)
    assert list(r.adapt["vertices"]) == list(n)


def test_adapt_slope_is_the_asymptotic_one():
    from twomem_post.adapt import slope
    n = 100 * 2.0 ** np.arange(10)
    # a pre-asymptotic start at a worse rate, then N^-1/2
    eta = np.where(n < 1000, n ** -0.2 * 1000 ** -0.3, n ** -0.5)
    assert abs(slope(n, eta) + 0.5) < 1e-12


def test_inconsistent_adapt_group_is_refused(tmp_path):
    path = make_result(tmp_path / "a.h5", error=False)
    _add_adapt(path)
    with h5py.File(path, "a") as f:
        del f["adapt/eta"]
        f["adapt/eta"] = np.ones(3)
    with pytest.raises(ResultError, match="one entry per step"):
        tr.load(path)


def test_real_adaptive_result(tmp_path):
    """The adaptive run's figures from a real result (a few refinement steps on the disk)."""
    result = tmp_path / "a.h5"
    proc = subprocess.run([str(twomem_or_skip()), "run", str(REPO / "input" / "default.nml"), "mesh.levels=0",
                           "adapt.tol=1e-2", f"output.file={result}"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr
    written, _, _ = run_plot(result, tmp_path / "figs")
    assert {"adapt_convergence", "adapt_mesh"} <= names(written)
    r = tr.load(result)
    assert len(r.adapt["eta"]) >= 2 and np.all(np.isfinite(r.adapt["energy_error"]))
