"""Scenes opened in the bpy wheel that tests and the bench share: the sample Cornell box and
Sponza (read from ``../shared/scenes/sponza`` at run time, never copied) with two point lights."""
from __future__ import annotations

from pathlib import Path

import bpy

ROOT = Path(__file__).resolve().parents[1]
SPONZA = ROOT.parent / "shared" / "scenes" / "sponza" / "sponza.obj"

SPONZA_LIGHTS = (("AtriumWest", (-7.0, 0.0, 4.0)), ("AtriumEast", (7.0, 0.0, 4.0)))
"""Two point lights in the atrium (Blender Z up after import), 4 m up, 7 m either side of its centre."""
SPONZA_POWER_W = 3000.0


def load_cornell(name: str = "cornell_point") -> list:
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{name}.blend"))
    return [o for o in bpy.context.scene.objects if o.type == "MESH"]


def load_sponza() -> list:
    """Crytek Sponza from ``../shared/scenes/sponza`` and two point lights in its atrium."""
    if not SPONZA.is_file():
        raise FileNotFoundError(f"Sponza not found at {SPONZA}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.obj_import(filepath=str(SPONZA))
    for name, location in SPONZA_LIGHTS:
        data = bpy.data.lights.new(name, "POINT")
        data.energy = SPONZA_POWER_W
        data.shadow_soft_size = 0.0
        light = bpy.data.objects.new(name, data)
        light.location = location
        bpy.context.scene.collection.objects.link(light)
    return [o for o in bpy.context.scene.objects if o.type == "MESH" and len(o.data.polygons)]
