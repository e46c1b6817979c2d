"""Tests of `python -m twomem_post study`: the mesh sequences, methods and paper data as units;
the whole study against a stand-in executable (synthetic.fake_twomem: parallel runs, logs, a
failing method, CSV files, figures, exit status); the command-line errors; and a tiny study with
the real program when it is found (TWOMEM_EXE, else build/release/twomem).
"""
from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import pytest

from synthetic import env_with_package, fake_twomem

POSTPROC = Path(__file__).resolve().parents[1]
REPO = POSTPROC.parent
if str(POSTPROC) not in sys.path:  # works without the editable install too
    sys.path.insert(0, str(POSTPROC))

from twomem_post import methods, paper, study, tables  # noqa: E402
from twomem_post.__main__ import main  # noqa: E402
from twomem_post.errors import EnvironmentFailure, PostError  # noqa: E402
from twomem_post.runner import find_twomem  # noqa: E402

SUMMARY_HEADER = ["tag", "method", "mesh.levels", *tables.SUMMARY, "status", "exit_code"]


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return reader.fieldnames, list(reader)


def sweep_args(**kw) -> argparse.Namespace:
    base = dict(levels=None, coarse_h=None, sweep=None, paper=False)
    return argparse.Namespace(**{**base, **kw})


@pytest.fixture
def case(tmp_path) -> Path:
    path = tmp_path / "case.nml"
    path.write_text("&mesh\n  levels = 0\n/\n&problem\n  exact = 'radial'\n/\n")
    return path


# ----------------------------------------------------------------------------------------------
# units

def test_paper_data_is_consistent():
    """The transcription: per-step counts add up to Fig. 6's totals at 7840 triangles."""
    i = paper.TRIANGLES.index(paper.PER_STEP_TRIANGLES)
    for method, steps in paper.GMRES_PER_STEP.items():
        assert sum(steps) == paper.AT_CONVERGENCE["gmres_iterations"][method][i]
        assert len(steps) == paper.AT_CONVERGENCE["newton_iterations"][method][i]
    for per_method in paper.AT_CONVERGENCE.values():
        assert all(len(v) == len(paper.TRIANGLES) for v in per_method.values())


def test_paper_meshes_match_ours():
    assert [paper.mesh_index(n) for n in (2032, 7424, 34592)] == [0, 2, 6]
    assert paper.mesh_index(5500) is None and paper.mesh_index(float("nan")) is None
    assert paper.value("newton_iterations", "adaptive", 7424) == 14
    assert paper.value("eta_total", "exact", 7424) is None  # not published
    assert paper.is_paper_case("&problem\n   exact = 'bbbv'\n/")
    assert not paper.is_paper_case("&problem\n   exact = 'radial'\n/")


def test_mesh_sequences():
    s = study.parse_sweep(sweep_args(levels="0,1,2"))
    assert s.keys == ("mesh.levels",) and s.values == ("0", "1", "2")
    assert s.tag("exact", "1") == "exact_L1" and s.overrides("1") == ("mesh.levels=1",)
    s = study.parse_sweep(sweep_args(coarse_h="0.25,0.122"))
    assert s.overrides("0.25") == ("mesh.coarse_h=0.25", "mesh.boundary_h=0.25")
    assert study.parse_sweep(sweep_args(paper=True)).values == study.PAPER_COARSE_H
    s = study.parse_sweep(sweep_args(sweep="mesh.coarse_h+mesh.boundary_h=0.5,0.25"))
    assert s.tag("direct", "0.5") == "direct_coarse_h0.5" and len(s.overrides("0.5")) == 2
    s = study.parse_sweep(sweep_args())
    assert s.tag("exact", "") == "exact" and s.overrides("") == ()


@pytest.mark.parametrize("kw", [dict(sweep="mesh.levels"), dict(sweep="levels=1,2"),
                                dict(levels="1,,2"), dict(levels="1,1"), dict(levels="1;rm")])
def test_bad_mesh_sequences(kw):
    with pytest.raises(PostError):
        study.parse_sweep(sweep_args(**kw))


def test_methods():
    assert methods.parse("exact, inexact") == ["exact", "inexact"]
    for bad in ("exact,newton", "", "exact,exact"):
        with pytest.raises(ValueError):
            methods.parse(bad)


def test_plan_orders_overrides(tmp_path):
    """Method first, then max_it and the mesh, and --set last (it has the last word)."""
    sweep = study.parse_sweep(sweep_args(levels="0,1"))
    runs = study.plan(sweep, ["exact", "direct"], tmp_path, 500, ("newton.tol=1e-8",))
    assert [r.tag for r in runs] == ["exact_L0", "direct_L0", "exact_L1", "direct_L1"]
    assert runs[0].overrides == (*methods.METHODS["exact"], "newton.max_it=500",
                                 "mesh.levels=0", "newton.tol=1e-8")
    assert runs[3].result == tmp_path / "runs" / "direct_L1.h5"
    assert runs[3].params == {"mesh.levels": "1"}


