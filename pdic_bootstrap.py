"""Import this repository as the package ``pdic`` from a plain checkout.

Blender installs the extension as a package; a checkout is just a folder. Both
the headless bake script and the tests call :func:`load` so that
``pdic.pdic_addon`` and ``pdic.core`` resolve with the same relative imports
the installed extension uses.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent


def load(name: str = "pdic"):
    """Return the repository as package ``name`` (imported once, then cached in sys.modules)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
