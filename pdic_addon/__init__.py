"""Everything of PDIC that touches bpy; registration stays thin and symmetric.

Each module listed in :data:`MODULE_NAMES` has its own symmetric
``register()``/``unregister()`` (most also export ``classes``); they are
registered in this order and unregistered in reverse.
"""
from __future__ import annotations

import importlib

MODULE_NAMES = ("preferences", "properties", "operators", "gltf_export", "panels", "overlay")


def _modules():
    return [importlib.import_module(f".{name}", __package__) for name in MODULE_NAMES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
