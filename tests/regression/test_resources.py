"""Resource limits and interruption (docs/robustness.md, "Memory" and "Signals").

* A run (or `check`) that cannot fit in memory is refused before any refinement: exit 2, one
  line `twomem: error: mesh.levels: N levels need about X GB, this machine allows Y GB (...)`,
  nothing written; the limit may come from the machine or from `ulimit -v` (RLIMIT_AS, set
  here in the child).
* An allocation that fails anyway (the refusal switched off by TWOMEM_MEMORY_CHECK=off) ends
  with exit 3 and one line, never gfortran's backtrace and exit 1.
* SIGTERM / SIGINT during a run: `twomem: interrupted by SIGTERM` (SIGINT), exit 143 (130), no
  temporary file, an older result of the same name intact; under mpirun every rank stops.
* No array as large as the mesh lives on the stack: a run of 1.5·10^5 vertices fits in a
  512 KiB stack (the estimators' patch code keeps its temporaries there, CMakeLists.txt; a
  whole-mesh temporary among them crashed runs of 4·10^6 vertices in the default 8 MiB).
"""
from __future__ import annotations

import hashlib
import os
import re
import resource
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from twomem_testlib import DEFAULT_CASE, EXE, TMP

NOISE = ("Backtrace", "Error termination", "Program received signal", "STOP")
# AddressSanitizer reserves terabytes of address space: an RLIMIT_AS makes it fail at start
UNDER_ASAN = "ASAN_OPTIONS" in os.environ


@pytest.fixture
def work(request) -> Path:
    d = TMP / "resources" / re.sub(r"[^\w.-]+", "_", request.node.name)[:100]
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    return d


def limit_address_space(gib: float):
    def apply() -> None:
        size = int(gib * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (size, size))
    return apply


def twomem(*args, env: dict | None = None, preexec=None) -> subprocess.CompletedProcess:
    return subprocess.run([EXE, *map(str, args)], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})}, preexec_fn=preexec)


def one_error_line(proc: subprocess.CompletedProcess, code: int) -> str:
    detail = f"\nstdout:\n{proc.stdout[-1500:]}\nstderr:\n{proc.stderr[-3000:]}"
    assert proc.returncode == code, f"exit {proc.returncode}, expected {code}{detail}"
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("twomem: error: "), detail
    for word in NOISE:
        assert word not in proc.stderr and word not in proc.stdout, f"runtime noise {word!r}{detail}"
    return lines[0][len("twomem: error: "):]


def files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob("*") if p.is_file())


SIZE = re.compile(r"^mesh\.levels: (\d+) levels need about ([\d.]+) GB, this machine allows ([\d.]+) GB \((.+)\)$")


@pytest.mark.parametrize("command", ["check", "run"])
def test_absurd_size_is_refused_up_front(work, command):
    start = time.monotonic()
    # the case of the bug report: under 8 GB it died in an allocation, with a backtrace
    proc = twomem(command, DEFAULT_CASE, "mesh.levels=7", f"output.file={work / 'a.h5'}")
    msg = one_error_line(proc, 2)
    m = SIZE.match(msg)
    assert m, msg
    assert int(m[1]) == 7 and float(m[2]) > float(m[3]) > 0
    assert files(work) == []
    # refused from the coarse mesh, not after refining it
    assert time.monotonic() - start < 60
    assert "level  1:" not in proc.stdout


def test_size_beyond_32_bit_indices_is_refused(work):
    msg = one_error_line(twomem("check", DEFAULT_CASE, "mesh.levels=9"), 2)
    assert re.fullmatch(r"mesh\.levels: 9 levels make about \S+ vertices; 32-bit indices allow about \S+ "
                        r"\(use fewer levels or more MPI ranks\)", msg), msg


@pytest.mark.skipif(UNDER_ASAN, reason="RLIMIT_AS and AddressSanitizer do not mix")
def test_ulimit_v_is_the_limit_seen(work):
    # 5 levels: about 4 GB with the default method (4 levels, 0.7 GB, fit)
    proc = twomem("run", DEFAULT_CASE, "mesh.levels=5", f"output.file={work / 'a.h5'}",
                  preexec=limit_address_space(1.0))
    m = SIZE.match(one_error_line(proc, 2))
    assert m and "ulimit -v" in m[4], proc.stderr
    # what the process already maps counts against the limit
    assert float(m[3]) < 1.0 * 2**30 / 1e9
    assert files(work) == []
    # a small run under the same limit is not refused
    small = twomem("run", DEFAULT_CASE, "mesh.levels=1", f"output.file={work / 'b.h5'}",
                   preexec=limit_address_space(1.0))
    assert small.returncode == 0, small.stderr
    assert files(work) == ["b.h5", "b.xdmf"]


@pytest.mark.skipif(UNDER_ASAN, reason="RLIMIT_AS and AddressSanitizer do not mix")
def test_failed_allocation_is_one_line_and_exit_3(work):
    target = work / "a.h5"
    target.write_bytes(b"an older result")
    proc = twomem("run", DEFAULT_CASE, "mesh.levels=6", f"output.file={target}",
                  env={"TWOMEM_MEMORY_CHECK": "off"}, preexec=limit_address_space(1.0))
    msg = one_error_line(proc, 3)
    assert msg.startswith("out of memory: "), msg
    assert target.read_bytes() == b"an older result"
    assert files(work) == ["a.h5"]


def limit_stack(kib: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_STACK, (kib * 1024, resource.RLIM_INFINITY))
    return apply


