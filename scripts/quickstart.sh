#!/usr/bin/env bash
# The quickstart: set up, run the three-stage CPU workflow into a fresh store, then report.
#
#     bash scripts/quickstart.sh            # store in runs/quickstart/store (replaced if it exists)
#     QUICKSTART_STORE=/tmp/qs bash scripts/quickstart.sh
#
# Re-running after an interruption resumes: set QUICKSTART_KEEP=1 to keep the store, and the
# committed steps are skipped while an interrupted `train` continues from its last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
STORE=${QUICKSTART_STORE:-runs/quickstart/store}
export ACCRUE_STORE=$STORE
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}   # two cores: one thread per process beats oversubscription
if [ -z "${QUICKSTART_KEEP:-}" ]; then rm -rf "$STORE"; fi
mkdir -p "$(dirname "$STORE")"
.venv/bin/accrue init
start=$(date +%s)
.venv/bin/accrue run workflows/quickstart.yaml ${QUICKSTART_KEEP:+--continue}
echo "quickstart: accrue run took $(( $(date +%s) - start )) s"
if .venv/bin/accrue report --help >/dev/null 2>&1; then
  .venv/bin/accrue report workflows/quickstart.yaml --out "$(dirname "$STORE")/report"
fi
