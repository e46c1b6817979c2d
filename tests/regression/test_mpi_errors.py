"""Bad input and failures under MPI: on 3 ranks every kind of bad input ends the run on every
rank with the exit code of a serial run, the serial run's one error line printed once (by rank
0), no result file, and nothing hangs (each run has a time limit). Also the errors only a
distributed run can meet: a coarse mesh too small for the ranks, and preconditioners that act
on one rank's matrix.

Skipped when the build has no MPI (`twomem --version` says so) or mpirun is missing.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from twomem_testlib import EXE, SOURCE, out_file

RANKS = 3
TIME_LIMIT = 90  # seconds per run; a hang fails the test instead of blocking ctest
MESHES = SOURCE / "tests" / "data" / "meshes"
SMALL = ("mesh.coarse_h=0.5", "mesh.boundary_h=0.2", "mesh.levels=1", "estimate.enabled=.false.",
         "newton.linear=gmres")


def mpi_build() -> bool:
    version = subprocess.run([EXE, "--version"], capture_output=True, text=True, timeout=60).stdout
    return "MPI: none" not in version and shutil.which("mpirun") is not None


pytestmark = pytest.mark.skipif(not mpi_build(), reason="no MPI in this build, or no mpirun")


def mpi_env() -> dict[str, str]:
    # Open MPI refuses root without these; the tests run as whoever runs ctest
    return dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
                OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1")


def launch(args: list[str], ranks: int | None, cwd: Path) -> subprocess.CompletedProcess:
    cmd = [EXE, *args] if ranks is None else ["mpirun", "-n", str(ranks), "--oversubscribe", EXE, *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=mpi_env(), timeout=TIME_LIMIT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{' '.join(cmd)} did not end within {TIME_LIMIT} s")


def error_lines(proc: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.startswith("twomem: error:")]


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


DEFAULT = str(SOURCE / "input" / "default.nml")
# name: the arguments after `twomem`; {out} is the result file, {dir} a scratch directory
BAD = {
    "unknown-command": ["solve"],
    "missing-case": ["run", "{dir}/no_such.nml"],
    "namelist-type": ["run", "{dir}/levels_abc.nml", "output.file={out}"],
    "unknown-key": ["run", DEFAULT, *SMALL, "mesh.levle=1", "output.file={out}"],
    "nan-value": ["run", DEFAULT, *SMALL, "problem.g=nan", "output.file={out}"],
    "malformed-override": ["run", DEFAULT, *SMALL, "mesh.levels", "output.file={out}"],
    "missing-mesh": ["run", DEFAULT, *SMALL, "mesh.domain=gmsh", "mesh.file={dir}/none.msh",
                     "problem.exact=none", "output.file={out}"],
    "truncated-gmsh": ["run", DEFAULT, *SMALL, "mesh.domain=gmsh",
                       f"mesh.file={MESHES / 'broken' / 'truncated_nodes.msh'}", "problem.exact=none",
                       "output.file={out}"],
    "binary-gmsh": ["run", DEFAULT, *SMALL, "mesh.domain=gmsh", f"mesh.file={MESHES / 'broken' / 'binary.msh'}",
                    "problem.exact=none", "output.file={out}"],
    "check-bad-case": ["check", "{dir}/levels_abc.nml"],
    "unwritable-output": ["run", DEFAULT, *SMALL, "output.file={dir}/a_file/result.h5"],
    "not-converged": ["run", DEFAULT, *SMALL, "newton.initial=paper", "newton.max_it=1", "output.file={out}"],
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_input_stops_every_rank_like_a_serial_run(name):
    work = out_file(f"mpi-errors-{name}")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    write(work / "levels_abc.nml", "&mesh\n coarse_h = 0.5\n levels = 'abc'\n/\n")
    write(work / "a_file", "not a directory\n")
    outcomes = {}
    for ranks in (None, RANKS):
        out = work / f"result-{ranks or 1}.h5"
        args = [a.format(out=out, dir=work) for a in BAD[name]]
        proc = launch(args, ranks, work)
        outcomes[ranks] = (proc.returncode, error_lines(proc), out.exists())
    serial, parallel = outcomes[None], outcomes[RANKS]
    assert serial[0] != 0, f"{name}: the serial run succeeded: not a failure case"
    assert parallel[0] == serial[0], f"{name}: exit {parallel[0]} on {RANKS} ranks, {serial[0]} serial"
    assert parallel[1] == serial[1], f"{name}: error lines {parallel[1]} on {RANKS} ranks, {serial[1]} serial"
    assert len(serial[1]) == (0 if serial[0] == 1 else 1)
    assert parallel[2] == serial[2], f"{name}: result file written on one side only"
    leftovers = [p.name for p in work.iterdir() if ".tmp" in p.name]
    assert not leftovers, f"{name}: temporary files left: {leftovers}"


@pytest.mark.parametrize("args, fragment", [
    (["mesh.coarse_h=2", "mesh.boundary_h=2"], "too few to give each of 4 MPI ranks a part"),
    (["gmres.precond=ilu0"], "gmres.precond"),
    (["gmres.precond=jacobi"], "gmres.precond"),
])
def test_errors_of_distributed_runs(args, fragment):
    work = out_file("mpi-errors-distributed")
    work.mkdir(parents=True, exist_ok=True)
    out = work / "result.h5"
    out.unlink(missing_ok=True)
    base = [a for a in SMALL if not any(a.split("=")[0] == b.split("=")[0] for b in args)]
    proc = launch(["run", DEFAULT, *base, *args, f"output.file={out}"], 4, work)
    lines = error_lines(proc)
    assert proc.returncode == 2 and len(lines) == 1 and fragment in lines[0], proc.stdout[-2000:] + proc.stderr
    assert not out.exists()
