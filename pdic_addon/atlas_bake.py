"""Atlas mode of a bake: many objects share a few light-map images (:mod:`core.atlas`).

The job calls one hook per step, each on the step's thread:

1. :func:`density_scales` (choose, main): each object's texel-density factor from
   its resolution override.
2. :func:`unwrap_into_atlases` (unwrap, worker, no bpy): each mesh's own unwrap
   (cached) or, for an object naming Light-Map UVs, its islands as they are, then all
   charts packed together; the job's ``uv_loops`` get the atlas
   UVs (the extract step writes them into ``PDIC_Lightmap``) and its resolutions
   become each object's *window* of its atlas.
3. :func:`window_scene` (extract, main, after extraction): each target's UVs
   re-expressed in its window, so the unchanged pipeline bakes the window's texels.
4. :func:`write_atlas_images` (finish, main): covered window texels copied into the
   atlases, the atlases dilated once and written like per-object maps (a re-bake
   under temporary names); :func:`swap_atlas_images` gives them their final names
   when the job swaps its outputs in.
"""
from __future__ import annotations

from dataclasses import replace

import bpy

from ..core import atlas as core_atlas
from ..core import unwrap
from ..core.executor import Progress
from . import writeback

ATLAS_PREFIX = "Atlas"
"""Atlas images are ``PDIC_Atlas<index>`` (``writeback.image_name`` of ``Atlas<index>``), owned by
``Atlas<index>``; their files ``<blend>.PDIC_Atlas<index>.exr``."""
CHART_RESOLUTION = 256
"""Resolution of each object's own unwrap in atlas mode: only its charts are kept (the map
grows until xatlas packs them, as Sponza's many small charts need)."""


def atlas_key(index: int) -> str:
    return f"{ATLAS_PREFIX}{index}"


def object_charts(tris, scale, padding: int, cache_dir, max_resolution: int, **hooks) -> unwrap.UnwrapResult:
    """The mesh's own unwrap (cached by content) at world scale ``scale``: its charts, at any packing.

    hooks : ``cancelled`` and ``progress`` of :func:`core.unwrap.unwrap`.
    """
    return unwrap.unwrap(tris.positions * scale, tris.triangles, CHART_RESOLUTION, padding, cache_dir=cache_dir,
                         triangle_polygon=tris.polygon, max_resolution=max(max_resolution, CHART_RESOLUTION),
                         **hooks)


def refuse_shared_meshes(mesh_users: dict) -> None:
    """Objects sharing a mesh cannot share one atlas place (they would share texels): ValueError naming them."""
    for mesh_name, users in mesh_users.items():
        if len(users) > 1:
            raise ValueError(f"atlas mode: objects {', '.join(users)} share mesh {mesh_name!r}; each needs its own "
                             f"place in the atlas: make the mesh single-user (Object > Relations) or bake without "
                             f"atlases")


def density_scales(job) -> dict:
    """Hook 1 (choose, main thread): object name -> texel density relative to the others
    (a resolution override / the size its area would get; 1 without override)."""
    scales = {}
    for mesh_name, (name,) in job.mesh_users.items():
        override = getattr(getattr(bpy.data.objects[name], "pdic", None), "resolution", 0)
        scales[name] = 1.0
        if override:
            s, tris = job.settings, job.triangles[mesh_name]
            auto = unwrap.choose_resolution(tris.surface_area(tuple(job.scales[mesh_name])), s.texel_density or 1.0,
                                            s.default_resolution, s.min_resolution, s.max_resolution)
            scales[name] = float(override) / max(auto, 1)
    return scales


