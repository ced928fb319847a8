#!/usr/bin/env bash
# The quickstart: set up, run the three-stage CPU workflow, then report.
#
#     bash scripts/quickstart.sh            # resumes: committed steps are skipped, an interrupted
#                                           # step continues from its last checkpoint
#     bash scripts/quickstart.sh --fresh    # start over: the previous store is removed first
#     QUICKSTART_STORE=/tmp/qs bash scripts/quickstart.sh
#
# The store lives in runs/quickstart/store (or $QUICKSTART_STORE); its report in the directory beside it.
set -euo pipefail
cd "$(dirname "$0")/.."
fresh=0
for arg in "$@"; do
  case "$arg" in
    --fresh) fresh=1 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "error: unknown argument $arg (use --fresh to start over)" >&2; exit 2 ;;
  esac
done
bash scripts/setup.sh
STORE=${QUICKSTART_STORE:-runs/quickstart/store}
export ACCRUE_STORE=$STORE
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}   # two cores: one thread per process beats oversubscription
resume=()
if [ "$fresh" = 1 ]; then
  rm -rf "$STORE"
elif [ -f "$STORE/config" ]; then
  resume=(--continue)   # committed steps are cache hits; an interrupted one continues
  echo "quickstart: resuming the store at $STORE (pass --fresh to start over)"
fi
mkdir -p "$(dirname "$STORE")"
.venv/bin/accrue init
start=$(date +%s)
.venv/bin/accrue run workflows/quickstart.yaml "${resume[@]}"
echo "quickstart: accrue run took $(( $(date +%s) - start )) s"
if .venv/bin/accrue report --help >/dev/null 2>&1; then
  .venv/bin/accrue report workflows/quickstart.yaml --out "$(dirname "$STORE")/report"
fi
