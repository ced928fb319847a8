#!/usr/bin/env bash
# Runs the walk-through of docs/sharing.md ("Sharing a store") exactly as written: the ```bash blocks between
# <!-- walkthrough:share:start --> and <!-- walkthrough:share:end -->, each in the clone of the
# machine its first line names (# robot PC, # workstation, # auditor). Every machine is a fresh
# `git clone` of this repository's HEAD (committed work only) with this checkout's .venv linked in,
# and has its own store; they share only $REMOTE. Prints each command, its output and its time;
# stops at the first command that fails, and fails if a workstation `accrue run` ran any step
# (the step cache must have come with the pull).
#
#   bash scripts/walkthrough_share.sh dir      # remote: a directory (the NAS mount)
#   bash scripts/walkthrough_share.sh s3       # remote: a bucket on a local moto S3 server
#   bash scripts/walkthrough_share.sh --list   # the extracted commands, one "machine<TAB>command" a line
#   bash scripts/walkthrough_share.sh --check-cached LOG   # the cache-hit check on one run's output
#
# WALKTHROUGH_DIR=DIR keeps the clones, stores and logs there (default: a new temp directory).
set -euo pipefail
REPO=$(cd "$(dirname "$0")/.." && pwd)
PAGE=$REPO/docs/sharing.md

# The page's walk-through blocks as "machine<TAB>command" lines (comments and blank lines dropped).
extract() {
  awk '
    /<!-- walkthrough:share:start -->/ { inside = 1; next }
    /<!-- walkthrough:share:end -->/   { inside = 0; next }
    !inside { next }
    /^```bash[[:space:]]*$/ { block = 1; machine = ""; next }
    /^```/ && block { if (machine == "") { print "error: a walk-through block names no machine" > "/dev/stderr"; exit 2 }
                      block = 0; next }
    block && machine == "" { if ($0 !~ /^# /) { print "error: a walk-through block must start with \"# MACHINE\"" > "/dev/stderr"; exit 2 }
                             machine = substr($0, 3); next }
    block && /^[[:space:]]*(#|$)/ { next }
    block { print machine "\t" $0 }
  ' "$PAGE"
}

# The summary line of `accrue run` must say it ran nothing and took at least one step from the cache.
check_cached() {
  local line
  line=$(grep -Eo 'done \([0-9]+ steps run, [0-9]+ cached\)' "$1" | tail -n 1 || true)
  if [ -z "$line" ]; then
    echo "error: no 'N steps run, M cached' summary in $1" >&2
    return 1
  fi
  local run cached
  run=$(sed -E 's/done \(([0-9]+) steps run, ([0-9]+) cached\)/\1/' <<<"$line")
  cached=$(sed -E 's/done \(([0-9]+) steps run, ([0-9]+) cached\)/\2/' <<<"$line")
  if [ "$run" != 0 ] || [ "$cached" = 0 ]; then
    echo "error: the workstation's run was not all cache hits: $run steps run, $cached cached" >&2
    return 1
  fi
  echo "check: all cache hits ($run steps run, $cached cached)"
}

case "${1:-}" in
  --list) extract; exit ;;
  --check-cached) check_cached "$2"; exit ;;
  dir | s3) KIND=$1 ;;
  *) echo "usage: $0 dir|s3|--list|--check-cached LOG" >&2; exit 2 ;;
esac

[ -x "$REPO/.venv/bin/accrue" ] || { echo "error: no $REPO/.venv; run bash scripts/setup.sh first" >&2; exit 2; }
COMMANDS=$(extract)
[ -n "$COMMANDS" ] || { echo "error: no walk-through blocks in $PAGE" >&2; exit 2; }
WORK=${WALKTHROUGH_DIR:-$(mktemp -d /tmp/accrue-walkthrough.XXXXXX)}
mkdir -p "$WORK"
unset ACCRUE_STORE
export COLUMNS=200 # rich wraps at 80 when piped; keep each summary on one line

echo "# docs/sharing.md walk-through, remote kind: $KIND"
echo "# command: bash scripts/walkthrough_share.sh $KIND"
echo "# commit:  $(git -C "$REPO" rev-parse HEAD) ($(git -C "$REPO" log -1 --format=%cd --date=iso))"
echo "# date:    $(date -u '+%Y-%m-%d %H:%M:%S UTC')"
echo "# machine: $(nproc) cores, $(uname -sm); load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "# work:    $WORK"

