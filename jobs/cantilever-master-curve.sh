#!/usr/bin/env bash
# Cantilever master curve: tip of a strip under self-weight for several Gamma*, against the
# heavy elastica. Usage: jobs/cantilever-master-curve.sh [RANKS] [OUT]   (e.g. 2 out/master-curve)
set -euo pipefail
cd "$(dirname "$0")/.."
ranks="${1:-1}"
out="${2:-out/master-curve}"
make -s setup
for gamma in 0.5 2 5 10 20 50 100 300; do
  mpirun --allow-run-as-root --oversubscribe -n "$ranks" .venv/bin/bhem-hpc cantilever \
    --gamma "$gamma" --patches 32 --out "$out/gamma-$gamma" | sed -n '1,3p'
done
