#!/usr/bin/env bash
# Check jobs/slurm.sbatch on a running SLURM (e.g. Debian's slurm-wlm on one node), from a scratch
# directory: a 2-rank job with a PETSc option passed through, then a job whose time limit (3 min)
# makes it requeue itself and continue from its checkpoint. About 5 minutes; prints PASS or FAIL.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
sinfo >/dev/null || { echo "FAIL: no SLURM controller answers (sinfo)"; exit 1; }
work="$(mktemp -d)"; cd "$work"
cat >scene.toml <<'TOML'
[surface]
kind = "rectangle"
size = [0.4, 0.3]
patches = [3, 2]

[material]
young = 1.0e4
poisson = 0.3
thickness = 1.0e-3
density = 200.0

[time]
dt = 0.01
steps = 6

[effects]
gravity = [0.0, 0.0, -9.81]
damping = { mass = 0.5 }

[[constraints]]
type = "clamp"
corners = ["min_min"]
TOML
sed -e 's/steps = 6/steps = 1000000/' scene.toml >long.toml
printf '\n[output]\nevery = 50\n' >>long.toml
wait_for() { while [ -n "$(squeue -h -j "$1" -o %T)" ]; do sleep 5; done; }
fail() { echo "FAIL: $*"; tail -20 "$work"/*.log; exit 1; }
job=$(sbatch --parsable -n 2 "$here/jobs/slurm.sbatch" scene.toml out -bhem_snes_monitor_typo)
wait_for "$job"
grep -q '"status": "completed"' out/summary.json || fail "the 2-rank job did not complete"
grep -q '"ranks": 2' out/summary.json || fail "the job did not run on 2 ranks"
grep -q 'bhem_snes_monitor_typo' out/summary.json || fail "the PETSc option did not reach the run"
job=$(sbatch --parsable -n 1 --time=3 --signal=B:USR1@60 "$here/jobs/slurm.sbatch" long.toml long)
for _ in $(seq 1 120); do grep -q "continuing from" long.log 2>/dev/null && break; sleep 5; done
scancel "$job"
grep -q "time limit near: requeueing" long.log || fail "the job did not requeue itself"
grep -q "continuing from $work/long/checkpoint.h5" long.log || fail "the requeued job did not continue"
echo "PASS (output in $work)"
