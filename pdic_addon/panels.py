"""The "Lightmaps" tab of the 3D viewport sidebar (N-panel) and the Object-properties panel.

Drawing is split into one small function per section, each taking a layout
and plain data (``draw_quality(layout, props)``, ``draw_stats(layout, stats)``);
the Panel classes only pick the data from the context and call them. What a
section shows is computed by pure helpers (:func:`preset_summary`,
:func:`stats_rows`, :func:`shading_state`) that tests call directly.

Sidebar layout::

    PDIC Light Maps       [Bake All] [Bake Selected] [Clear]   (progress + Cancel while baking)
                          Quality: Preview | Final | Custom
      Settings            photons, bounces, a, hemisphere (Custom only); density/resolution, passes, seed
      Output              folder, image format
      Active Object       bake on/off, resolution override, light-map UVs of its own, its light map
      Display             Original | Baked Lighting; Show Cache Records (+ zones, point size)
      Last Bake           per-pass seconds, photons, records, rays cast / saved
"""
from __future__ import annotations

import json

import bpy

from ..core import settings as core_settings
from . import writeback
from .operators import PDIC_OT_bake

CATEGORY = "Lightmaps"

# Stage keys of the stats (core/pipeline.py, job.py) -> what the panel calls them, in bake order.
STAGE_LABELS = (
    ("addon_choose", "Choose objects"),
    ("addon_unwrap", "Unwrap UVs"),
    ("addon_extract", "Extract scene"),
    ("bvh", "Build BVH"),
    ("rasterise", "Rasterise texels"),
    ("validity", "Texel validity"),
    ("verdicts_wait", "Waiting for texel validity"),
    ("direct", "Direct light"),
    ("direct_wait", "Waiting for direct light"),
    ("photons", "Pass 1: photons"),
    ("cache", "Pass 2: cache"),
    ("photon_direct", "Pass 3: photon direct"),
    ("refine", "Pass 3: refine"),
    ("interpolate", "Interpolate"),
    ("texels", "Small objects' texels"),
    ("texels_wait", "Waiting for small objects"),
    ("dilate", "Dilate"),
    ("addon_write_images", "Write images"),
)

OVERLAPPING_STAGES = ("addon_compute", "addon_finish")
"""Timings that contain other stages: not listed, not added to the total."""


# --------------------------------------------------------------------------- pure helpers
def preset_summary(quality: str) -> str:
    """One line saying what a preset does, e.g. ``250,000 photons, up to 64 bounces, a 0.40, 12x24 cells``."""
    s = core_settings.preset(quality)
    cells = f"{s.hemisphere_theta}x{s.hemisphere_phi} cells" if s.refine else "no refinement"
    return f"{s.photons:,} photons, up to {s.max_bounces} bounces, a {s.a:.2f}, {cells}"


def _count(value) -> str:
    """A counter for a narrow column: 1,234 / 56k / 7.89M / 1.23G."""
    if isinstance(value, float) and not value.is_integer():
        return f"{value:.3g}"
    value = int(value)
    if abs(value) >= 1_000_000_000:
        return f"{value / 1e9:.2f}G"
    if abs(value) >= 1_000_000:
        return f"{value / 1e6:.2f}M"
    if abs(value) >= 10_000:
        return f"{value / 1e3:.0f}k"
    return f"{value:,}"


def stats_rows(stats: dict) -> list[tuple[str, str]]:
    """(label, value) rows for the Last Bake section from a bake's stats dict (``scene.pdic.last_stats``).

    Per-pass wall seconds in bake order (a stage that ran beside others marked, and left out of
    the total, whose stages it overlapped), the total, then photons, records,
    rays cast and the rays saved by reusing photon paths (pass 3). Missing
    keys are left out (a Preview bake has no refinement).
    """
    rows: list[tuple[str, str]] = []
    seconds = stats.get("seconds", {})
    beside = stats.get("seconds_beside", [])  # ran beside other stages (direct light, validity beside pass 2)
    known = {k for k, _ in STAGE_LABELS}
    for key, label in STAGE_LABELS:
        if key in seconds:
            rows.append((label + (" (beside)" if key in beside else ""), f"{seconds[key]:.2f} s"))
    for key in seconds:  # stages a newer core adds
        if key not in known and key not in OVERLAPPING_STAGES:
            rows.append((key.replace("_", " ").capitalize(), f"{seconds[key]:.2f} s"))
    if seconds:  # addon_compute spans the core stages; addon_finish spans writing images; beside: overlapped
        total = sum(v for k, v in seconds.items() if k not in OVERLAPPING_STAGES and k not in beside)
        rows.append(("Total", f"{total:.2f} s"))
    c = stats.get("counters", {})
    if "photons_emitted" in c:
        stored = _count(c.get("photons_stored", 0))
        rows.append(("Photons emitted / stored", f"{_count(c['photons_emitted'])} / {stored}"))
    if "records" in c:
        rows.append(("Records (pass 2)", _count(c["records"])))
    if "records_total" in c:
        holes = _count(c.get("hole_records", 0))
        rows.append(("Records incl. holes", f"{_count(c['records_total'])} ({holes} holes)"))
    if "rays_cast" in c:
        rows.append(("Rays cast", _count(c["rays_cast"])))
    if c.get("refine_cells") and c.get("refine_virtual_rays"):  # photon-path reuse on (not the default)
        saved = c["refine_virtual_rays"]
        share = c.get("refine_cells_virtual", 0) / c["refine_cells"]
        rows.append(("Rays saved (photon paths)", f"{_count(saved)} ({100 * share:.0f}% of cells)"))
    if "texels" in stats:
        rows.append(("Texels", _count(stats["texels"])))
    return rows


