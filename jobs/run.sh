#!/usr/bin/env bash
# Run a scene under MPI on a workstation: jobs/run.sh SCENE.toml OUT_DIR [RANKS] [bhem-hpc/PETSc options...]
# (RANKS defaults to 1; options may follow OUT_DIR directly)
# e.g. jobs/run.sh jobs/twisting.toml out/twisting 2 --force -bhem_snes_monitor
# Needs the project's .venv (make setup). As root, Open MPI needs --allow-run-as-root; with more
# ranks than cores, --oversubscribe: both are added only then.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: $0 SCENE.toml OUT_DIR [RANKS] [options...]" >&2; exit 2; }
scene="$1"; out="$2"; shift 2
ranks=1
if [ $# -ge 1 ] && { [[ "$1" != -* ]] || [[ "$1" =~ ^-[0-9.]+$ ]]; }; then  # RANKS is optional: options may follow OUT_DIR
    [[ "$1" =~ ^[0-9]+$ ]] && [ "$1" -ge 1 ] && [ "$1" -le 100000 ] \
        || { echo "$0: error: RANKS must be an integer in 1..100000, got '$1'" >&2; exit 2; }
    ranks="$1"; shift
fi
here="$(cd "$(dirname "$0")/.." && pwd)"
[ -x "$here/.venv/bin/bhem-hpc" ] || { echo "$here/.venv/bin/bhem-hpc not found: run 'make setup' first" >&2; exit 2; }
flags=()
[ "$(id -u)" -ne 0 ] || flags+=(--allow-run-as-root)
[ "$ranks" -le "$(nproc)" ] || flags+=(--oversubscribe)
# One BLAS thread per rank unless told otherwise: ranks x threads beyond the cores only costs.
if [ "$ranks" -gt 1 ]; then export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"; fi
exec mpirun "${flags[@]}" -n "$ranks" "$here/.venv/bin/bhem-hpc" run "$scene" --out "$out" "$@"
