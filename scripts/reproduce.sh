#!/usr/bin/env bash
# The main job on a fresh machine: build the environment, then re-run every notebook and
# gather figures and numbers under build/. Extra arguments go to `lsmta reproduce`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
source scripts/env.sh
.venv/bin/lsmta reproduce "$@"