MOTO_PID=
cleanup() { if [ -n "$MOTO_PID" ]; then kill "$MOTO_PID" 2>/dev/null || true; fi; }
trap cleanup EXIT
if [ "$KIND" = dir ]; then
  mkdir -p "$WORK/nas" # the mounted disk; `remote add --create` makes the remote's own directory in it
  export REMOTE=$WORK/nas/accrue
else
  # moto's S3 server in its own process, as benchmarks/bench_remote.py starts it, and the lab's bucket
  PORT=$("$REPO/.venv/bin/python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  "$REPO/.venv/bin/python" -c "import time; from moto.server import ThreadedMotoServer; s = ThreadedMotoServer(ip_address='127.0.0.1', port=$PORT, verbose=False); s.start(); time.sleep(10**6)" >"$WORK/moto.log" 2>&1 &
  MOTO_PID=$!
  export AWS_ENDPOINT_URL=http://127.0.0.1:$PORT AWS_ACCESS_KEY_ID=testing AWS_SECRET_ACCESS_KEY=testing AWS_REGION=us-east-1
  unset AWS_PROFILE
  "$REPO/.venv/bin/python" - <<'EOF'
import os, time, boto3
client = boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL"])
deadline = time.monotonic() + 60
while True:
    try:
        client.create_bucket(Bucket="lab-accrue")
        break
    except Exception:
        if time.monotonic() > deadline:
            raise SystemExit("error: the moto S3 server did not start")
        time.sleep(0.2)
EOF
  export REMOTE=s3://lab-accrue/cell-3
fi
echo "# remote:  $REMOTE${AWS_ENDPOINT_URL:+ (endpoint $AWS_ENDPOINT_URL)}"

# one fresh clone per machine, with this checkout's environment; PYTHONPATH makes the clone's own
# code the one imported (the .venv's editable install points at this checkout)
declare -A DIRS
while IFS=$'\t' read -r machine _; do
  [ -n "${DIRS[$machine]:-}" ] && continue
  dir=$WORK/$(tr -c 'a-zA-Z0-9\n' '-' <<<"$machine")
  git clone -q "$REPO" "$dir"
  ln -s "$REPO/.venv" "$dir/.venv"
  DIRS[$machine]=$dir
  echo "# $machine: $dir (clone of $(git -C "$dir" rev-parse --short HEAD))"
done <<<"$COMMANDS"

n=0
checked=0
SUMMARY=
total_start=$(date +%s.%N)
while IFS=$'\t' read -r machine cmd; do
  n=$((n + 1))
  dir=${DIRS[$machine]}
  log=$WORK/$(printf '%02d' "$n").log
  echo
  echo "+ [$machine] $cmd    (load $(cut -d' ' -f1 /proc/loadavg))"
  start=$(date +%s.%N)
  set +e
  (cd "$dir" && PATH=$dir/.venv/bin:$PATH PYTHONPATH=$dir bash -c "$cmd") </dev/null 2>&1 | tee "$log"
  rc=${PIPESTATUS[0]}
  set -e
  took=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  echo "= rc $rc, ${took} s"
  SUMMARY+=$(printf '%8s s  [%s] %s' "$took" "$machine" "$cmd")$'\n'
  if [ "$rc" != 0 ]; then
    echo "error: [$machine] $cmd exited $rc" >&2
    exit 1
  fi
  if [ "$machine" = workstation ] && [[ "$cmd" == "accrue run "* ]]; then
    check_cached "$log"
    checked=$((checked + 1))
  fi
done <<<"$COMMANDS"
# a page that renamed the machine or dropped its run must not pass unchecked
[ "$checked" -gt 0 ] || { echo "error: the walk-through has no workstation 'accrue run' to check for cache hits" >&2; exit 1; }

total=$(awk -v a="$total_start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
echo
echo "# summary ($KIND remote; load at end: $(cut -d' ' -f1-3 /proc/loadavg))"
printf '%s' "$SUMMARY"
echo "# walk-through passed: $n commands in $total s"
