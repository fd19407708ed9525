#!/usr/bin/env bash
# Set up the venv (quick when already set up) and, for the whole suite, the browser viewer's
# Chromium and npm packages (tools/setup_web.sh), then run pytest on the real bpy wheel.
#
#   bash tools/test.sh                              # the whole suite (tests/), bpy 5.0.1 / Python 3.11
#   bash tools/test.sh --py313                      # the whole suite on bpy 5.2.3 / Python 3.13 / numpy 2
#   bash tools/test.sh tests/test_packaging.py -x   # paths and pytest options pass through
#   bash tools/test.sh -k manifest                  # options only: still runs tests/
#   bash tools/test.sh -m "not slow"                # leave out the slow tests (marker in conftest.py)
# The 15 slowest tests are listed at the end (--durations=15).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY=3.11
VENV="$ROOT/.venv"
if [[ "${1:-}" == "--py313" ]]; then
    PY=3.13
    VENV="$ROOT/.venv-py313"
    shift
fi
bash "$ROOT/tools/setup.sh" --python "$PY"
cd "$ROOT"

# Add tests/ unless a path to test was given.
targets=(tests)
for arg in "$@"; do
    if [[ "$arg" != -* && -e "${arg%%::*}" ]]; then
        targets=()
        break
    fi
done
# The browser viewer tests need Chromium and web/'s npm packages: set them up when the run
# includes those tests (idempotent, returns at once when ready). A machine that cannot
# install them still runs every other test; the browser tests then fail naming the script.
if [[ ${#targets[@]} -gt 0 || "$*" == *viewer_browser* ]]; then
    bash "$ROOT/tools/setup_web.sh" </dev/null \
        || echo "test.sh: tools/setup_web.sh failed; the browser viewer tests will fail" >&2
fi
exec "$VENV/bin/python" -m pytest "${targets[@]}" -q --durations=15 "$@"
