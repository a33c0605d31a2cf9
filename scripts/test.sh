#!/usr/bin/env bash
# The whole test suite on a fresh machine: build the environment, lint, then the unit tests
# and every notebook (through nbmake, each in its own folder), spread over the machine's cores
# by pytest-xdist: one worker per core, one file at a time, the longest files first
# (conftest.py). Each worker computes on one thread (BLAS, numba): two workers with two
# threads each would fight for the two cores. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
source scripts/env.sh
.venv/bin/ruff check --no-cache lsmta tests experiments notebooks
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1
.venv/bin/python -m pytest notebooks tests --nbmake --nbmake-timeout=600 -n auto --dist loadfile --no-loadscope-reorder "$@"
