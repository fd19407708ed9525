#!/usr/bin/env bash
# Create .venv (CPython 3.11) and install the pinned requirements.txt into it.
#
# Idempotent and quick: when .venv already holds exactly these requirements (a
# stamp file records their hash and the venv's interpreter) it returns at once
# without running pip. Override the base interpreter with PYTHON=/path/to/python3.11.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
REQUIREMENTS="$ROOT/requirements.txt"
STAMP="$VENV/.pdic-requirements.sha256"

say() { echo "setup: $*" >&2; }

# The bpy wheel (Blender 5.0) exists only for CPython 3.11.
python_is_311() { "$1" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null; }

# What the stamp records: the requirements and the venv's exact interpreter.
requirements_hash() {
    { cat "$REQUIREMENTS"; "$VENV/bin/python" -c 'import sys; print(sys.version.split()[0])'; } \
        | sha256sum | cut -d' ' -f1
}

# Fast path: already set up.
if [[ -x "$VENV/bin/python" ]] && python_is_311 "$VENV/bin/python" \
    && [[ -f "$STAMP" ]] && [[ "$(cat "$STAMP")" == "$(requirements_hash)" ]]; then
    exit 0
fi

start=$SECONDS
if [[ ! -x "$VENV/bin/python" ]] || ! python_is_311 "$VENV/bin/python"; then
    if [[ -n "${PYTHON:-}" ]]; then
        candidates=("$PYTHON")
    else
        candidates=(python3 python3.11)
    fi
    BASE_PYTHON=""
    for candidate in "${candidates[@]}"; do
        if command -v "$candidate" >/dev/null 2>&1 && python_is_311 "$candidate"; then
            BASE_PYTHON="$(command -v "$candidate")"
            break
        fi
    done
    if [[ -z "$BASE_PYTHON" ]]; then
        found=""
        for candidate in "${candidates[@]}"; do
            found+=" $candidate ($("$candidate" --version 2>&1 || true));"
        done
        say "error: PDIC needs CPython 3.11 (the bpy 5.0 wheel exists only for 3.11). Tried:$found"
        say "       install Python 3.11, or run with PYTHON=/path/to/python3.11"
        exit 1
    fi
    say "creating $VENV with $BASE_PYTHON ($("$BASE_PYTHON" --version 2>&1))"
    rm -rf "$VENV"
    "$BASE_PYTHON" -m venv "$VENV"
fi

say "installing pinned requirements from requirements.txt (pip)"
rm -f "$STAMP"
"$VENV/bin/python" -m pip install --disable-pip-version-check -q -r "$REQUIREMENTS"
requirements_hash >"$STAMP"
say "ready in $((SECONDS - start)) s: $VENV"
