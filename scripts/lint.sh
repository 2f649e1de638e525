#!/usr/bin/env bash
# `make lint`: ruff check and ruff format --check of the repository, without building ROS.
#
# The ruff is the one pinned in requirements.txt: .venv/bin/ruff when `make setup` made the
# venv, else .venv-lint/bin/ruff, a small venv of its own that this script creates (or
# refreshes when the pin changed) with any python3 (MLKM_PYTHON if set). So a fresh clone
# lints in seconds. .venv-lint holds a `.gitignore` of `*`, which keeps it out of git and of
# ruff's own file walk; `rm -rf .venv-lint` removes it.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"

pin=$(sed -n 's/^ruff==\([^ ;#]*\).*/\1/p' requirements.txt)
[[ -n $pin ]] || { echo 'lint: no ruff==<version> pin in requirements.txt' >&2; exit 2; }

version_of() { "$1" --version 2>/dev/null | awk '{print $2}'; }

ruff=$ROOT/.venv/bin/ruff
if [[ ! -x $ruff ]]; then
  ruff=$ROOT/.venv-lint/bin/ruff
  if [[ ! -x $ruff || $(version_of "$ruff") != "$pin" ]]; then
    py=${MLKM_PYTHON:-python3}
    echo "lint: installing ruff==$pin into .venv-lint (with $py)" >&2
    rm -rf .venv-lint
    "$py" -m venv .venv-lint
    echo '*' >.venv-lint/.gitignore
    .venv-lint/bin/python -m pip install --disable-pip-version-check --no-input -q "ruff==$pin"
  fi
fi
if [[ $(version_of "$ruff") != "$pin" ]]; then
  echo "lint: warning: $ruff is ruff $(version_of "$ruff"), requirements.txt pins $pin" >&2
fi
"$ruff" check . && "$ruff" format --check .
