#!/usr/bin/env bash
# Set up the project's virtual environment (.venv) on a fresh machine if needed, then run a job:
#   bash scripts/dev.sh demo [args]   one calibration episode (arc-calib demo --synthetic [args])
#   bash scripts/dev.sh test [args]   the test suite (pytest [args])
#   bash scripts/dev.sh lint          ruff
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv="$root/.venv"
stamp="$venv/.installed-$(sha1sum pyproject.toml | cut -c1-12)"
if [ ! -f "$stamp" ]; then
  python3 -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  "$venv/bin/python" -m pip install --quiet -e ".[dev]"
  rm -f "$venv"/.installed-* && touch "$stamp"
fi
job="${1:-test}"
shift || true
case "$job" in
  demo) exec "$venv/bin/arc-calib" demo --synthetic "$@" ;;
  test) exec "$venv/bin/python" -m pytest -q "$@" ;;
  lint) exec "$venv/bin/ruff" check . ;;
  *) echo "usage: bash scripts/dev.sh {demo|test|lint} [args]" >&2; exit 2 ;;
esac