def test_find_twomem(tmp_path, monkeypatch):
    exe = fake_twomem(tmp_path)
    monkeypatch.setenv("TWOMEM_EXE", str(exe))
    assert find_twomem() == exe.resolve()
    with pytest.raises(EnvironmentFailure):
        find_twomem(str(tmp_path / "missing"))  # --twomem wins over the environment
    monkeypatch.setenv("TWOMEM_EXE", "no-such-twomem-program")
    with pytest.raises(EnvironmentFailure):
        find_twomem()


# ----------------------------------------------------------------------------------------------
# whole studies with the stand-in executable

def test_study_with_a_failing_method(tmp_path, case, capsys, monkeypatch):
    monkeypatch.delenv("FAKE_ETA", raising=False)
    out = tmp_path / "study"
    (out / "runs").mkdir(parents=True)
    (out / "runs" / "adaptive_L0.h5").write_bytes(b"stale")  # from an earlier study
    rc = main(["study", str(case), "--levels", "0,1", "--methods", "exact,inexact,adaptive",
               "-o", str(out), "--twomem", str(fake_twomem(tmp_path)), "--jobs", "2"])
    captured = capsys.readouterr()
    assert rc == 1  # the adaptive runs failed
    assert sum(line.startswith("[") for line in captured.out.splitlines()) == 6
    assert "2 of 6 runs did not succeed" in captured.err

    header, rows = read_csv(out / "summary.csv")
    assert header == SUMMARY_HEADER
    assert [r["tag"] for r in rows] == ["exact_L0", "inexact_L0", "adaptive_L0",
                                        "exact_L1", "inexact_L1", "adaptive_L1"]
    for r in rows:
        failed = r["method"] == "adaptive"
        assert r["exit_code"] == ("2" if failed else "0")
        assert r["status"].startswith("failed: twomem: error:") == failed
        assert (r["nt"] == "") == failed
    assert [r["nt"] for r in rows if r["method"] == "exact"] == ["8", "32"]
    assert not (out / "runs" / "adaptive_L0.h5").exists()

    header, history = read_csv(out / "history.csv")
    assert header[:4] == ["tag", "method", "mesh.levels", "nt"]
    assert {"newton_it", "gmres_it", "inner", "eta_total", "energy_error"} <= set(header)
    assert {r["tag"] for r in history} == {"exact_L0", "inexact_L0", "exact_L1", "inexact_L1"}
    assert len(history) == 2 * (1 + 2 * 2) + 2 * (1 + 2 * 3)  # rows of steps 2 and 3, GMRES

    for tag in (r["tag"] for r in rows):
        assert "OMP_NUM_THREADS=1" in (out / "runs" / f"{tag}.log").read_text()
    for name in ("iterations", "work_precision"):
        assert (out / f"{name}.png").stat().st_size > 1000
    assert "estimators.png and effectivity.png skipped" in captured.err
    assert "| method | triangles |" in captured.out


