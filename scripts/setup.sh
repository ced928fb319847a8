#!/usr/bin/env bash
# Creates .venv (Python 3.11) and installs exactly the versions pinned in uv.lock — the ones CI
# tested — plus accrue itself (editable) and the dev tools. Re-running is cheap: the install is
# skipped while uv.lock and pyproject.toml are unchanged, and uv's download cache is reused.
# After changing dependencies in pyproject.toml, run `.venv/bin/uv lock` and commit uv.lock
# (setup refuses a lock file that no longer matches pyproject.toml).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${ACCRUE_PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3 python; do
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then PY=$cand; break; fi
  done
fi
[ -n "$PY" ] || { echo "error: accrue needs Python 3.11 (lerobot 0.4.4 is the last release for it); set ACCRUE_PYTHON" >&2; exit 2; }
[ -f uv.lock ] || { echo "error: uv.lock is missing; run \`uv lock\` (it pins every version)" >&2; exit 2; }
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=$(cat uv.lock pyproject.toml | "$PY" -c 'import hashlib,sys; print(hashlib.sha256(sys.stdin.buffer.read()).hexdigest())')
if [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp" ]; then
  [ -x .venv/bin/uv ] || .venv/bin/python -m pip install -q --disable-pip-version-check "uv>=0.9,<1"
  # --locked: the lock must match pyproject.toml; --inexact: keep pip and uv themselves in .venv
  .venv/bin/uv sync --locked --extra dev --inexact --python .venv/bin/python
  echo "$stamp" > .venv/.setup-stamp
fi
