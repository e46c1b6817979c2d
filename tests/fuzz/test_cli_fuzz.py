"""The executable on a sample of the fuzzer's inputs: the bad-input contract end to end.

`twomem_fuzz TARGET DIR` writes the inputs the in-process fuzzer would parse; here each goes
through `twomem check` (and, for meshes, `twomem run`) as a user would pass it. Whatever the
input, the process must end by itself within the timeout with exit 0 (valid) or 2 (bad input),
a run also 1 (not converged) or 3; a failure prints exactly one stderr line
`twomem: error: <file or override>: ...` with no Fortran runtime noise, and leaves no result
file behind; `check` writes nothing at all.

TWOMEM_FUZZ_CLI_COUNT inputs per target (default 100) starting at TWOMEM_FUZZ_CLI_FIRST
(default 1000000, so they are not the ones the in-process test already parses), seed
TWOMEM_FUZZ_SEED (default 1).
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

EXE = os.environ.get("TWOMEM_EXE", "twomem")
FUZZ = os.environ.get("TWOMEM_FUZZ_EXE", "twomem_fuzz")
SOURCE = Path(os.environ.get("TWOMEM_SOURCE_DIR", Path(__file__).resolve().parents[2]))
TMP = Path(os.environ.get("TWOMEM_TEST_TMP", "/tmp/twomem-tests")) / "cli-fuzz"
COUNT = int(os.environ.get("TWOMEM_FUZZ_CLI_COUNT", "100"))
FIRST = int(os.environ.get("TWOMEM_FUZZ_CLI_FIRST", "1000000"))
TIMEOUT = 120
PREFIX = b"twomem: error: "
NOISE = (b"STOP", b"Backtrace", b"Error termination", b"Program received signal", b"runtime error",
         b"AddressSanitizer", b"LeakSanitizer")
# keeps every check to one coarse mesh, so that a slow input is a hang and not a big mesh; it
# comes after the fuzzed overrides and so cannot mask a syntax or conversion error in them
SMALL = [b"mesh.levels=0", b"mesh.coarse_h=0.5", b"mesh.boundary_h=0"]
TINY_GMSH = "&mesh domain = 'gmsh', levels = 0 /\n&newton linear = 'direct' /\n"


def samples(target: str) -> list[Path]:
    """The inputs of `target`, written by the fuzz driver into a fresh directory."""
    d = TMP / "inputs" / target
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    env = dict(os.environ, TWOMEM_FUZZ_COUNT=str(COUNT), TWOMEM_FUZZ_FIRST=str(FIRST),
               TWOMEM_TEST_TMP=str(d))
    subprocess.run([FUZZ, target, str(d)], env=env, check=True, timeout=TIMEOUT, capture_output=True)
    files = sorted(p for p in d.iterdir() if p.name.startswith(target + "-"))
    assert len(files) == COUNT, f"the fuzz driver wrote {len(files)} {target} inputs, not {COUNT}"
    return files


def files_below(d: Path) -> set[Path]:
    return {p for p in d.rglob("*")}


def twomem(args: list[bytes], cwd: Path) -> subprocess.CompletedProcess:
    try:
        return subprocess.run([os.fsencode(EXE), *args], capture_output=True, cwd=cwd, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"hang: twomem {b' '.join(args)!r} ran longer than {TIMEOUT} s")


def contract(proc: subprocess.CompletedProcess, codes: tuple[int, ...], names: tuple[bytes, ...],
             what: str) -> None:
    """Exit code in `codes`; on failure one clean stderr line naming one of `names`."""
    detail = f"{what}: exit {proc.returncode}\nstderr: {proc.stderr[:2000]!r}\nstdout tail: {proc.stdout[-1500:]!r}"
    assert proc.returncode in codes, detail
    for word in NOISE:
        assert word not in proc.stdout and word not in proc.stderr, f"runtime noise {word!r}; {detail}"
    if proc.returncode == 0:
        assert proc.stderr == b"", detail
        return
    lines = proc.stderr.split(b"\n")
    assert len(lines) == 2 and lines[1] == b"", f"stderr must be exactly one line; {detail}"
    assert lines[0].startswith(PREFIX), detail
    message = lines[0][len(PREFIX):]
    assert any(message.startswith(n) for n in names), f"the message names neither of {names}; {detail}"
    assert all(c >= 32 and c != 127 for c in message), f"control character in the message; {detail}"


@pytest.fixture(scope="module")
def gmsh_inputs() -> list[Path]:
    return samples("gmsh")


def test_check_mutated_meshes(gmsh_inputs):
    work = TMP / "gmsh-check"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    case = work / "case.nml"
    case.write_text(TINY_GMSH)
    before = files_below(work)
    for mesh in gmsh_inputs:
        proc = twomem([b"check", bytes(case), b"mesh.file=" + bytes(mesh)], work)
        contract(proc, (0, 2), (bytes(mesh) + b":", bytes(mesh) + b" "), mesh.name)
        assert files_below(work) == before, f"{mesh.name}: check wrote files"


def test_run_mutated_meshes(gmsh_inputs):
    """A rejected mesh leaves no result behind; an accepted one is solved and written whole."""
    work = TMP / "gmsh-run"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    case = work / "case.nml"
    case.write_text(TINY_GMSH)
    out = work / "out"
    solved = 0
    for mesh in gmsh_inputs:
        shutil.rmtree(out, ignore_errors=True)
        result = out / "a.h5"
        proc = twomem([b"run", bytes(case), b"mesh.file=" + bytes(mesh), b"output.file=" + bytes(result)], work)
        contract(proc, (0, 1, 2, 3), (bytes(mesh) + b":", bytes(mesh) + b" ", b"mesh:"), mesh.name)
        left = sorted(p.name for p in out.rglob("*")) if out.exists() else []
        if proc.returncode in (0, 1):
            solved += 1
            assert left == ["a.h5", "a.xdmf"], f"{mesh.name}: exit {proc.returncode} but files {left}"
        else:
            assert left == [], f"{mesh.name}: exit {proc.returncode} left {left}"
    print(f"{solved} of {len(gmsh_inputs)} mutated meshes solved")


def test_check_mutated_case_files():
    work = TMP / "namelist-check"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    before = files_below(work)
    for case in samples("namelist"):
        proc = twomem([b"check", bytes(case), *SMALL], work)
        contract(proc, (0, 2), (bytes(case) + b":", b"override '"), case.name)
        assert files_below(work) == before, f"{case.name}: check wrote files"


def test_check_mutated_overrides():
    work = TMP / "override-check"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    case = work / "base.nml"
    shutil.copy(SOURCE / "input" / "default.nml", case)
    before = files_below(work)
    for sample in samples("override"):
        overrides = sample.read_bytes().split(b"\0")
        proc = twomem([b"check", bytes(case), *overrides, *SMALL], work)
        contract(proc, (0, 2), (bytes(case), b"override '"), f"{sample.name} {overrides!r}")
        assert files_below(work) == before, f"{sample.name}: check wrote files"
