#!/usr/bin/env bash
# Set up the project's virtual environment (.venv) on a fresh machine if needed, then run a job:
#   bash scripts/dev.sh demo [args]   one calibration episode in the MuJoCo scene (arc-calib demo [args])
#   bash scripts/dev.sh test [args]   the test suite (pytest [args])
#   bash scripts/dev.sh lint          ruff
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv="$root/.venv"
stamp="$venv/.installed-$(sha1sum pyproject.toml | cut -c1-12)"
# Offscreen rendering needs an EGL (or OSMesa) library; Debian's Mesa provides one for CPUs.
if ! ldconfig -p 2>/dev/null | grep -q -E 'libEGL\.so\.1|libOSMesa\.so'; then
  echo "installing Mesa EGL for offscreen rendering (apt)" >&2
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq && $sudo_cmd apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null
fi
# The export tests check the URDF with check_urdf (Debian's liburdfdom-tools); they fail in CI without it.
if ! command -v check_urdf >/dev/null 2>&1; then
  echo "installing liburdfdom-tools for check_urdf (apt)" >&2
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq liburdfdom-tools >/dev/null
fi
# The report's rendering test screenshots result.report.html with headless Chromium (Debian's
# chromium-headless-shell: about 11 s and 270 MB here); the test is skipped where it cannot be installed.
if ! command -v chromium-headless-shell >/dev/null 2>&1 && ! command -v chromium >/dev/null 2>&1; then
  echo "installing chromium-headless-shell for the report's rendering test (apt)" >&2
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  { $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get update -qq &&
    $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
      chromium-headless-shell >/dev/null; } || echo "could not install chromium-headless-shell: that test is skipped" >&2
fi
if [ ! -f "$stamp" ]; then
  python3 -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  # ray: the studies' --ray test runs in CI too (measured: ~8 s to install, 240 MB)
  "$venv/bin/python" -m pip install --quiet -e ".[dev,ray]"
  rm -f "$venv"/.installed-* && touch "$stamp"
fi
job="${1:-test}"
shift || true
case "$job" in
  demo) exec "$venv/bin/arc-calib" demo "$@" ;;
  test) exec "$venv/bin/python" -m pytest -q "$@" ;;
  lint) exec "$venv/bin/ruff" check . ;;
  *) echo "usage: bash scripts/dev.sh {demo|test|lint} [args]" >&2; exit 2 ;;
esac