def test_paper_case_with_estimators(tmp_path, capsys, monkeypatch):
    """Every figure, and the paper's values beside ours on its case ('bbbv')."""
    monkeypatch.setenv("FAKE_ETA", "1")
    monkeypatch.setenv("FAKE_ADAPTIVE", "1")
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    case = tmp_path / "paper.nml"
    case.write_text("&problem\n   exact = 'bbbv'\n/\n")
    out = tmp_path / "study"
    rc = main(["study", str(case), "--coarse-h", "0.25,0.125", "-o", str(out), "--twomem",
               str(fake_twomem(tmp_path)), "--jobs", "1", "--format", "pdf"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    header, rows = read_csv(out / "summary.csv")
    assert header[2:4] == ["mesh.coarse_h", "mesh.boundary_h"] and len(rows) == 6
    for name in ("iterations", "work_precision", "estimators", "effectivity"):
        assert (out / f"{name}.pdf").read_bytes()[:5] == b"%PDF-"
    assert "| Newton (paper) |" in captured.out
    assert "OMP_NUM_THREADS=unset" in (out / "runs" / "exact_h0.25.log").read_text()
    assert captured.err == ""


def test_unusable_result_is_a_failure(tmp_path, case, capsys):
    out = tmp_path / "study"
    rc = main(["study", str(case), "--methods", "direct", "--set", "fake.broken=1", "-o",
               str(out), "--twomem", str(fake_twomem(tmp_path))])
    captured = capsys.readouterr()
    assert rc == 1
    _, rows = read_csv(out / "summary.csv")
    assert rows[0]["tag"] == "direct" and rows[0]["exit_code"] == "0"
    assert rows[0]["status"].startswith("failed: unusable result: not a readable HDF5 file")
    assert "no run produced a result: figures skipped" in captured.err


def test_job_array_split(tmp_path, case, capsys, monkeypatch):
    """--list, --task N per run (as a job array runs them) and --collect give the same tables
    as one study; a run no task ran is reported, not invented."""
    monkeypatch.delenv("FAKE_ETA", raising=False)
    fake = str(fake_twomem(tmp_path))
    base = ["study", str(case), "--levels", "0,1", "--methods", "exact,inexact,adaptive", "--twomem", fake]
    whole, split = tmp_path / "whole", tmp_path / "split"
    assert main([*base, "-o", str(whole), "--jobs", "1"]) == 1
    capsys.readouterr()

    assert main([*base, "-o", str(split), "--list"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert listed == ["0 exact_L0", "1 inexact_L0", "2 adaptive_L0", "3 exact_L1", "4 inexact_L1",
                      "5 adaptive_L1"]
    assert not split.exists()  # --list runs and writes nothing
    for n in range(5):  # the last task never ran (a cancelled array task)
        assert main([*base, "-o", str(split), "--task", str(n)]) == (1 if n == 2 else 0)
    assert not (split / "summary.csv").exists()  # a task writes its run only
    capsys.readouterr()

    assert main([*base, "-o", str(split), "--collect"]) == 1
    captured = capsys.readouterr()
    assert "adaptive_L0 (exit 2), adaptive_L1 (not run)" in captured.err
    _, rows = read_csv(split / "summary.csv")
    _, expected = read_csv(whole / "summary.csv")
    for got, want in zip(rows[:5], expected[:5]):
        assert {k: v for k, v in got.items() if k != "wall_time"} == \
               {k: v for k, v in want.items() if k != "wall_time"}
    assert rows[5]["status"] == f"failed: not run: no log {split / 'runs' / 'adaptive_L1.log'}"
    assert rows[5]["exit_code"] == ""
    assert "| not run |" in captured.out

    assert main([*base, "-o", str(split), "--task", "6"]) == 2
    assert capsys.readouterr().err.startswith("twomem_post: error: --task: 6 is not a run of this study")


# ----------------------------------------------------------------------------------------------
# command-line errors

@pytest.mark.parametrize("args, where, status", [
    (["missing.nml"], "missing.nml", 2),
    (["CASE", "--methods", "exact,fast"], "--methods", 2),
    (["CASE", "--sweep", "mesh.levels"], "--sweep", 2),
    (["CASE", "--set", "newton"], "--set", 2),
    (["CASE", "--jobs", "0"], "--jobs", 2),
    (["CASE", "--twomem", "/nonexistent/twomem"], "/nonexistent/twomem", 3),
], ids=["missing-case", "bad-method", "bad-sweep", "bad-set", "no-jobs", "no-executable"])
def test_bad_input_is_one_line(tmp_path, case, capsys, args, where, status):
    args = [str(case) if a == "CASE" else a for a in args]
    rc = main(["study", *args, "-o", str(tmp_path / "out")])
    captured = capsys.readouterr()
    assert rc == status
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"twomem_post: error: {where}: "), captured.err
    assert not (tmp_path / "out" / "summary.csv").exists()


def test_missing_case_from_the_shell(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "twomem_post", "study", "missing.nml", "-o",
                           "out"], capture_output=True, text=True, cwd=tmp_path,
                          env=env_with_package(), timeout=120)
    assert proc.returncode == 2
    assert proc.stderr == "twomem_post: error: missing.nml: no such case file\n"


# ----------------------------------------------------------------------------------------------
# the real program

def test_tiny_real_study(tmp_path, capsys):
    try:
        exe = find_twomem()
    except EnvironmentFailure as exc:
        pytest.skip(f"no twomem executable ({exc.why})")
    out = tmp_path / "study"
    rc = main(["study", str(REPO / "input" / "default.nml"), "--levels", "0,1", "--methods",
               "direct,inexact", "-o", str(out), "--twomem", str(exe)])
    captured = capsys.readouterr()
    assert rc == 0, captured.out + captured.err
    header, rows = read_csv(out / "summary.csv")
    assert header == SUMMARY_HEADER and len(rows) == 4
    assert all(r["status"] == "converged" and r["exit_code"] == "0" for r in rows)
    nt = {r["tag"]: int(r["nt"]) for r in rows}
    assert nt["direct_L0"] == nt["inexact_L0"] < nt["direct_L1"] == nt["inexact_L1"]
    assert [int(r["gmres_iterations"]) > 0 for r in rows] == [False, True, False, True]
    _, history = read_csv(out / "history.csv")
    assert {r["tag"] for r in history} == set(nt)
    for name in ("iterations", "work_precision"):
        assert (out / f"{name}.png").stat().st_size > 1000
