#!/usr/bin/env bash
# The whole test suite on a fresh machine: build the environment, lint, then the unit tests
# and every notebook (through nbmake, each in its own folder), spread over the machine's cores
# by pytest-xdist (-n auto; the notebooks, the longest, first; an idle worker takes queued
# tests from a busy one). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
source scripts/env.sh
.venv/bin/ruff check lsmta tests experiments notebooks
.venv/bin/python -m pytest notebooks tests --nbmake --nbmake-timeout=600 -n auto --dist worksteal "$@"
