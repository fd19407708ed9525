"""PDIC core: photon-driven irradiance cache light-map baking, bpy-free.

Pure numpy/scipy/embreex/xatlas numerics. Never imports bpy: the Blender side
(``pdic_addon``) hands in a :class:`core.scene.Scene` and
:class:`core.settings.BakeSettings` and gets back light maps and statistics.
"""

__version__ = "0.1.0"
