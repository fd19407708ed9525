"""Bake settings stored in the .blend: ``scene.pdic`` and ``object.pdic``.

The UI edits these properties; :func:`to_settings` turns them into the frozen
:class:`core.settings.BakeSettings` that crosses into the core (STYLE.md,
principle 2). Tooltips are the settings' own documentation.
"""
from __future__ import annotations

from dataclasses import replace

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from ..core import settings as core_settings
from ..core.constants import CYCLES_WHOLE_TEXEL_FOOTPRINT

DEFAULTS = core_settings.BakeSettings()
DEFAULT_OUTPUT = "//pdic_lightmaps/"

QUALITY_ITEMS = (
    ("PREVIEW", "Preview", "Passes 1-2: photon map and coarse irradiance cache (fast, for layout)"),
    ("FINAL", "Final", "Passes 1-3: irradiance cache refined with photon-path reuse"),
    ("CUSTOM", "Custom", "Passes 1-3 with the photon, bounce and cache settings below"),
)
IMAGE_FORMAT_ITEMS = (
    ("EXR_HALF", "OpenEXR Half", "16-bit float OpenEXR (ZIP): half the size, 3 significant digits"),
    ("EXR_FLOAT", "OpenEXR Float", "32-bit float OpenEXR (ZIP): exact"),
)
# Path properties that may hold "//" (relative to the .blend); Blender 5.0 warns unless they say so.
BLEND_RELATIVE = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (5, 0, 0) else set()

# BakeSettings fields a quality preset decides unless the quality is CUSTOM.
PRESET_FIELDS = ("photons", "max_bounces", "density_control", "a", "hemisphere_theta", "hemisphere_phi",
                 "direct_samples")


def _redraw_viewports(self, context):
    from . import overlay

    overlay.tag_redraw(context)


class PDIC_SceneSettings(bpy.types.PropertyGroup):
    """Scene-wide PDIC bake settings."""

    quality: EnumProperty(name="Quality", items=QUALITY_ITEMS, default="FINAL",
                          description="How much work the bake does: Preview (no refinement, fast), Final "
                                      "(the paper's three passes) or Custom (your photon, bounce and cache "
                                      "settings)")
    photons: IntProperty(name="Photons", default=DEFAULTS.photons, min=1000, soft_max=4_000_000,
                         description="Photons emitted, shared among lights by power (Custom quality). Typical 100k-4M")
    max_bounces: IntProperty(name="Max Bounces", default=DEFAULTS.max_bounces, min=1, max=255,
                             description="Safety limit on a photon's diffuse bounces (Custom quality); Russian "
                                         "roulette ends paths first. Below ~16 it darkens bright, enclosed scenes")
    density_control: IntProperty(name="Density Control", default=DEFAULTS.density_control, min=0, soft_max=256,
                                 description="Most photons wanted in a record's zone of influence (paper section "
                                             "3.4, Custom quality); fewer are kept where records are large, their "
                                             "power moved to neighbours. 0 = off. Typical 32-64")
    a: FloatProperty(name="Accuracy a", default=DEFAULTS.a, min=0.05, max=2.0, step=5, precision=2,
                     description="Ward's accuracy a: smaller = more cache records, fewer artefacts (Custom quality). "
                                 "Typical 0.2-0.5")
    hemisphere_theta: IntProperty(name="Hemisphere Rows", default=DEFAULTS.hemisphere_theta, min=1, max=256,
                                  description="Theta rows of the stratified hemisphere used to refine records "
                                              "(pass 3, Custom quality). Typical 8-16; rows x columns = cells "
                                              "per record")
    hemisphere_phi: IntProperty(name="Hemisphere Columns", default=DEFAULTS.hemisphere_phi, min=1, max=512,
                                description="Phi columns of the stratified hemisphere used to refine records "
                                            "(pass 3, Custom quality). Typical 2x the rows")
    direct_samples: IntProperty(name="Direct Samples", default=DEFAULTS.direct_samples, min=1, soft_max=256,
                                max=1024,
                                description="Shadow rays per texel sample toward each soft light: area lights, "
                                            "a sun or lamp with a size, emissive meshes, and the sky when no "
                                            "indirect light is baked (otherwise the cache's records bring the "
                                            "sky) (Custom quality). Raise it for grainy soft shadows. "
                                            "Typical 16-256")
    texel_density: FloatProperty(name="Texel Density", default=DEFAULTS.texel_density, min=0.0, soft_max=256.0,
                                 description="Texels per scene unit: each map grows until its charts fit at this "
                                             "density (0 = use the default resolution). Typical 8-64 for "
                                             "metre-scale scenes")
    default_resolution: IntProperty(name="Resolution", default=DEFAULTS.default_resolution, min=8, max=8192,
                                    description="Light-map width and height of an object without an override, "
                                                "when the texel density is 0")
    atlas_size: IntProperty(name="Atlas Size", default=0, min=0, max=16384,
                            description="Pack all baked objects into shared light-map atlases of this width and "
                                        "height (0 = one light map per object). Typical 1024-4096")
    direct: BoolProperty(name="Direct", default=True,
                         description="Bake direct light: shadow rays from every texel to every light")
    indirect: BoolProperty(name="Indirect", default=True,
                           description="Bake indirect (bounced) light from the photon-driven irradiance cache")
    seed: IntProperty(name="Seed", default=0, min=0, description="Random seed; the same seed gives the same light maps")
    output_folder: StringProperty(name="Output Folder", default=DEFAULT_OUTPUT, subtype="DIR_PATH",
                                  options=BLEND_RELATIVE,
                                  description="Folder for the light-map images and pdic_manifest.json "
                                              "(// = next to the .blend)")
    image_format: EnumProperty(name="Image Format", items=IMAGE_FORMAT_ITEMS, default="EXR_HALF",
                               description="File format of the light maps")

    # -- display (viewport only; never changes a bake) ----------------------------------
    show_records: BoolProperty(name="Show Cache Records", default=False, update=_redraw_viewports,
                               description="Draw the last bake's irradiance records in the 3D viewport: a point "
                                           "at each record p_k coloured by its indirect irradiance E_k")
    show_record_discs: BoolProperty(name="Zones of Influence", default=False, update=_redraw_viewports,
                                    description="Also draw each record's zone of influence: a disc of radius a*R_k "
                                                "facing n_k (gaps are where texels needed hole records)")
    record_point_size: FloatProperty(name="Point Size", default=5.0, min=1.0, max=32.0, subtype="PIXEL",
                                     update=_redraw_viewports,
                                     description="Diameter of the record points in pixels. Typical 3-8")

    # -- the last bake (written by the bake, read by the panel and the overlay) -----------
    last_stats: StringProperty(name="Last Bake Statistics", default="",
                               description="Statistics of the last bake as JSON (per-pass seconds, photons, "
                                           "records, rays); the manifest holds the same")
    manifest_file: StringProperty(name="Last Manifest", default="", subtype="FILE_PATH", options=BLEND_RELATIVE,
                                  description="pdic_manifest.json of the last bake ('' if the light maps were "
                                              "packed into the .blend)")
    records_file: StringProperty(name="Last Cache Records", default="", subtype="FILE_PATH", options=BLEND_RELATIVE,
                                 description="The last bake's irradiance records (pdic_records.npz), drawn by "
                                             "Show Cache Records")


