#!/usr/bin/env bash
# Creates .venv (Python 3.11) and installs accrue with its pinned stack. Re-running is cheap:
# the install is skipped while pyproject.toml is unchanged, and uv's download cache is reused.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${ACCRUE_PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3 python; do
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then PY=$cand; break; fi
  done
fi
[ -n "$PY" ] || { echo "error: accrue needs Python 3.11 (lerobot 0.4.4 is the last release for it); set ACCRUE_PYTHON" >&2; exit 2; }
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=$(cat pyproject.toml | "$PY" -c 'import hashlib,sys; print(hashlib.sha256(sys.stdin.buffer.read()).hexdigest())')
if [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp" ]; then
  .venv/bin/python -m pip install -q --disable-pip-version-check "uv>=0.4,<1"
  .venv/bin/uv pip install --python .venv/bin/python -e '.[dev]'
  echo "$stamp" > .venv/.setup-stamp
fi
