"""Atlas mode of a bake: many objects share a few light-map images (:mod:`core.atlas`).

The job calls three hooks, one per step:

1. :func:`unwrap_into_atlases` (prepare): each mesh's own unwrap (cached), then all
   charts packed together; ``PDIC_Lightmap`` gets the atlas UVs, the job's
   resolutions become each object's *window* of its atlas.
2. :func:`window_scene` (prepare, after extraction): each target's UVs re-expressed
   in its window, so the unchanged pipeline bakes the window's texels.
3. :func:`atlas_images` (finish): covered window texels copied into the atlases,
   the atlases dilated once.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..core import atlas as core_atlas
from ..core import unwrap
from . import uvmaps

ATLAS_PREFIX = "Atlas"
"""Atlas images are ``PDIC_Atlas<index>`` (``writeback.image_name`` of ``Atlas<index>``)."""
CHART_RESOLUTION = 256
"""Resolution of each object's own unwrap in atlas mode: only its charts are kept (doubled
until xatlas packs them, as Sponza's many small charts need)."""


def atlas_key(index: int) -> str:
    return f"{ATLAS_PREFIX}{index}"


def _object_charts(mesh, tris, scale, padding: int, cache_dir, max_resolution: int):
    """The mesh's own unwrap (cached by content): its charts, at any packing."""
    res = CHART_RESOLUTION
    while True:
        try:
            return unwrap.unwrap(tris.positions * scale, tris.triangles, res, padding, cache_dir=cache_dir,
                                 triangle_polygon=tris.polygon)
        except RuntimeError:
            if res >= max_resolution:
                raise
            res = min(2 * res, max_resolution)


def unwrap_into_atlases(job, by_mesh: dict, triangles: dict) -> core_atlas.AtlasLayout:
    """Hook 1: pack every bake object into ``job.atlas_size`` atlases and write the UVs.

    Objects sharing a mesh cannot share one atlas place (they would share texels):
    raises ValueError naming them. Per-object resolution overrides scale the object's
    texel density relative to the others (override / the size its area would get).
    """
    shared = [users for users in by_mesh.values() if len(users) > 1]
    if shared:
        names = ", ".join(o.name for o in shared[0])
        raise ValueError(f"atlas mode: objects {names} share mesh {shared[0][0].data.name!r}; each needs its own "
                         f"place in the atlas: make the mesh single-user (Object > Relations) or bake without atlases")
    s = job.settings
    inputs, results = [], {}
    for mesh, (obj,) in by_mesh.items():
        tris = triangles[mesh]
        scale = np.asarray(tuple(obj.matrix_world.to_scale()), np.float64)
        try:
            result = _object_charts(mesh, tris, scale, s.padding, job.cache_dir, s.max_resolution)
        except (ValueError, RuntimeError) as e:
            raise ValueError(f"cannot unwrap mesh {mesh.name!r} (object {obj.name!r}): {e}") from e
        results[obj.name] = (mesh, tris, result)
        inputs.append(core_atlas.AtlasInput(obj.name, tris.positions * scale, tris.triangles, result.uv,
                                            _density_scale(obj, tris, scale, s)))
    layout = core_atlas.pack_atlases(inputs, job.atlas_size, s.padding, s.texel_density)
    for p in layout.placements:
        mesh, tris, result = results[p.name]
        uv_loop, conflicts = unwrap.loop_uvs(p.uv, tris.loops, tris.loop_count)
        if conflicts:
            job.warnings.append(f"mesh {mesh.name!r}: {conflicts} polygon corners got split UVs")
        uvmaps.write_lightmap_uv(mesh, uv_loop, job.txn)
        job.resolutions[p.name] = (p.window[2], p.window[3])
        job.unwraps[p.name] = {"charts": result.chart_count, "unwrap_cached": result.from_cache,
                               "atlas": p.atlas, "atlas_window": list(p.window)}
    return layout


def _density_scale(obj, tris, scale, settings) -> float:
    override = getattr(getattr(obj, "pdic", None), "resolution", 0)
    if not override:
        return 1.0
    auto = unwrap.choose_resolution(tris.surface_area(tuple(scale)), settings.texel_density or 1.0,
                                    settings.default_resolution, settings.min_resolution, settings.max_resolution)
    return float(override) / max(auto, 1)


def window_scene(scene, layout: core_atlas.AtlasLayout):
    """Hook 2: the extracted scene with each target's atlas UVs mapped into its window."""
    targets = []
    for t in scene.targets:
        p = layout.placement(t.name)
        targets.append(replace(t, lightmap_uv=p.window_uv(layout.size, t.lightmap_uv),
                               width=p.window[2], height=p.window[3]))
    return replace(scene, targets=tuple(targets))


def atlas_images(layout: core_atlas.AtlasLayout, result, padding: int) -> tuple[dict, int]:
    """Hook 3: atlas key -> (size, size, 4) float32 RGBA, and texels two objects both cover (0)."""
    images, conflicts = core_atlas.composite(layout, result.lightmaps, result.coverage, padding + 2)
    return {atlas_key(i): image for i, image in enumerate(images)}, conflicts


def write_atlas_images(job, plan) -> dict:
    """Hook 3 (finish): composite, write one image per atlas; object name -> (image, relpath, atlas pixels).

    A re-bake writes under a temporary name; :func:`commit_atlas_images` swaps it in.
    """
    from . import writeback

    images, conflicts = atlas_images(job.atlas_layout, job.result, job.settings.padding)
    if conflicts:  # a packing bug, never the user's input
        raise ValueError(f"atlas: {conflicts} texels are covered by two objects (please report this scene)")
    written = {}
    for key, pixels in images.items():
        temp = writeback.image_name(key) + ".pdic_new" if writeback.owned_images(key) else None
        image, relpath = writeback.write_image(key, pixels, plan, job.image_format, job.txn, name=temp)
        written[key] = (image, relpath, pixels)
    job.atlas_written = written
    return {p.name: written[atlas_key(p.atlas)] for p in job.atlas_layout.placements}


def commit_atlas_images(job) -> None:
    """Replace earlier atlas images by the new ones (names ``PDIC_Atlas<i>``)."""
    from . import writeback

    for key, (image, _, _) in job.atlas_written.items():
        writeback.remove_outputs(key, keep={image})
        image.name = writeback.image_name(key)