def parse_stats(text: str) -> dict | None:
    """``scene.pdic.last_stats`` as a dict, None if empty or unreadable."""
    if not text:
        return None
    try:
        stats = json.loads(text)
    except ValueError:
        return None
    return stats if isinstance(stats, dict) else None


def shading_state(scene) -> str | None:
    """What the scene's baked objects show: ``"BAKED"``, ``"ORIGINAL"``, ``"MIXED"``, or None if none is baked."""
    owners = {writeback.owner_of(m) for m in writeback.owned_materials()}
    shown = [writeback.is_baked_shading(o) for o in scene.objects if o in owners]
    if not shown:
        return None
    return "BAKED" if all(shown) else "ORIGINAL" if not any(shown) else "MIXED"


def bake_progress() -> tuple[float, str] | None:
    """(fraction, text) of the running modal bake, None when idle."""
    running = PDIC_OT_bake.running()
    if running is None:
        return None
    s = running.state
    if running.progress.cancel_requested.is_set():
        return s["fraction"], "Cancelling..."
    eta = f", {s['eta']:.0f} s left" if s["eta"] is not None else ""
    return s["fraction"], f"{s['stage']} {100 * s['fraction']:.0f}%{eta}"


# --------------------------------------------------------------------------- sections
def draw_actions(layout, progress: tuple[float, str] | None) -> None:
    """Bake All / Bake Selected / Clear, or the running bake's progress bar and Cancel."""
    if progress is not None:
        fraction, text = progress
        layout.progress(factor=fraction, text=text)
        layout.operator("pdic.cancel_bake", text="Cancel", icon="CANCEL")
        return
    row = layout.row(align=True)
    row.scale_y = 1.4
    row.operator("pdic.bake", text="Bake All", icon="RENDER_STILL").scope = "ALL"
    row.operator("pdic.bake", text="Bake Selected", icon="RESTRICT_SELECT_OFF").scope = "SELECTED"
    layout.operator("pdic.clear", text="Clear", icon="TRASH").scope = "ALL"
    layout.operator("pdic.export_glb", text="Export glTF", icon="EXPORT")


def draw_quality(layout, props) -> None:
    """Quality preset as a segmented row, with what the preset means underneath."""
    layout.row().prop(props, "quality", expand=True)
    if props.quality != "CUSTOM":
        layout.label(text=preset_summary(props.quality), icon="INFO")


def draw_custom_settings(layout, props) -> None:
    """Pass 1-3 settings; only shown for the Custom preset (the presets decide them otherwise)."""
    col = layout.column(align=True)
    col.prop(props, "photons")
    col.prop(props, "max_bounces")
    col.prop(props, "density_control")
    col = layout.column(align=True)
    col.prop(props, "a")
    col = layout.column(align=True)
    col.prop(props, "hemisphere_theta")
    col.prop(props, "hemisphere_phi", text="Columns")
    layout.column(align=True).prop(props, "direct_samples")


def draw_light_map_settings(layout, props) -> None:
    """Resolution (texel density or default resolution), passes and seed: used by every preset."""
    col = layout.column(align=True)
    col.prop(props, "texel_density")
    sub = col.column(align=True)
    sub.active = props.texel_density == 0.0  # the density wins when it is set
    sub.prop(props, "default_resolution")
    layout.prop(props, "atlas_size")
    row = layout.row(align=True, heading="Passes")
    row.prop(props, "direct", toggle=True)
    row.prop(props, "indirect", toggle=True)
    layout.prop(props, "seed")


def draw_output(layout, props) -> None:
    """Where the light maps and the manifest go, and in which format."""
    layout.prop(props, "output_folder", text="Folder")
    layout.prop(props, "image_format", text="Format")
    if props.output_folder.startswith("//") and not bpy.data.filepath:
        layout.label(text="Unsaved file: light maps are packed into the .blend", icon="PACKAGE")


