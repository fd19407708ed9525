#!/usr/bin/env bash
# Bake a sample scene headless and print stage times and output paths.
#
#   bash tools/bake_sample.sh                             # cornell_point -> out/cornell_point
#   bash tools/bake_sample.sh cornell_point --quality FINAL
#   bash tools/bake_sample.sh SCENE [pdic_bake.py options...]
#
# Sets up .venv, generates sample_blends/*.blend when the scene is missing
# (sample_blends/generate.py), then runs pdic_bake.py with the bpy wheel.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/tools/setup.sh"
cd "$ROOT"
PY="$ROOT/.venv/bin/python"

scene="cornell_point"
if [[ $# -gt 0 && "$1" != -* ]]; then
    scene="$1"
    shift
fi
blend="sample_blends/$scene.blend"

if [[ ! -f "$blend" ]]; then
    echo "bake_sample: $blend missing, generating sample scenes (sample_blends/generate.py)" >&2
    "$PY" sample_blends/generate.py
    if [[ ! -f "$blend" ]]; then
        echo "bake_sample: error: sample_blends/generate.py did not write $blend; scenes there:" >&2
        ls sample_blends/*.blend >&2 2>/dev/null || echo "  (none)" >&2
        exit 1
    fi
fi

exec "$PY" pdic_bake.py --blend "$blend" --output "out/$scene" --preview-png "out/$scene/preview.png" --exposure -1 "$@"
