"""Tests of `python -m twomem_post plot`: synthetic result files built with h5py, and a real
result when the executable is known (env TWOMEM_EXE) or the stored regression reference.

Run: .venv/bin/python -m pytest -q postproc/tests
"""
from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

POSTPROC = Path(__file__).resolve().parents[1]
REPO = POSTPROC.parent
if str(POSTPROC) not in sys.path:  # works without the editable install too
    sys.path.insert(0, str(POSTPROC))

from twomem_post import plot as tp  # noqa: E402
from twomem_post.__main__ import main  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAPS = ["u1", "u2", "membranes", "lambda", "contact"]


# ----------------------------------------------------------------------------------------------
# synthetic result files

def square_mesh(n: int = 4):
    """[-1, 1]^2 cut into n x n squares, two counter-clockwise triangles each."""
    s = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(s, s)
    xy = np.column_stack([x.ravel(), y.ravel()])
    tri = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            b, c, d = a + 1, a + n + 1, a + n + 2
            tri += [[a, b, d], [a, d, c]]
    return xy, np.array(tri, dtype=np.int32)


def history_rows(gmres: bool, eta: bool):
    """Newton rows (inner 0) and, with gmres, one inner row inside every step."""
    rows = []  # newton_it, gmres_it, inner
    if gmres:
        rows = [(0, 0, 0), (1, 10, 1), (1, 17, 0), (2, 27, 1), (2, 30, 0), (3, 38, 0)]
    else:
        rows = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)]
    k = np.array([r[0] for r in rows], dtype=np.int32)
    n = len(rows)
    decay = 10.0 ** (-3.0 * np.arange(n))
    h = {
        "newton_it": k,
        "gmres_it": np.array([r[1] for r in rows], dtype=np.int32),
        "inner": np.array([r[2] for r in rows], dtype=np.int32),
        "lin_residual": 0.3 * decay,
        "alg_residual": np.where(np.arange(n) == 0, 0.0, 1e-2 * decay),
        "energy_error": 1e-2 + 1e-2 * decay,
        "active": np.full(n, 5, dtype=np.int32),
        "active_changed": np.zeros(n, dtype=np.int32),
        "step": np.ones(n),
        "wall_time": np.linspace(0.0, 1.0, n),
    }
    for name in ("eta_disc", "eta_lin", "eta_alg", "eta_total"):
        h[name] = (1.5 * h["energy_error"] if name == "eta_total" else 0.5 * h["energy_error"]) \
            if eta else np.full(n, np.nan)
    return h


def make_result(path: Path, *, case="synthetic", error=True, estimators=False, gmres=True,
                history=True, solution=("u1", "u2", "lambda"), mesh=True, n=4) -> Path:
    xy, tri = square_mesh(n)
    r2 = (xy ** 2).sum(axis=1)
    bump = 0.2 * np.maximum(r2 - 0.3, 0.0)
    fields = {"u1": 0.1 + bump, "u2": 0.1 - bump, "lambda": np.where(r2 < 0.3, 1.0 - r2, 0.0)}
    fields["u2"][r2 < 0.3] -= 1e-14  # GMRES-like round-off in the gap of contact vertices
    rng = np.random.default_rng(1)
    with h5py.File(path, "w") as f:
        f.attrs["version"] = "0.1.0"
        f.attrs["input"] = f"! twomem input: case '{case}' from 'input/{case}.nml'\n&mesh\n/\n"
        f.attrs["status"] = "converged"
        if mesh:
            f["mesh/vertices"] = xy
            f["mesh/triangles"] = tri
        for name in solution:
            f[f"solution/{name}"] = fields[name]
        if error:
            e = rng.uniform(1e-4, 1e-2, len(tri))
            e[:3] = 0.0  # exact on a few elements: must not break the log scale
            f["error/energy"] = e
            f["error/energy"].attrs["total"] = np.sqrt((e ** 2).sum())
        if estimators:
            f["estimators/eta_total"] = rng.uniform(1e-4, 3e-2, len(tri))
        if history:
            for name, values in history_rows(gmres, estimators).items():
                f[f"history/{name}"] = values
        s = f.create_group("summary")
        s.attrs["nv"], s.attrs["nt"] = len(xy), len(tri)
    return path


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

def test_full_result_draws_every_figure(tmp_path):
    f = make_result(tmp_path / "r.h5")
    written, out, err = run_plot(f, tmp_path / "figs" / "sub")  # outdir created, parents too
    assert names(written) == set(MAPS) | {"error", "history_newton", "history_gmres"}
    check_pngs(written)
    assert out.splitlines() == [str(p) for p in written]
    # estimators all NaN: no effectivity, said in one line
    assert "effectivity" in err and len(err.splitlines()) == 1


def test_direct_solver_without_exact_solution(tmp_path):
    f = make_result(tmp_path / "r.h5", error=False, gmres=False)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert names(written) == set(MAPS) | {"history_newton"}
    check_pngs(written)
    assert "error" in err and not (tmp_path / "figs" / "error.png").exists()
    assert not (tmp_path / "figs" / "history_gmres.png").exists()


