"""The shape the code keeps (STYLE.md): short functions in core/, one registry for thresholds."""
from __future__ import annotations

import ast
import re

from conftest import ROOT

MAX_LINES = 80


def _functions(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node.name, node.lineno, node.end_lineno - node.lineno + 1


def test_no_core_function_over_80_lines():
    long = [f"{path.name}:{line} {name} ({length} lines)"
            for path in sorted((ROOT / "core").glob("*.py"))
            for name, line, length in _functions(path) if length > MAX_LINES]
    assert not long, "functions over 80 lines in core/: " + ", ".join(long)


def test_random_streams_are_named_constants():
    # Every generator of the bake is seeded [seed, STREAM_..., ...]: no literal stream id.
    literal = re.compile(r"default_rng\(\[\s*(settings\.)?seed\s*,\s*\d")
    found = [f"{path.name}:{i}" for path in sorted((ROOT / "core").glob("*.py"))
             for i, line in enumerate(path.read_text().splitlines(), 1) if literal.search(line)]
    assert not found, "literal random stream ids: " + ", ".join(found)