@pytest.mark.skipif(UNDER_ASAN, reason="AddressSanitizer's redzones need a larger stack")
@pytest.mark.parametrize("extra", [[], ["estimate.flux=rt0", "newton.cfun=fb", "estimate.checks=all"]],
                         ids=["rt1_min", "rt0_fb_all_checks"])
def test_no_mesh_sized_array_on_the_stack(work, extra):
    # a pack over the vertices in the patch tables' set-up (600 KB here) did not fit
    proc = twomem("run", DEFAULT_CASE, "mesh.levels=4", *extra, f"output.file={work / 'a.h5'}",
                  env={"OMP_NUM_THREADS": "1"}, preexec=limit_stack(512))
    assert proc.returncode == 0, f"exit {proc.returncode}\nstderr:\n{proc.stderr[-2000:]}"
    assert "151225 vertices" in proc.stdout


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def wait_for(proc: subprocess.Popen, pattern: str, out: Path, seconds: float = 120) -> None:
    """Wait until the run's standard output (redirected to `out`) shows `pattern`."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if re.search(pattern, out.read_text(errors="replace"), re.M):
            return
        assert proc.poll() is None, f"the run ended before {pattern!r}:\n{out.read_text()[-2000:]}"
        time.sleep(0.05)
    raise AssertionError(f"no {pattern!r} within {seconds} s")


def old_result(work: Path) -> tuple[Path, str]:
    """A finished small run's result, to be overwritten by the interrupted run."""
    target = work / "out" / "result.h5"
    first = twomem("run", DEFAULT_CASE, "mesh.levels=0", f"output.file={target}")
    assert first.returncode == 0, first.stderr
    return target, digest(target)


# gfortran buffers standard output sent to a file: unbuffered, the progress lines show when the
# run gets there
UNBUFFERED = {**os.environ, "GFORTRAN_UNBUFFERED_PRECONNECTED": "y"}

# a run that takes several seconds in every build: the signal arrives while it solves
LONG = ["mesh.levels=4", "newton.linear=gmres", "estimate.enabled=.false.", "gmres.precond=ilu0"]


@pytest.mark.parametrize("signo, name", [(signal.SIGTERM, "SIGTERM"), (signal.SIGINT, "SIGINT")])
@pytest.mark.parametrize("when", ["solving", "starting"])
def test_signal_ends_the_run_cleanly(work, signo, name, when):
    target, before = old_result(work)
    out = work / "stdout.txt"
    with open(out, "w") as stdout:
        proc = subprocess.Popen([EXE, "run", DEFAULT_CASE, *LONG, f"output.file={target}"], stdout=stdout,
                                stderr=subprocess.PIPE, text=True, env=UNBUFFERED)
        try:
            wait_for(proc, r"^problem:" if when == "solving" else r"^mesh:", out)
            proc.send_signal(signo)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 128 + signo, f"exit {proc.returncode}\n{err}\n{out.read_text()[-2000:]}"
    assert err == f"twomem: interrupted by {name}\n"
    assert digest(target) == before
    assert files(work / "out") == ["result.h5", "result.xdmf"]


def ranks_of(target: Path) -> list[int]:
    """Process ids of twomem runs writing `target` still alive."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if str(target) in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


def sigterm_under_mpirun(work: Path) -> str:
    """SIGTERM to mpirun mid-solve of a 2-rank run that would overwrite an old result: every rank
    stops, the old result and the output directory are untouched. Returns mpirun's stderr."""
    target, before = old_result(work)
    out = work / "stdout.txt"
    env = {**UNBUFFERED, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    # from (g, 0, 0) the contact front moves a mesh layer per Newton step (about 40 steps, 3–4 s
    # here): the signal lands mid-solve (with nested iteration the whole run now takes ~1 s)
    args = ["mesh.levels=4", "newton.linear=gmres", "newton.initial=paper", "estimate.enabled=.false.",
            f"output.file={target}"]
    with open(out, "w") as stdout:
        proc = subprocess.Popen(["mpirun", "-np", "2", "-x", "GFORTRAN_UNBUFFERED_PRECONNECTED", EXE, "run", DEFAULT_CASE, *args], stdout=stdout,
                                stderr=subprocess.PIPE, text=True, env=env)
        try:
            wait_for(proc, r"^problem:", out)
            if "1 MPI ranks" in out.read_text():
                # mpirun forwards SIGTERM; SIGKILL would leave its two one-rank runs behind
                proc.send_signal(signal.SIGTERM)
                proc.communicate(timeout=60)
                pytest.skip("this build runs without MPI")
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    # mpirun's own exit status is its business (Open MPI 4: 1); what matters is below
    assert proc.returncode != 0
    for _ in range(100):
        if not ranks_of(target):
            break
        time.sleep(0.1)
    assert ranks_of(target) == [], "a rank outlived mpirun"
    assert digest(target) == before
    assert files(work / "out") == ["result.h5", "result.xdmf"]
    return err


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="no mpirun")
def test_sigterm_under_mpirun_stops_every_rank(work):
    err = sigterm_under_mpirun(work)
    if not err:
        # mpirun, ending on the same signal, may close its relay of rank 0's stderr before the
        # line passes (seen once in a CI run under load, every other check held): the scenario,
        # all its checks included, runs once more, and that run must print the line
        shutil.rmtree(work / "out")
        err = sigterm_under_mpirun(work)
    # rank 0 alone prints it: one line per run, not one per rank
    assert err.count("twomem: interrupted by SIGTERM") == 1, err
