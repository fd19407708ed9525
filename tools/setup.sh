#!/usr/bin/env bash
# Create a virtual environment with the bpy wheel and install its pinned requirements.
#
#   bash tools/setup.sh                 # .venv:       CPython 3.11, bpy 5.0.1, numpy 1.26 (requirements.txt)
#   bash tools/setup.sh --python 3.13   # .venv-py313: CPython 3.13, bpy 5.2.3, numpy 2.3 (requirements-py313.txt)
#
# Idempotent and quick: when the venv already holds exactly these requirements (a stamp
# file records their hash and the venv's interpreter) it returns at once without running
# pip. Override the base interpreter with PYTHON=/path/to/python3.11 (or python3.13).
# With no python3.13 on the machine (Debian 12 has none), --python 3.13 builds one from
# Debian 13's source package once, cached outside the repo (tools/build_python313.sh).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY=3.11
while (($#)); do
    case "$1" in
        --python) PY="${2:-}"; shift 2 ;;
        --python=*) PY="${1#--python=}"; shift ;;
        *) echo "setup: unknown argument '$1' (usage: tools/setup.sh [--python 3.11|3.13])" >&2; exit 2 ;;
    esac
done
case "$PY" in
    3.11) VENV="$ROOT/.venv"; REQUIREMENTS="$ROOT/requirements.txt"; BPY="bpy 5.0" ;;
    3.13) VENV="$ROOT/.venv-py313"; REQUIREMENTS="$ROOT/requirements-py313.txt"; BPY="bpy 5.2" ;;
    *) echo "setup: --python must be 3.11 or 3.13, not '$PY'" >&2; exit 2 ;;
esac
STAMP="$VENV/.pdic-requirements.sha256"

say() { echo "setup: $*" >&2; }

# The bpy wheel exists for exactly one CPython minor version.
python_is() { "$2" -c "import sys; sys.exit(0 if '%d.%d' % sys.version_info[:2] == '$1' else 1)" 2>/dev/null; }

# What the stamp records: the requirements and the venv's exact interpreter.
requirements_hash() {
    { cat "$REQUIREMENTS"; "$VENV/bin/python" -c 'import sys; print(sys.version.split()[0])'; } \
        | sha256sum | cut -d' ' -f1
}

# The compiled kernels of Equation 3 (core/native_kernels.py), built with this machine's C compiler when
# missing or older than their source; without a compiler PDIC bakes with numpy kernels, and says so.
build_native() { "$VENV/bin/python" "$ROOT/tools/build_native.py" || say "warning: compiled kernels not built"; }

# Fast path: already set up.
if [[ -x "$VENV/bin/python" ]] && python_is "$PY" "$VENV/bin/python" \
    && [[ -f "$STAMP" ]] && [[ "$(cat "$STAMP")" == "$(requirements_hash)" ]]; then
    build_native
    exit 0
fi

# The first candidate interpreter that really is CPython $PY (a pyenv shim for a version
# that is not active exists on PATH but does not run).
find_base_python() {
    local candidates candidate
    if [[ -n "${PYTHON:-}" ]]; then
        candidates=("$PYTHON")
    elif [[ "$PY" == 3.11 ]]; then
        candidates=(python3 python3.11)
    else
        candidates=(python3.13 python3)
    fi
    for candidate in "${candidates[@]}"; do
        if command -v "$candidate" >/dev/null 2>&1 && python_is "$PY" "$candidate"; then
            command -v "$candidate"
            return 0
        fi
    done
    if [[ "$PY" == 3.13 && -z "${PYTHON:-}" ]]; then
        say "no python3.13 found: tools/build_python313.sh provides one (built once from Debian 13's source package, ~2.5 min, then cached)"
        bash "$ROOT/tools/build_python313.sh"
        return 0
    fi
    local found=""
    for candidate in "${candidates[@]}"; do
        found+=" $candidate ($("$candidate" --version 2>&1 || true));"
    done
    say "error: PDIC needs CPython $PY (the $BPY wheel exists only for $PY). Tried:$found"
    say "       install Python $PY, or run with PYTHON=/path/to/python$PY"
    return 1
}

start=$SECONDS
# A venv whose creation was interrupted has its python but no pip: make it again.
if [[ ! -x "$VENV/bin/python" ]] || ! python_is "$PY" "$VENV/bin/python" \
        || ! "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
    BASE_PYTHON="$(find_base_python)"
    say "creating $VENV with $BASE_PYTHON ($("$BASE_PYTHON" --version 2>&1))"
    rm -rf "$VENV"
    "$BASE_PYTHON" -m venv "$VENV"
fi

say "installing pinned requirements from $(basename "$REQUIREMENTS") (pip)"
rm -f "$STAMP"
"$VENV/bin/python" -m pip install --disable-pip-version-check -q -r "$REQUIREMENTS"
requirements_hash >"$STAMP"
build_native
say "ready in $((SECONDS - start)) s: $VENV"
