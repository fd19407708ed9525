"""Small Blender scenes and fast settings shared by the add-on tests (bpy; import as ``addon_scenes``)."""
from __future__ import annotations


def lamp(bpy, energy: float = 300.0):
    """A point light 3 units above the origin (300 W: E/pi ~ 0.84 right below it)."""
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
    bpy.context.object.data.energy = energy
    return bpy.context.object


def fast_settings(bpy, resolution: int, image_format: str | None = None) -> None:
    """Custom quality cheap enough for a test: 2000 photons, one bounce, a 2x4 hemisphere."""
    props = bpy.context.scene.pdic
    props.quality = "CUSTOM"
    props.photons = 2000
    props.max_bounces = 1
    props.hemisphere_theta, props.hemisphere_phi = 2, 4
    props.default_resolution = resolution
    if image_format is not None:
        props.image_format = image_format
