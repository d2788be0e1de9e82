#!/usr/bin/env bash
# Check jobs/slurm.sbatch on a running SLURM (e.g. Debian's slurm-wlm on one node), from a scratch
# directory, with jobs/drape.toml: a 2-rank job of 3 steps with a PETSc option passed through, then
# a long job whose time limit (3 min) makes it requeue itself and continue from its checkpoint.
# About 5 minutes; prints PASS or FAIL.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
sinfo >/dev/null || { echo "FAIL: no SLURM controller answers (sinfo)"; exit 1; }
work="$(mktemp -d)"; cd "$work"
wait_for() { while [ -n "$(squeue -h -j "$1" -o %T)" ]; do sleep 5; done; }
fail() { echo "FAIL: $*"; tail -20 "$work"/*.log; exit 1; }
scene="$here/jobs/drape.toml"
job=$(sbatch --parsable -n 2 "$here/jobs/slurm.sbatch" "$scene" out --steps 3 -bhem_snes_monitor_typo)
wait_for "$job"
grep -q '"status": "completed"' out/summary.json || fail "the 2-rank job did not complete"
grep -q '"ranks": 2' out/summary.json || fail "the job did not run on 2 ranks"
grep -q 'bhem_snes_monitor_typo' out/summary.json || fail "the PETSc option did not reach the run"
job=$(sbatch --parsable -n 1 --time=3 --signal=B:USR1@60 "$here/jobs/slurm.sbatch" "$scene" long --steps 1000000)
for _ in $(seq 1 120); do grep -q "continuing from" long.log 2>/dev/null && break; sleep 5; done
scancel "$job"
grep -q "time limit near: requeueing" long.log || fail "the job did not requeue itself"
grep -q "continuing from $work/long/checkpoint.h5" long.log || fail "the requeued job did not continue"
echo "PASS (output in $work)"
