"""PDIC: photon-driven irradiance cache light-map baking for Blender (extension entry point).

The repository root is the extension package: Blender imports it as
``bl_ext.<repo>.pdic``; tests import it as ``pdic`` (see tests/conftest.py).
Registration stays thin: everything Blender-facing lives in ``pdic_addon``,
the numerics in the bpy-free ``core``.
"""


def register():
    from .pdic_addon import register as _register

    _register()


def unregister():
    from .pdic_addon import unregister as _unregister

    _unregister()
