#!/usr/bin/env bash
# Run a scene under MPI: jobs/run.sh SCENE.toml OUT_DIR [RANKS] [extra bhem-hpc/PETSc options...]
# e.g. jobs/run.sh jobs/twisting.toml out/twisting 2 --force -bhem_snes_monitor
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: $0 SCENE.toml OUT_DIR [RANKS] [options...]" >&2; exit 2; }
scene="$1"; out="$2"; ranks="${3:-1}"; shift $(( $# < 3 ? $# : 3 ))
here="$(cd "$(dirname "$0")/.." && pwd)"
make -s -C "$here" setup
# One BLAS thread per rank unless told otherwise: ranks x threads beyond the cores only costs.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-$([ "$ranks" -gt 1 ] && echo 1 || echo "")}"
[ -n "$OPENBLAS_NUM_THREADS" ] || unset OPENBLAS_NUM_THREADS
exec mpirun --allow-run-as-root --oversubscribe -n "$ranks" "$here/.venv/bin/bhem-hpc" run "$scene" --out "$out" "$@"
