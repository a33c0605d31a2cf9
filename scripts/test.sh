#!/usr/bin/env bash
# The whole test suite on a fresh machine: build the environment, lint, then the unit tests
# and every notebook (through nbmake, each in its own folder). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
source scripts/env.sh
.venv/bin/ruff check lsmta tests experiments notebooks
.venv/bin/python -m pytest tests notebooks --nbmake --nbmake-timeout=600 "$@"