def draw_object(layout, obj) -> None:
    """Per-object settings of ``obj`` (the active object) and what it has been baked to."""
    if obj is None or obj.type != "MESH":
        layout.label(text="Select a mesh to set its light map", icon="INFO")
        return
    settings = obj.pdic
    layout.prop(settings, "bake")
    sub = layout.column()
    sub.active = settings.bake
    sub.prop(settings, "resolution", text="Resolution")
    sub.prop_search(settings, "uv_map", obj.data, "uv_layers", icon="GROUP_UVS")
    if obj.library is not None or obj.data.library is not None:
        layout.label(text="Linked from a library: skipped by the bake", icon="LIBRARY_DATA_DIRECT")
    image = next(iter(writeback.owned_images(obj)), None)
    if image is not None:
        w, h = image.size
        layout.label(text=f"Light map {w}x{h}: {image.name}", icon="IMAGE_DATA")
        if writeback.is_baked_shading(obj):  # the material shown is rebuilt by every bake
            layout.label(text="Shown material is a baked copy: edit the original", icon="ERROR")
    elif settings.bake:
        layout.label(text="Not baked yet", icon="DOT")


def draw_display(layout, props, shading: str | None, has_records: bool) -> None:
    """Original vs baked shading, and the cache-record overlay toggles."""
    row = layout.row(align=True)
    row.enabled = shading is not None
    row.operator("pdic.toggle_shading", text="Original", depress=shading == "ORIGINAL").mode = "ORIGINAL"
    row.operator("pdic.toggle_shading", text="Baked Lighting", depress=shading == "BAKED").mode = "BAKED"
    if shading is None:
        layout.label(text="Nothing baked yet", icon="INFO")
    layout.prop(props, "show_records")
    sub = layout.column()
    sub.active = props.show_records
    sub.prop(props, "show_record_discs")
    sub.prop(props, "record_point_size")
    if props.show_records and not has_records:
        layout.label(text="Bake to create cache records", icon="INFO")


def draw_stats(layout, stats: dict | None) -> None:
    """The last bake's statistics as a two-column table."""
    if stats is None:
        layout.label(text="No bake yet")
        return
    objects = stats.get("objects", [])
    quality = str(stats.get("quality", "?")).title()
    layout.label(text=f"{len(objects)} object(s), {quality} quality", icon="RENDER_RESULT")
    if stats.get("finished"):
        layout.label(text=f"Finished {stats['finished']}")
    col = layout.column(align=True)
    for label, value in stats_rows(stats):
        split = col.split(factor=0.6)
        split.label(text=label)
        split.label(text=value)
    if stats.get("warnings"):
        layout.label(text=f"{stats['warnings']} warning(s): see the manifest", icon="ERROR")


# --------------------------------------------------------------------------- panels
class _Sidebar:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY

    @classmethod
    def poll(cls, context):
        return getattr(context.scene, "pdic", None) is not None


def _split(layout):
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class VIEW3D_PT_pdic(_Sidebar, bpy.types.Panel):
    """Bake light maps with the photon-driven irradiance cache"""

    bl_label = "PDIC Light Maps"
    bl_idname = "VIEW3D_PT_pdic"

    def draw(self, context):
        layout = self.layout
        draw_actions(layout, bake_progress())
        draw_quality(layout, context.scene.pdic)


class VIEW3D_PT_pdic_settings(_Sidebar, bpy.types.Panel):
    bl_label = "Settings"
    bl_parent_id = "VIEW3D_PT_pdic"

    def draw(self, context):
        props = context.scene.pdic
        layout = _split(self.layout)
        if props.quality == "CUSTOM":
            draw_custom_settings(layout, props)
            layout.separator()
        draw_light_map_settings(layout, props)


class VIEW3D_PT_pdic_output(_Sidebar, bpy.types.Panel):
    bl_label = "Output"
    bl_parent_id = "VIEW3D_PT_pdic"

    def draw(self, context):
        draw_output(_split(self.layout), context.scene.pdic)


class VIEW3D_PT_pdic_object(_Sidebar, bpy.types.Panel):
    bl_label = "Active Object"
    bl_parent_id = "VIEW3D_PT_pdic"

    def draw(self, context):
        draw_object(_split(self.layout), context.active_object)


class VIEW3D_PT_pdic_display(_Sidebar, bpy.types.Panel):
    bl_label = "Display"
    bl_parent_id = "VIEW3D_PT_pdic"

    def draw(self, context):
        props = context.scene.pdic
        draw_display(self.layout, props, shading_state(context.scene), bool(props.records_file))


class VIEW3D_PT_pdic_stats(_Sidebar, bpy.types.Panel):
    bl_label = "Last Bake"
    bl_parent_id = "VIEW3D_PT_pdic"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        draw_stats(self.layout, parse_stats(context.scene.pdic.last_stats))


class OBJECT_PT_pdic(bpy.types.Panel):
    """PDIC light-map settings of this object"""

    bl_label = "Light Map (PDIC)"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return context.object is not None and getattr(context.object, "pdic", None) is not None

    def draw(self, context):
        draw_object(_split(self.layout), context.object)


classes = (VIEW3D_PT_pdic, VIEW3D_PT_pdic_settings, VIEW3D_PT_pdic_output, VIEW3D_PT_pdic_object,
           VIEW3D_PT_pdic_display, VIEW3D_PT_pdic_stats, OBJECT_PT_pdic)


register, unregister = bpy.utils.register_classes_factory(classes)
