"""Everything of PDIC that touches bpy; registration stays thin and symmetric.

Each module listed in :data:`MODULES` exports ``classes`` and its own
``register()``/``unregister()``; panels, the cache overlay and preferences
join the list as they are written.
"""
from __future__ import annotations

import importlib

MODULE_NAMES = ("properties", "operators")


def _modules():
    return [importlib.import_module(f".{name}", __package__) for name in MODULE_NAMES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