class PDIC_ObjectSettings(bpy.types.PropertyGroup):
    """Per-object PDIC bake settings."""

    bake: BoolProperty(name="Bake Light Map", default=True,
                       description="Give this object a light map (off: it only casts shadows and bounces light)")
    resolution: IntProperty(name="Resolution Override", default=0, min=0, max=8192,
                            description="Light-map width and height for this object (0 = from the scene settings)")
    uv_map: StringProperty(name="Light-Map UVs", default="",
                           description="Bake into this UV map of the mesh as it is laid out (your own light-map "
                                       "UVs: islands inside the 0-1 square, none overlapping; copied into "
                                       "PDIC_Lightmap, yours is not changed). Empty = PDIC unwraps the mesh")


def to_settings(props, quality: str | None = None, **overrides) -> core_settings.BakeSettings:
    """The frozen core settings for ``scene.pdic`` (plus explicit field overrides).

    PREVIEW and FINAL take photons, bounces, ``a`` and the hemisphere from their
    preset; CUSTOM takes them from the properties. Passes, seed, resolution and
    texel density always come from the properties. Threads are a per-machine
    preference, not a scene setting: pass ``threads=`` (default 0 = all cores).
    ``quality`` replaces ``props.quality``; ``overrides`` replace any field last.
    """
    quality = (quality or props.quality).upper()
    base = core_settings.preset(quality)
    fields = dict(
        direct=bool(props.direct), indirect=bool(props.indirect), seed=int(props.seed),
        texel_density=float(props.texel_density), default_resolution=int(props.default_resolution),
        direct_footprint_side=cycles_footprint_side(bpy.app.version),
    )
    if quality == "CUSTOM":
        fields.update({name: getattr(props, name) for name in PRESET_FIELDS})
        fields["a"] = float(fields["a"])
    fields.update(overrides)
    return replace(base, **fields)


def cycles_footprint_side(version: tuple) -> float:
    """Width (texels) of the square this Blender's Cycles bake averages a texel over (0.5 before 5.2)."""
    return 1.0 if tuple(version) >= CYCLES_WHOLE_TEXEL_FOOTPRINT else 0.5


classes = (PDIC_SceneSettings, PDIC_ObjectSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.pdic = PointerProperty(type=PDIC_SceneSettings)
    bpy.types.Object.pdic = PointerProperty(type=PDIC_ObjectSettings)


def unregister():
    del bpy.types.Object.pdic
    del bpy.types.Scene.pdic
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
