#!/bin/bash
# Submit a study (python -m twomem_post study, see postproc/) to Slurm as a job array, one
# twomem run per task, and a job that gathers the tables and figures once every task has
# ended, whether it succeeded or not (a run that failed or never ran is reported as such).
#
#   jobs/submit_study.sh CASE.nml -o DIR [--levels ... | --coarse-h ... | --sweep ...]
#                        [--methods ...] [--set GROUP.KEY=VALUE ...] [--max-it N]
#
# Run it on the login node from the directory the paths in the arguments are relative to; the
# jobs run there too. Environment: TWOMEM_EXE, TWOMEM_PYTHON (defaults: the repository's
# build/release/twomem and .venv/bin/python; both passed on to the jobs), TWOMEM_ARRAY_MAX
# (tasks at a time, default all), SBATCH_* variables for sbatch itself; TWOMEM_DRY_RUN=1
# prints the two sbatch commands instead of submitting them.
set -euo pipefail
jobs=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
export TWOMEM_EXE=${TWOMEM_EXE:-$(dirname "$jobs")/build/release/twomem}
export TWOMEM_PYTHON=${TWOMEM_PYTHON:-$(dirname "$jobs")/.venv/bin/python}
python=$TWOMEM_PYTHON
[ -x "$python" ] || { echo "submit_study: no Python $python (scripts/bootstrap.sh makes .venv, or set TWOMEM_PYTHON)" >&2; exit 3; }

# the plan, checked on the login node: bad arguments fail here, before anything is queued
plan=$("$python" -m twomem_post study "$@" --list) || exit $?
n=$(printf '%s\n' "$plan" | grep -c .)
echo "submit_study: $n runs:" $(printf '%s\n' "$plan" | cut -d' ' -f2)
limit=${TWOMEM_ARRAY_MAX:+%$TWOMEM_ARRAY_MAX}

array=(sbatch --parsable --array="0-$((n - 1))$limit" "$jobs/study_array.sbatch" "$@")
collect_cmd=$(printf '%q ' "$python" -m twomem_post study "$@" --collect)
collect_cmd=${collect_cmd% }
collect=(sbatch --parsable --job-name=twomem-collect --ntasks=1 --time=00:30:00
         --output=twomem-collect-%j.out --wrap "$collect_cmd")
if [ -n "${TWOMEM_DRY_RUN:-}" ]; then
  printf '%q ' "${array[@]}"; echo
  printf '%q ' "${collect[@]:0:1}" --dependency=afterany:ARRAY_JOB_ID "${collect[@]:1}"; echo
  exit 0
fi
id=$("${array[@]}")
id=${id%%;*}  # --parsable prints "jobid[;cluster]"
done_id=$("${collect[@]:0:1}" --dependency="afterany:$id" "${collect[@]:1}")
echo "submit_study: array job $id, then collect job ${done_id%%;*}"
