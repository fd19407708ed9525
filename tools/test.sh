#!/usr/bin/env bash
# Set up .venv (quick when already set up), then run pytest on the real bpy wheel.
#
#   bash tools/test.sh                              # the whole suite (tests/)
#   bash tools/test.sh tests/test_packaging.py -x   # paths and pytest options pass through
#   bash tools/test.sh -k manifest                  # options only: still runs tests/
#   bash tools/test.sh -m "not slow"                # leave out the slow tests (marker in conftest.py)
# The 15 slowest tests are listed at the end (--durations=15).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/tools/setup.sh"
cd "$ROOT"

# Add tests/ unless a path to test was given.
targets=(tests)
for arg in "$@"; do
    if [[ "$arg" != -* && -e "${arg%%::*}" ]]; then
        targets=()
        break
    fi
done
exec "$ROOT/.venv/bin/python" -m pytest "${targets[@]}" -q --durations=15 "$@"
