"""The command-line contract of `twomem` (docs/input.md, docs/usage.md), probed as a demanding user.

Every bad input (usage, namelist file, override, mesh file) must exit 2, every output that
cannot be written must exit 3 before any solving, and each must print exactly one stderr line
`twomem: error: <where>: <what>` naming the file and line / group / key, with no Fortran
runtime noise and no result file (.h5, .xdmf, *.tmp-*, *.probe-*) left behind. `check`
writes nothing; a run writes the .h5 and .xdmf atomically, exits 1 (with `status` saying why)
when it does not converge, and its stored `input` attribute is itself a valid case file.
All cases use tiny meshes (one coarse level), so each takes a fraction of a second.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import h5py
import pytest

from twomem_testlib import EXE, SOURCE, TMP

MESHES = SOURCE / "tests" / "data" / "meshes"
BROKEN = sorted((MESHES / "broken").glob("*.msh"))
GOOD_MESHES = sorted(MESHES.glob("*.msh"))
NOISE = ("STOP", "Backtrace", "Error termination", "Program received signal")
# a tiny valid case: one coarse level, the only linear solver of this version
TINY = "&mesh levels = 0, coarse_h = 0.5 /\n&newton linear = 'direct' /\n"
PREFIX = "twomem: error: "


@pytest.fixture
def work(request) -> Path:
    """A fresh directory per test under TWOMEM_TEST_TMP."""
    d = TMP / "cli" / re.sub(r"[^\w.-]+", "_", request.node.name)[:100]
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    return d


def twomem(*args, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([EXE, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=120)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def no_noise(proc: subprocess.CompletedProcess) -> None:
    for word in NOISE:
        assert word not in proc.stdout and word not in proc.stderr, f"runtime noise {word!r}"


def leftovers(directory: Path) -> list[Path]:
    """Result files, temporaries and probes below `directory`."""
    if not directory.exists():
        return []
    return sorted(p for p in directory.rglob("*") if p.is_file()
                  and (p.suffix in (".h5", ".xdmf") or ".tmp-" in p.name or ".probe-" in p.name))


def solved(proc: subprocess.CompletedProcess) -> bool:
    """Did the run get as far as the Newton solver?"""
    return bool(re.search(r"^(problem:|newton\s)", proc.stdout, re.M))


def error_line(proc: subprocess.CompletedProcess, code: int, out: Path | None = None) -> str:
    """Assert the bad-input contract and return the message (after the prefix)."""
    detail = f"\nstdout:\n{proc.stdout[-2000:]}\nstderr:\n{proc.stderr}"
    assert proc.returncode == code, f"exit {proc.returncode}, expected {code}{detail}"
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, f"stderr must be exactly one line{detail}"
    assert lines[0].startswith(PREFIX), detail
    no_noise(proc)
    if out is not None:
        assert leftovers(out) == [], f"files left behind{detail}"
        assert not solved(proc), f"failed only after solving{detail}"
    return lines[0][len(PREFIX):]


# --- usage -----------------------------------------------------------------------------------

@pytest.mark.parametrize("args, fragment", [
    pytest.param([], "", id="no-arguments"),
    pytest.param(["solve"], "unknown command 'solve'", id="unknown-command"),
    pytest.param(["RUN"], "unknown command 'RUN'", id="command-is-case-sensitive"),
    pytest.param(["run"], "missing CASE.nml", id="run-without-case"),
    pytest.param(["check"], "missing CASE.nml", id="check-without-case"),
    pytest.param(["run", "no/such/case.nml"], "no/such/case.nml: ", id="case-missing"),
    pytest.param(["check", "no_such.nml"], "no_such.nml: ", id="check-case-missing"),
    pytest.param(["run", "."], ".: ", id="case-is-directory"),
    pytest.param(["run", "--help"], "--help: ", id="option-as-case-file"),
])
def test_usage_errors(work, args, fragment):
    proc = twomem(*args, cwd=work)
    assert fragment in error_line(proc, 2, work)
    assert list(work.iterdir()) == [], "a usage error must create nothing"


def test_case_is_directory_names_it(work):
    msg = error_line(twomem("check", work), 2)
    assert msg.startswith(f"{work}: ") and "directory" in msg


@pytest.mark.parametrize("args, expect", [
    (["--help"], "usage: twomem run CASE.nml"), (["-h"], "usage: twomem run CASE.nml"),
    (["help"], "usage: twomem run CASE.nml"), (["--version"], "twomem "), (["-V"], "twomem "),
])
def test_help_and_version(work, args, expect):
    proc = twomem(*args, cwd=work)
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.startswith(expect)
    no_noise(proc)
    if expect == "twomem ":
        m = re.fullmatch(r"twomem \d+\.\d+\.\d+\S*\nMPI: [^\n]+\nUMFPACK: \d+\.\d+\.\d+, BLAS (\S+)[^\n]*\n", proc.stdout)
        assert m, proc.stdout
        assert Path(m.group(1)).is_file(), f"the BLAS named is not a file: {m.group(1)}"


REFERENCE_BLAS = Path("/usr/lib/x86_64-linux-gnu/blas")


@pytest.mark.skipif(not (REFERENCE_BLAS / "libblas.so.3").exists(), reason="no Debian reference BLAS here")
def test_version_names_the_blas_the_process_loaded(work):
    """The BLAS line names the library whose dgemm_ UMFPACK calls, not the one the build saw:
    with the reference BLAS put first on the library path, that is the one named."""
    env = dict(os.environ, LD_LIBRARY_PATH=str(REFERENCE_BLAS))
    proc = subprocess.run([EXE, "--version"], capture_output=True, text=True, timeout=60, env=env, cwd=work)
    assert proc.returncode == 0, proc.stderr
    line = [l for l in proc.stdout.splitlines() if l.startswith("UMFPACK: ")]
    assert line and f"BLAS {REFERENCE_BLAS}/libblas.so.3" in line[0] and "OpenBLAS" not in line[0], proc.stdout


# --- namelist files: (text, line, group, key, fragment) ---------------------------------------

NML_ERRORS = {
    "unknown-group": (TINY + "&nosuch\n x = 1\n/\n", 3, "&nosuch", None, "unknown group"),
    "unknown-key": ("&mesh\n levels = 0, coarse_h = 0.5\n levle = 0\n/\n", 3, "&mesh", "levle", "unknown key"),
    "int-got-string": ("&mesh\n coarse_h = 0.5\n levels = 'abc'\n/\n", 3, "&mesh", "levels", "integer"),
    "int-got-real": ("&mesh\n coarse_h = 0.5\n levels = 4.0\n/\n", 3, "&mesh", "levels", "integer"),
    "int-overflow": ("&mesh\n levels = 99999999999999999999\n/\n", 2, "&mesh", "levels", "range"),
    "real-got-word": ("&mesh\n levels = 0\n coarse_h = abc\n/\n", 3, "&mesh", "coarse_h", "real"),
    "logical-got-word": (TINY + "&output\n xdmf = maybe\n/\n", 4, "&output", "xdmf", "logical"),
    "levels-negative": ("&mesh\n coarse_h = 0.5\n levels = -1\n/\n", 3, "&mesh", "levels", "-1"),
    "levels-too-large": ("&mesh\n coarse_h = 0.5\n levels = 13\n/\n", 3, "&mesh", "levels", "13"),
    "coarse_h-zero": ("&mesh\n levels = 0\n coarse_h = 0\n/\n", 3, "&mesh", "coarse_h", "0"),
    "mu1-negative": (TINY + "&problem\n mu1 = -1\n/\n", 4, "&problem", "mu1", "> 0"),
    "g-zero": (TINY + "&problem\n g = 0\n/\n", 4, "&problem", "g", "> 0"),
    "max_it-zero": ("&mesh levels = 0, coarse_h = 0.5 /\n&newton\n max_it = 0\n/\n", 3, "&newton", "max_it", "0"),
    "g-nan": (TINY + "&problem\n g = nan\n/\n", 4, "&problem", "g", "finite"),
    "coarse_h-inf": ("&mesh\n levels = 0\n coarse_h = inf\n/\n", 3, "&mesh", "coarse_h", ""),
    "f1-minus-inf": (TINY + "&problem\n f1 = -Infinity\n/\n", 4, "&problem", "f1", ""),
    "real-overflow": ("&mesh\n levels = 0\n coarse_h = 1e999\n/\n", 3, "&mesh", "coarse_h", ""),
    "domain-moon": ("&mesh\n levels = 0\n domain = 'moon'\n/\n", 3, "&mesh", "domain", "'moon'"),
    "cfun-word": ("&mesh levels = 0, coarse_h = 0.5 /\n&newton\n cfun = 'max'\n/\n", 3, "&newton", "cfun", "'max'"),
    "gmsh-without-file": ("&mesh\n levels = 0\n domain = 'gmsh'\n/\n", 3, "&mesh", "file", ""),
    "file-without-gmsh": ("&mesh\n levels = 0\n file = 'a.msh'\n/\n", 3, "&mesh", "file", ""),
    "radial-on-square": ("&mesh domain = 'square', levels = 0 /\n&problem\n exact = 'radial'\n/\n",
                         3, "&problem", "exact", "disk"),
    "unterminated-string": ("&mesh\n levels = 0\n domain = 'disk\n/\n", 3, "&mesh", "domain", "unterminated"),
    "missing-slash-at-eof": ("&mesh\n levels = 0\n", 1, "&mesh", None, "'/'"),
    "missing-slash-before-group": ("&mesh\n levels = 0\n&problem\n/\n", 3, "&mesh", None, "'/'"),
    "duplicate-key": ("&mesh\n levels = 0\n coarse_h = 0.5\n levels = 1\n/\n", 4, "&mesh", "levels", "twice"),
    "duplicate-group": ("&mesh levels = 0 /\n&problem /\n&mesh levels = 1 /\n", 3, "&mesh", None, "twice"),
    "stray-text": (TINY + "hello\n", 3, "", None, "hello"),
    "text-after-slash": ("&mesh\n levels = 0\n/ junk\n", 3, "", None, "junk"),
    "two-values": (TINY + "&problem\n mu1 = 1.0 2.0\n/\n", 4, "&problem", None, "2.0"),
    "null-value": ("&mesh\n levels = ,\n/\n", 2, "&mesh", "levels", "missing value"),
    "repeat-count": (TINY + "&problem\n mu1 = 3*1.0\n/\n", 4, "&problem", "mu1", "3*1.0"),
    "array-element": (TINY + "&problem\n mu1(1) = 1.0\n/\n", 4, "&problem", "mu1(1)", ""),
    "no-equals": ("&mesh\n levels 0\n/\n", 2, "&mesh", "levels", "'='"),
    "no-key": ("&mesh\n = 0\n/\n", 2, "&mesh", None, "'='"),
    "no-group-name": ("&\n/\n", 1, "", None, "group name"),
    "binary-garbage": ("\x7f\x01\x02 &mesh\n/\n", 1, "", None, ""),
}


@pytest.mark.parametrize("command", ["check", "run"])
@pytest.mark.parametrize("name", list(NML_ERRORS))
def test_namelist_file_errors(work, name, command):
    text, line, group, key, fragment = NML_ERRORS[name]
    case = write(work / "case.nml", text)
    out = work / "out"
    msg = error_line(twomem(command, case, f"output.file={out / 'a.h5'}"), 2, out)
    assert msg.startswith(f"{case}:{line}: "), msg
    assert group in msg and fragment in msg, msg
    if key is not None:
        assert re.search(rf"(^|\W){re.escape(key)}(\W|$)", msg), msg
    assert not out.exists(), "bad input must create no output directory"


# --- overrides ---------------------------------------------------------------------------------

OVERRIDE_ERRORS = {
    "mesh.levels=x": "integer",
    "nosuch.key=1": "unknown group 'nosuch'",
    "mesh.nosuchkey=1": "unknown key 'nosuchkey'",
    "mesh.levels": "'='",
    "mesh.levels=": "missing value",
    "levels=1": "'.'",
    "": "",
    "problem.g=nan": "finite",
    "problem.mu2=-inf": "finite",
    "problem.f1=1e999": "range",
    "mesh.levels=1 2": "integer",
    "mesh.levels=-1": "levels",
    "problem.mu1=0": "mu1",
    "newton.max_it=0": "max_it",
    "gmres.restart=0": "restart",
    "mesh.domain=moon": "'moon'",
    "mesh.domain='disk": "unterminated",
    "output.xdmf=maybe": "logical",
    "mesh.domain=gmsh": "file",
    "mesh.file=a.msh": "file",
    "problem.exact=radial": "disk",  # after mesh.domain=square
    "mesh.domain=" + "a" * 300: "256",
    "adapt.tol=-1": "tol",
    "adapt.tol=nan": "finite",
    "adapt.theta=0": "theta",
    "adapt.theta=1.5": "theta",
    "adapt.max_steps=0": "max_steps",
    "adapt.max_vertices=2": "max_vertices",
    "adapt.size=3": "max_vertices",
}


@pytest.mark.parametrize("command", ["check", "run"])
@pytest.mark.parametrize("override", list(OVERRIDE_ERRORS), ids=lambda s: s[:40] or "empty")
def test_override_errors(work, override, command):
    case = write(work / "case.nml", TINY)
    out = work / "out"
    pre = ["mesh.domain=square"] if override.startswith("problem.exact") else []
    msg = error_line(twomem(command, case, f"output.file={out / 'a.h5'}", *pre, override), 2, out)
    # a long override is quoted by its first 80 characters
    shown = override if len(override) <= 80 else override[:80] + "..."
    assert msg.startswith(f"override '{shown}': "), msg
    assert OVERRIDE_ERRORS[override] in msg, msg
    assert not out.exists()


# --- mesh files ----------------------------------------------------------------------------------

@pytest.mark.parametrize("command", ["check", "run"])
@pytest.mark.parametrize("mesh", BROKEN + ["missing.msh", "."], ids=lambda p: Path(p).stem or "directory")
def test_mesh_file_errors(work, mesh, command):
    mesh = MESHES / "broken" / mesh if isinstance(mesh, str) else mesh
    case = write(work / "case.nml", TINY)
    out = work / "out"
    proc = twomem(command, case, "mesh.domain=gmsh", f"mesh.file={mesh}", f"output.file={out / 'a.h5'}")
    msg = error_line(proc, 2, out)
    assert msg.startswith(f"{mesh}:") or msg.startswith(f"{mesh.resolve()}:"), msg


def test_broken_mesh_count():
    assert len(BROKEN) >= 20, "the broken-mesh collection went missing"


def test_bad_mesh_creates_no_output_directory(work):
    case = write(work / "case.nml", TINY)
    out = work / "out" / "sub"
    proc = twomem("run", case, "mesh.domain=gmsh", f"mesh.file={BROKEN[0]}", f"output.file={out / 'a.h5'}")
    error_line(proc, 2, out)
    assert not (work / "out").exists()


@pytest.mark.parametrize("mesh", GOOD_MESHES, ids=lambda p: p.stem)
def test_check_accepts_good_meshes(work, mesh):
    proc = twomem("check", write(work / "case.nml", TINY), "mesh.domain=gmsh", f"mesh.file={mesh}",
                  f"output.file={work / 'out' / 'a.h5'}")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert not (work / "out").exists()


# --- output that cannot be written: exit 3, before solving ----------------------------------------

def _unwritable(work: Path, kind: str) -> str:
    if kind == "proc":
        return "/proc/nope/a.h5"
    if kind in ("parent-is-file", "grandparent-is-file"):
        write(work / "plain", "not a directory\n")
        return str(work / "plain" / ("a.h5" if kind == "parent-is-file" else "sub/a.h5"))
    if kind == "target-is-directory":
        (work / "out" / "a.h5").mkdir(parents=True)
        return str(work / "out" / "a.h5")
    if kind == "trailing-slash":
        return f"{work / 'out'}/"
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["proc", "parent-is-file", "grandparent-is-file", "trailing-slash",
                                  "target-is-directory"])
def test_unwritable_output(work, kind):
    target = _unwritable(work, kind)
    case = write(work / "case.nml", TINY)
    proc = twomem("run", case, f"output.file={target}")
    msg = error_line(proc, 3, work)  # also: nothing left, and no Newton step was taken
    where = msg.split(": ", 1)[0]
    assert where and target.startswith(where.rstrip("/")), f"message must name the path: {msg}"
    assert not Path(target).with_suffix(".xdmf").exists()
    if kind == "target-is-directory":
        assert list(Path(target).iterdir()) == []


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root can write anywhere")
def test_read_only_directory(work):
    (work / "ro").mkdir()
    (work / "ro").chmod(0o555)
    proc = twomem("run", write(work / "case.nml", TINY), f"output.file={work / 'ro' / 'a.h5'}")
    assert error_line(proc, 3, work).startswith(str(work / "ro"))


def test_failed_run_keeps_previous_result(work):
    case = write(work / "case.nml", TINY)
    target = work / "out" / "a.h5"
    assert twomem("run", case, f"output.file={target}").returncode == 0
    before = target.read_bytes()
    error_line(twomem("run", case, f"output.file={target}", "mesh.domain=gmsh", "mesh.file=missing.msh"), 2)
    error_line(twomem("run", case, f"output.file={target}", "mesh.levels=x"), 2)
    assert target.read_bytes() == before
    assert leftovers(work / "out") == [target, target.with_suffix(".xdmf")]


# --- valid runs ---------------------------------------------------------------------------------

def test_check_prints_resolved_input_and_writes_nothing(work):
    case = write(work / "case.nml", TINY)
    proc = twomem("check", case, cwd=work)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    no_noise(proc)
    for group in ("mesh", "problem", "newton", "gmres", "estimate", "output"):
        assert re.search(rf"^&{group}$", proc.stdout, re.M), group
    assert re.search(r"^\s*levels = 0$", proc.stdout, re.M)
    assert re.search(r"^\s*file = 'results/case\.h5'$", proc.stdout, re.M), "output.file not resolved"
    assert not solved(proc)
    assert sorted(p.name for p in work.iterdir()) == ["case.nml"], "check must write nothing"


def test_successful_run_writes_result_and_sidecar(work):
    case = write(work / "case.nml", TINY)
    target = work / "out" / "tiny.h5"
    proc = twomem("run", case, f"output.file={target}")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    no_noise(proc)
    assert re.search(r"^newton\s+0\s", proc.stdout, re.M), "one progress line per Newton step"
    assert f"result: {target}" in proc.stdout
    assert leftovers(work / "out") == [target, target.with_suffix(".xdmf")]
    with h5py.File(target, "r") as f:
        status = f.attrs["status"]
        assert "converged" in status and "not" not in status.lower(), status
        assert f.attrs["version"] and "/mesh/vertices" in f and "/solution/u1" in f
        assert re.match(r"\d+\.\d+\.\d+, BLAS /", f.attrs["umfpack"]), f.attrs["umfpack"]


def test_default_output_file_is_relative_to_cwd(work):
    write(work / "mycase.nml", TINY)
    proc = twomem("run", "mycase.nml", "output.file=''", cwd=work)
    assert proc.returncode == 0, proc.stderr
    assert leftovers(work) == [work / "results" / "mycase.h5", work / "results" / "mycase.xdmf"]


def test_not_converged_exits_1_and_still_writes(work):
    case = write(work / "case.nml", TINY)
    target = work / "out" / "nc.h5"
    proc = twomem("run", case, "newton.max_it=1", f"output.file={target}")
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr
    no_noise(proc)
    assert leftovers(work / "out") == [target, target.with_suffix(".xdmf")]
    with h5py.File(target, "r") as f:
        status = f.attrs["status"]
        assert "not converged" in status and ("max_it" in status or "limit" in status), status
        assert f["summary"].attrs["newton_iterations"] == 1


def test_stored_input_reloads(work):
    case = write(work / "case.nml", TINY)
    target = work / "out" / "a.h5"
    overrides = ["problem.f1=0.1", "problem.mu2=1.7", "mesh.coarse_h=0.3", "newton.tol=1.234567890123457e-9",
                 "output.estimators=F", f"output.file={target}"]
    assert twomem("run", case, *overrides).returncode == 0
    with h5py.File(target, "r") as f:
        stored = f.attrs["input"]
    stored = stored.decode() if isinstance(stored, bytes) else stored
    reloaded = write(work / "reloaded.nml", stored)
    proc = twomem("check", reloaded)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    body = [line for line in stored.splitlines() if line and not line.startswith("!")]
    echo = proc.stdout.splitlines()
    start = echo.index(body[0])
    assert echo[start:start + len(body)] == body, "the reloaded case must resolve to the same input"
    assert "   estimators = .false." in body and not (work / "out" / "reloaded.h5").exists()


@pytest.mark.parametrize("file_text, overrides, expect", [
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["mesh.levels=1"], "levels = 1"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["mesh.levels=1", "mesh.levels=0"], "levels = 0"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["MESH.Levels=1"], "levels = 1"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["mesh.coarse_h=0.75"], "coarse_h = 0.75"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n&problem mu1 = -1 /\n", ["problem.mu1=2"], "mu1 = 2.0"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n&problem f1 = 1 /\n", ["problem.f1=1.d-3"], "f1 = 0.001"),
    ("&mesh domain = 'gmsh', file = 'gone.msh', levels = 0 /\n", ["mesh.domain=disk", "mesh.file=''",
                                                                  "mesh.coarse_h=0.5"], "domain = 'disk'"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["mesh.domain='SQUARE'"], "domain = 'square'"),
    ("&mesh levels = 0, coarse_h = 0.5 /\n", ["output.xdmf=F"], "xdmf = .false."),
])
def test_overrides_apply_after_file(work, file_text, overrides, expect):
    case = write(work / "case.nml", file_text + "&newton linear = 'direct' /\n")
    proc = twomem("check", case, *overrides, f"output.file={work / 'out' / 'a.h5'}")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert re.search(rf"^\s*{re.escape(expect)}$", proc.stdout, re.M), proc.stdout
    assert not (work / "out").exists()
