#!/usr/bin/env bash
# Run the PDIC benchmark suite (see bench/README.md). Arguments go to bench.run, e.g. --quick.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
if ! "$PY" -c "import matplotlib, pyoidn" 2>/dev/null; then
    "$PY" -m pip install -q -r requirements-bench.txt
fi
exec "$PY" -m bench.run "$@"