def test_estimators_side_by_side_and_effectivity(tmp_path):
    f = make_result(tmp_path / "r.h5", estimators=True)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert {"error", "effectivity", "history_newton", "history_gmres"} <= names(written)
    check_pngs(written)
    w, h = png_size(tmp_path / "figs" / "error.png")
    assert w > 1.6 * h  # two panels side by side
    w1, h1 = png_size(tmp_path / "figs" / "u1.png")
    assert w1 < 1.6 * h1
    assert err == ""


def test_estimator_without_exact_solution(tmp_path):
    f = make_result(tmp_path / "r.h5", estimators=True, error=False)
    written, out, err = run_plot(f, tmp_path / "figs")
    assert "estimator" in names(written) and "error" not in names(written)
    check_pngs(written)


def test_shared_colour_scale_covers_both(tmp_path):
    eta = np.array([1e-3, 2e-2, 0.0])
    err = np.array([5e-4, 1e-3, 1e-18])
    norm, clipped = tp._log_norm(eta, err)
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
    expect = {"mesh": {"history_newton", "history_gmres"},
              "solution": {"error", "history_newton", "history_gmres"},
              "history": set(MAPS) | {"error"},
              "u2": {"u1", "lambda", "error", "history_newton", "history_gmres"},
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
    assert {p.stem for p in pdfs} == set(MAPS) | {"error", "history_newton", "history_gmres"}
    for p in pdfs:
        assert p.read_bytes()[:5] == b"%PDF-"


# ----------------------------------------------------------------------------------------------
# helpers

def test_case_name():
    assert tp.case_name("! twomem input: case 'paper_p1' from 'x.nml'\n&mesh\n/", "f") == "paper_p1"
    assert tp.case_name("&mesh\n/", "fallback") == "fallback"
    assert tp.case_name(None, "fallback") == "fallback"


def test_contact_set_tolerates_solver_round_off():
    u1 = np.array([0.1, 0.1, 0.1, 0.2])
    u2 = np.array([0.1, 0.1 - 2e-12, 0.1 - 1e-6, 0.0])
    lam = np.array([0.5, 0.3, 0.0, 0.0])
    # gap 2e-12 with lambda > 0: in contact; gap 1e-6 with lambda = 0: not
    assert tp.contact_vertices(u1, u2, lam).tolist() == [True, True, False, False]
    # without lambda only the gap tolerance (1e-12 max|u|) counts
    assert tp.contact_vertices(u1, u2, None).tolist() == [True, False, False, False]


def test_region_outline_of_two_triangles():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    seg = tp.region_outline(tri, np.array([True, True]), xy)
    assert seg.shape == (4, 2, 2)  # the square's sides, not the shared diagonal
    assert tp.region_outline(tri, np.array([False, False]), xy).shape == (0, 2, 2)


# ----------------------------------------------------------------------------------------------
# command line and errors

def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(POSTPROC), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def test_command_line(tmp_path):
    f = make_result(tmp_path / "r.h5", case="cli_case")
    outdir = tmp_path / "figs"
    proc = subprocess.run([sys.executable, "-m", "twomem_post", "plot", str(f), "-o", str(outdir)],
                          capture_output=True, text=True, cwd=tmp_path, env=_env(), timeout=300)
    assert proc.returncode == 0, proc.stderr
    paths = proc.stdout.splitlines()
    assert {Path(p).stem for p in paths} == set(MAPS) | {"error", "history_newton", "history_gmres"}
    check_pngs(paths)
    assert all(Path(p).parent == outdir for p in paths)


def test_broken_file_command_line(tmp_path):
    bad = tmp_path / "broken.h5"
    bad.write_bytes(b"this is not HDF5\n" * 10)
    proc = subprocess.run([sys.executable, "-m", "twomem_post", "plot", str(bad), "-o",
                           str(tmp_path / "figs")], capture_output=True, text=True, cwd=tmp_path,
                          env=_env(), timeout=300)
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
    assert set(MAPS) | {"history_newton"} <= got
    check_pngs(written)
    return got


def test_stored_reference_result(tmp_path):
    ref = REPO / "tests" / "regression" / "reference" / "radial_small.h5"
    if not ref.exists():
        pytest.skip("no stored reference result")
    assert "error" in _plot_real(ref, tmp_path / "figs")


def test_real_result(tmp_path):
    exe = os.environ.get("TWOMEM_EXE")
    if not exe:
        pytest.skip("TWOMEM_EXE not set")
    if os.sep in exe:  # a relative path still works from the temporary directory
        exe = str(Path(exe).resolve())
    result = tmp_path / "r.h5"
    proc = subprocess.run([exe, "run", str(REPO / "input" / "default.nml"), "mesh.levels=1",
                           f"output.file={result}"], capture_output=True, text=True, cwd=tmp_path,
                          timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr
    got = _plot_real(result, tmp_path / "figs")
    assert "error" in got  # the default case knows its exact solution