def unwrap_into_atlases(job, progress: Progress, hooks) -> core_atlas.AtlasLayout:
    """Hook 2 (unwrap, worker thread, no bpy): pack every bake object into ``job.atlas_size`` atlases.

    Fills ``job.uv_loops`` (per mesh), ``job.resolutions`` (the windows) and ``job.unwraps``;
    ``hooks(label, fraction)`` gives the cancel/progress arguments of ``core.unwrap.unwrap``.
    """
    s = job.settings
    inputs, results = [], {}
    for i, (mesh_name, (name,)) in enumerate(job.mesh_users.items()):
        tris, scale = job.triangles[mesh_name], job.scales[mesh_name]
        if mesh_name in job.user_uvs:  # the user's islands are the charts: packed, each kept whole
            layout = job.checked_user_layout(mesh_name, name)
            result = unwrap.UnwrapResult(layout.uv, chart_count=0, utilization=layout.utilization)
        else:
            try:
                result = object_charts(tris, scale, s.padding, job.cache_dir, s.max_resolution,
                                       **hooks(mesh_name, i / len(job.mesh_users)))
            except (ValueError, RuntimeError) as e:  # bad geometry (DegenerateMeshError), or xatlas failing
                raise ValueError(f"cannot unwrap mesh {mesh_name!r} (object {name!r}): {e}") from e
        job.warnings += list(result.warnings)
        results[name] = (mesh_name, tris, result)
        inputs.append(core_atlas.AtlasInput(name, tris.positions * scale, tris.triangles, result.uv,
                                            job.atlas_density.get(name, 1.0)))
        progress.update((i + 1) / (len(job.mesh_users) + 1))
    progress.begin("Packing the atlases (xatlas)")
    try:  # in a child process: a crash or hang of xatlas cannot take Blender down
        layout = core_atlas.pack_atlases(inputs, job.atlas_size, s.padding, s.texel_density,
                                         cancelled=progress.cancel_requested.is_set)
    except unwrap.UnwrapError as e:
        raise ValueError(f"cannot pack the atlases: {e}") from e
    for p in layout.placements:
        mesh_name, tris, result = results[p.name]
        uv_loop, conflicts = unwrap.loop_uvs(p.uv, tris.loops, tris.loop_count)
        if conflicts:
            job.warnings.append(f"mesh {mesh_name!r}: {conflicts} polygon corners got split UVs")
        job.uv_loops[mesh_name] = uv_loop
        job.resolutions[p.name] = (p.window[2], p.window[3])
        source = ({"uv_source": job.user_uvs[mesh_name][0]} if mesh_name in job.user_uvs else
                  {"charts": result.chart_count, "unwrap_cached": result.from_cache})
        job.unwraps[p.name] = {**source, "atlas": p.atlas, "atlas_window": list(p.window)}
    progress.update(1.0)
    return layout


def window_scene(scene, layout: core_atlas.AtlasLayout):
    """Hook 3 (extract): the extracted scene with each target's atlas UVs mapped into its window."""
    targets = []
    for t in scene.targets:
        p = layout.placement(t.name)
        targets.append(replace(t, lightmap_uv=p.window_uv(layout.size, t.lightmap_uv),
                               width=p.window[2], height=p.window[3]))
    return replace(scene, targets=tuple(targets))


def atlas_images(layout: core_atlas.AtlasLayout, result, padding: int) -> tuple[dict, int]:
    """Atlas key -> (size, size, 4) float32 RGBA, and texels two objects both cover (0)."""
    images, conflicts = core_atlas.composite(layout, result.lightmaps, result.coverage, padding + 2)
    return {atlas_key(i): image for i, image in enumerate(images)}, conflicts


def write_atlas_images(job) -> dict:
    """Hook 4 (finish): composite and write one image per atlas, each file through
    ``writeback.write_image`` (backed up, undone on rollback); a re-bake writes the
    datablock under a temporary name. Returns atlas key -> (image, relpath, pixels)."""
    images, conflicts = atlas_images(job.atlas_layout, job.result, job.settings.padding)
    if conflicts:  # a packing bug, never the user's input
        raise ValueError(f"atlas: {conflicts} texels are covered by two objects (please report this scene)")
    written = {}
    for key, pixels in images.items():
        pixels = job._storable(key, pixels)
        rebake = bool(writeback.owned_images(key))
        temp = writeback.image_name(key) + writeback.TEMPORARY_SUFFIX if rebake else None
        image, relpath = writeback.write_image(key, pixels, job.plan, job.image_format, job.txn, name=temp)
        written[key] = (image, relpath, pixels)
    return written


def atlas_of(name: str, layout, written: dict):
    """The ``(image, relpath, pixels)`` of the atlas holding object ``name``; None without atlases."""
    return None if layout is None else written[atlas_key(layout.placement(name).atlas)]


def atlases_in_use(excluded: set) -> set:
    """Keys of the atlases whose images material copies of objects not in ``excluded`` (names) show."""
    keys = set()
    for copy in writeback.owned_materials():
        owner = writeback.owner_of(copy)
        if owner is None or owner.name in excluded or copy.node_tree is None:
            continue
        for node in copy.node_tree.nodes:
            image = getattr(node, "image", None)
            if writeback.is_pdic(image) and str(image[writeback.OWNER]).startswith(ATLAS_PREFIX):
                keys.add(image[writeback.OWNER])
    return keys


def swap_atlas_images(written: dict, txn, warnings: list) -> None:
    """Retire the previous images of the atlases just written and give the new ones their names (undoable)."""
    for key, (image, _, _) in written.items():
        writeback.retire_outputs(key, {image}, txn, warnings)
        writeback.rename(image, writeback.image_name(key), txn)
