#!/usr/bin/env bash
# All setup, then the job: `bash run.sh reproduce` (the M1-M4 reproduction, quick profile) or `bash run.sh test` (lint, tests).
# Creates or refreshes ./.venv, installs torch==2.13.0 (CPU) before anything that depends on torch, then the package.
set -euo pipefail
cd "$(dirname "$0")"
job=${1:?usage: bash run.sh reproduce|test [extra arguments]}
shift

python=${PYTHON:-python3.11}
command -v "$python" >/dev/null || python=python3
[ -x .venv/bin/python ] || "$python" -m venv .venv
export PIP_DISABLE_PIP_VERSION_CHECK=1
.venv/bin/python -m pip install -q torch==2.13.0
extras=""
if [ "$job" = test ]; then extras="[test]"; fi  # pytest, ruff, shapely, motmetrics: only the tests need them
.venv/bin/python -m pip install -q -e ".$extras"
export PATH="$PWD/.venv/bin:$PATH"

case "$job" in
  reproduce) exec memslidar reproduce --profile quick "$@" ;;
  test) ruff check . && exec python -m pytest -q "$@" ;;  # lint (pyproject.toml [tool.ruff]), then the tests
  *) echo "unknown job '$job': use reproduce or test" >&2; exit 2 ;;
esac
