"""Shared helpers of the regression tests: run the twomem executable, read results."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import h5py
import numpy as np

EXE = os.environ.get("TWOMEM_EXE", "twomem")
SOURCE = Path(os.environ.get("TWOMEM_SOURCE_DIR", Path(__file__).resolve().parents[2]))
TMP = Path(os.environ.get("TWOMEM_TEST_TMP", "/tmp/twomem-tests"))
DEFAULT_CASE = SOURCE / "input" / "default.nml"
#: the MPI launcher CMake found (unset: a build without MPI, or none on the path)
MPIEXEC = os.environ.get("TWOMEM_MPIEXEC")


def run(*args: str, case: Path | str = DEFAULT_CASE, command: str = "run", check_rc: int | None = 0,
        cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run `twomem COMMAND CASE ARGS...`; assert the exit code unless check_rc is None."""
    proc = subprocess.run([EXE, command, str(case), *args], capture_output=True, text=True, cwd=cwd,
                          timeout=1800)
    if check_rc is not None and proc.returncode != check_rc:
        raise AssertionError(f"twomem {command} {case} {' '.join(args)} exited {proc.returncode}, "
                             f"expected {check_rc}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr}")
    return proc


def run_on_ranks(ranks: int, *args: str, case: Path | str = DEFAULT_CASE,
                 timeout: int = 600) -> subprocess.CompletedProcess:
    """Run `twomem run CASE ARGS...` on `ranks` MPI ranks (oversubscribed, one OpenMP thread each,
    as root too) from the source directory; assert exit code 0."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    command = [MPIEXEC or "mpirun", "--oversubscribe", "-n", str(ranks), EXE, "run", str(case), *args]
    # no stdin: mpirun forwards it to rank 0 and would stop in a background process group
    proc = subprocess.run(command, capture_output=True, text=True, cwd=SOURCE, env=env, timeout=timeout,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f"{' '.join(command)} exited {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr}"
    return proc


def result(path: Path | str) -> dict:
    """Mesh, fields and summary of a result file as numpy arrays."""
    with h5py.File(path, "r") as f:
        out = {"summary": {k: v for k, v in f["summary"].attrs.items()},
               "input": f.attrs["input"], "status": f.attrs["status"]}
        for name in ("vertices", "triangles"):
            if f"mesh/{name}" in f:
                out[name] = f[f"mesh/{name}"][()]
        for name in ("u1", "u2", "lambda"):
            if f"solution/{name}" in f:
                out[name] = f[f"solution/{name}"][()]
        if "error/energy" in f:
            out["energy"] = f["error/energy"][()]
    return out


def out_file(name: str) -> Path:
    TMP.mkdir(parents=True, exist_ok=True)
    return TMP / name
