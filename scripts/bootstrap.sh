#!/usr/bin/env bash
# Build everything lsmta needs on a fresh Debian machine (Python 3.10+; root or sudo for the
# system libraries): the packages of apt.txt (Mesa's EGL for off-screen pyvista, Chromium
# for the book's browser tests), then a virtual environment in .venv
# with the exact versions of requirements.lock (made by pip-compile, see ENVIRONMENT.md) and
# the package itself. LSMTA_UNLOCKED=1 installs the newest versions pyproject.toml allows
# instead. Safe to run again: steps already done are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."

# 1. System packages, listed in apt.txt (Binder reads the same file): Mesa's EGL for
#    headless 3-D rendering (VTK's EGL render window) and Chromium, in which the tests open
#    the book (tests/test_book.py) and a reader can.
sys_pkgs="$(sed -e 's/#.*//' apt.txt | tr -s ' \n' ' ')"
missing=""
for p in $sys_pkgs; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing system packages:$missing"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
  else
    echo "bootstrap: please install$missing (Debian names; apt.txt) for off-screen pyvista and the browser tests" >&2
  fi
fi

# 2. The virtual environment, rebuilt only when pyproject.toml or requirements.lock changes.
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for cand in python3.11 python3.12 python3.10 python3; do
    command -v "$cand" >/dev/null 2>&1 && { PY="$cand"; break; }
  done
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.lsmta-installed
unlocked="${LSMTA_UNLOCKED:-}"
want="$(cat pyproject.toml requirements.lock | sha256sum | cut -d' ' -f1)${unlocked:+-unlocked}"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  pip_q() { .venv/bin/python -m pip install -q "$@" 2>&1 | grep -v "^WARNING: Location" || true; }
  pip_q --upgrade pip
  if [ -n "$unlocked" ]; then
    echo "bootstrap: installing lsmta and the newest allowed dependencies into .venv"
    pip_q -e '.[test]'
  else
    echo "bootstrap: installing the locked dependencies (requirements.lock) and lsmta into .venv"
    pip_q -r requirements.lock
    pip_q --no-deps -e .
  fi
  .venv/bin/python -c "import lsmta, numpy, scipy, cv2, skimage, pyvista, emcee, nbmake, myst_nb, plotly" \
    || { echo "bootstrap: the install failed" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
