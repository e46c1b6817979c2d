"""The Slurm job scripts of jobs/: they parse (bash -n), print the right command lines in a dry
run (TWOMEM_DRY_RUN=1) with and without a Slurm allocation, refuse a missing argument, and really
run: the threaded script solves a case, the hybrid one on 2 MPI ranks through mpirun (outside
Slurm), and jobs/submit_study.sh submits a tiny study through a stand-in `sbatch` that runs the
array tasks and then the collecting job, as Slurm would, so that the study's tables come out.
"""
from __future__ import annotations

import csv
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from twomem_testlib import EXE, SOURCE, out_file

JOBS = SOURCE / "jobs"
SCRIPTS = sorted(p for p in JOBS.iterdir() if p.suffix in (".sbatch", ".sh"))
CASE = SOURCE / "input" / "default.nml"
TINY = ("mesh.coarse_h=0.5", "mesh.boundary_h=0.2", "mesh.levels=1", "estimate.enabled=.false.")


def env(**extra: str) -> dict[str, str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    return dict(base, TWOMEM_EXE=EXE, TWOMEM_PYTHON=sys.executable, OMPI_ALLOW_RUN_AS_ROOT="1",
                OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", **extra)


def bash(script: Path, *args: str, cwd: Path | None = None, **extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(script), *args], capture_output=True, text=True, cwd=cwd or SOURCE,
                          env=env(**extra), timeout=600)


def test_there_are_job_scripts():
    names = {p.name for p in SCRIPTS}
    assert {"threaded.sbatch", "hybrid.sbatch", "study_array.sbatch", "submit_study.sh"} <= names


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_scripts_parse(script):
    proc = subprocess.run(["bash", "-n", str(script)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert os.access(script, os.X_OK), f"{script.name} is not executable"


def test_dry_runs():
    slurm = dict(SLURM_JOB_ID="42", SLURM_CPUS_PER_TASK="8", SLURM_SUBMIT_DIR=str(SOURCE), TWOMEM_DRY_RUN="1")
    p = bash(JOBS / "threaded.sbatch", str(CASE), "mesh.levels=6", **slurm)
    assert p.returncode == 0 and p.stdout == f"OMP_NUM_THREADS=8 {EXE} run {CASE} mesh.levels=6 \n", p.stdout
    p = bash(JOBS / "hybrid.sbatch", str(CASE), **slurm)
    assert p.returncode == 0
    assert p.stdout == (f"OMP_NUM_THREADS=8 srun --cpus-per-task=8 --cpu-bind=cores --distribution=block:block "
                        f"{EXE} run {CASE} \n"), p.stdout
    p = bash(JOBS / "hybrid.sbatch", str(CASE), TWOMEM_DRY_RUN="1", TWOMEM_RANKS="3")
    assert p.returncode == 0 and p.stdout.startswith("OMP_NUM_THREADS=1 mpirun -n 3 "), p.stdout
    p = bash(JOBS / "study_array.sbatch", str(CASE), "-o", "out", **slurm, SLURM_ARRAY_TASK_ID="3")
    assert p.returncode == 0
    assert p.stdout == f"OMP_NUM_THREADS=8 {sys.executable} -m twomem_post study {CASE} -o out --task 3 --twomem {EXE} \n"
    p = bash(JOBS / "submit_study.sh", str(CASE), "-o", "out", "--levels", "0,1", "--methods", "exact",
             TWOMEM_DRY_RUN="1", TWOMEM_ARRAY_MAX="1")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == "submit_study: 2 runs: exact_L0 exact_L1"
    assert lines[1].startswith(f"sbatch --parsable --array=0-1%1 {JOBS / 'study_array.sbatch'} {CASE} -o out")
    assert lines[2].startswith("sbatch --dependency=afterany:ARRAY_JOB_ID --parsable --job-name=twomem-collect")
    assert lines[2].endswith("--collect ")


@pytest.mark.parametrize("script, args, fragment", [
    ("threaded.sbatch", [], "usage: sbatch jobs/threaded.sbatch"),
    ("hybrid.sbatch", [], "usage: sbatch jobs/hybrid.sbatch"),
    ("study_array.sbatch", [str(CASE), "-o", "out"], "not an array task"),
    ("submit_study.sh", ["no_such.nml", "-o", "out"], "no_such.nml: no such case file"),
])
def test_refusals(script, args, fragment):
    p = bash(JOBS / script, *args)
    assert p.returncode == 2 and fragment in p.stderr, p.stdout + p.stderr


def test_threaded_job_solves_a_case():
    out = out_file("jobs-threaded.h5")
    out.unlink(missing_ok=True)
    p = bash(JOBS / "threaded.sbatch", str(CASE), *TINY, f"output.file={out}")
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr
    assert "threads" in p.stdout.splitlines()[0]
    with h5py.File(out) as f:
        assert f.attrs["status"].startswith("converged")


def test_hybrid_job_runs_two_ranks():
    version = subprocess.run([EXE, "--version"], capture_output=True, text=True, timeout=60).stdout
    if "MPI: none" in version or shutil.which("mpirun") is None:
        pytest.skip("no MPI in this build, or no mpirun")
    out = out_file("jobs-hybrid.h5")
    out.unlink(missing_ok=True)
    p = bash(JOBS / "hybrid.sbatch", str(CASE), *TINY, "newton.linear=gmres", f"output.file={out}",
             TWOMEM_RANKS="2", TWOMEM_MPIRUN_ARGS="--oversubscribe")
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr
    with h5py.File(out) as f:
        assert f.attrs["status"].startswith("converged")
        assert int(f["summary"].attrs["mpi_ranks"]) == 2


FAKE_SBATCH = '''#!{python}
"""Stand-in for sbatch: logs its arguments, runs an array script once per task (in order) or a
--wrap command, in the current directory, and prints a job id as --parsable does."""
import os, subprocess, sys
args = sys.argv[1:]
with open(os.environ["FAKE_SBATCH_LOG"], "a") as log:
    log.write(" ".join(args) + "\\n")
array = wrap = None
i = 0
while i < len(args):
    if args[i].startswith("--array="):
        array = args[i].split("=", 1)[1].split("%")[0]
    elif args[i] == "--wrap":
        wrap = args[i + 1]
        i += 1
    elif not args[i].startswith("--"):
        break
    i += 1
env = dict(os.environ, SLURM_SUBMIT_DIR=os.getcwd(), SLURM_CPUS_PER_TASK="1", SLURM_JOB_ID="100")
with open(os.environ["FAKE_SBATCH_LOG"] + ".out", "a") as out:
    if wrap is not None:
        subprocess.run(["bash", "-c", wrap], env=env, stdout=out, stderr=out)
        print("101")
    else:
        first, last = map(int, array.split("-"))
        for task in range(first, last + 1):
            subprocess.run(["bash", *args[i:]], env=dict(env, SLURM_ARRAY_TASK_ID=str(task)), stdout=out,
                           stderr=out)
        print("100;cluster")
'''


def test_submitted_study(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "sbatch"
    fake.write_text(FAKE_SBATCH.format(python=sys.executable))
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    log = tmp_path / "sbatch.log"
    study_dir = tmp_path / "study"
    p = bash(JOBS / "submit_study.sh", str(CASE), "-o", str(study_dir), "--levels", "0,1", "--methods", "exact,direct",
             "--set", "mesh.coarse_h=0.5", "--set", "mesh.boundary_h=0.2", cwd=tmp_path,
             PATH=f"{bin_dir}:{os.environ['PATH']}", FAKE_SBATCH_LOG=str(log))
    assert p.returncode == 0, p.stdout + p.stderr + (tmp_path / "sbatch.log.out").read_text()
    assert p.stdout.splitlines()[-1] == "submit_study: array job 100, then collect job 101"
    calls = log.read_text().splitlines()
    assert len(calls) == 2 and calls[0].startswith("--parsable --array=0-3 ")
    assert calls[1].startswith("--dependency=afterany:100 --parsable")
    with open(study_dir / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["tag"] for r in rows] == ["exact_L0", "direct_L0", "exact_L1", "direct_L1"]
    assert all(r["status"] == "converged" and r["exit_code"] == "0" for r in rows), rows
    assert (study_dir / "iterations.png").stat().st_size > 1000
