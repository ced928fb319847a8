#!/usr/bin/env bash
# Creates .venv (Python 3.12) and installs exactly the versions pinned in uv.lock — the ones CI
# tested — plus accrue itself (editable) and the dev tools. Re-running is cheap: the install is
# skipped while uv.lock and pyproject.toml are unchanged, and uv's download cache is reused.
# After changing dependencies in pyproject.toml, run `.venv/bin/uv lock` and commit uv.lock
# (setup refuses a lock file that no longer matches pyproject.toml).
set -euo pipefail
cd "$(dirname "$0")/.."
is312() { "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1; }
PY=${ACCRUE_PYTHON:-}
if [ -z "$PY" ]; then
  # on PATH first, then pyenv's 3.12 (its shim refuses while another version is selected)
  cands=(python3.12 python3 python)
  if command -v pyenv >/dev/null; then
    for d in "$(pyenv root)"/versions/3.12*; do [ -x "$d/bin/python3.12" ] && cands+=("$d/bin/python3.12"); done
  fi
  for cand in "${cands[@]}"; do
    if command -v "$cand" >/dev/null && is312 "$cand"; then PY=$cand; break; fi
  done
fi
[ -n "$PY" ] && is312 "$PY" || {
  echo "error: accrue needs Python 3.12 (lerobot 0.6 requires it): none on PATH or in pyenv, or ACCRUE_PYTHON is not 3.12; set ACCRUE_PYTHON to a python3.12" >&2
  exit 2
}
[ -f uv.lock ] || { echo "error: uv.lock is missing; run \`uv lock\` (it pins every version)" >&2; exit 2; }
if [ -x .venv/bin/python ] && ! is312 .venv/bin/python; then
  echo "setup: .venv is not Python 3.12 (left from the 3.11 / lerobot 0.4 set-up); recreating it" >&2
  rm -rf .venv
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=$(cat uv.lock pyproject.toml | "$PY" -c 'import hashlib,sys; print(hashlib.sha256(sys.stdin.buffer.read()).hexdigest())')
if [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp" ]; then
  [ -x .venv/bin/uv ] || .venv/bin/python -m pip install -q --disable-pip-version-check "uv>=0.9,<1"
  # --locked: the lock must match pyproject.toml; --inexact: keep pip and uv themselves in .venv
  .venv/bin/uv sync --locked --extra dev --inexact --python .venv/bin/python
  echo "$stamp" > .venv/.setup-stamp
fi
