"""Benchmark scenes, built in the bpy wheel: Cornell (sample blend), Sponza (OBJ) and a generated,
densely occluded building of the project's own.

Each ``load_*`` opens or builds the scene in the current Blender session and
returns the mesh objects to bake. :func:`prepare` runs the add-on's job up to
extraction (resolution, xatlas unwrap into ``PDIC_Lightmap`` with a cache
folder, extraction) and returns the core scene.
"""
from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from tests.blend_scenes import SPONZA, SPONZA_LIGHTS, SPONZA_POWER_W, load_cornell, load_sponza  # noqa: E402,F401


# --------------------------------------------------------------------------- generated building
def boxes_mesh(name: str, boxes: list) -> bpy.types.Mesh:
    """A mesh of axis-aligned boxes ((x0, y0, z0), (x1, y1, z1)), every face facing out of its box."""
    verts, faces = [], []
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for lo, hi in boxes:
        base = len(verts)
        for i in range(8):
            verts.append((hi[0] if i & 4 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 1 else lo[2]))
        faces += [tuple(base + k for k in q) for q in quads]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    # outward normals (box corners are listed so some quads wind inward)
    import bmesh
    bm = bmesh.new()
    bm.from_mesh(mesh)
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
    bm.to_mesh(mesh)
    bm.free()
    return mesh


def _boxes_object(name: str, boxes: list, colour) -> bpy.types.Object:
    """One mesh object made of axis-aligned boxes (:func:`boxes_mesh`) with a Principled BSDF of ``colour``."""
    mesh = boxes_mesh(name, boxes)
    mat = bpy.data.materials.new(name + "Mat")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*colour, 1.0)
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


OCCLUDED_LAMPS = (("Lamp1", (3.0, 3.0, 1.8), 800.0), ("Lamp3", (15.0, 4.5, 4.8), 800.0))
"""The occluded building's point lamps: (name, location, watts), in rooms 1 and 3."""


def load_occluded(lamps=OCCLUDED_LAMPS) -> list:
    """Three rooms in a row joined by doorways, a columned hall, a stair to a railed gallery.

    18 m x 6 m x 6 m shell (two storeys of 3 m; the gallery floor covers half of room 3),
    lit by two point lights in rooms 1 and 3 only: room 2 and the gallery get light
    through doorways and the stair well, past columns, stairs and railing bars.
    lamps : the point lamps of radius 0, (name, location, watts) each (default OCCLUDED_LAMPS).
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    t = 0.2  # wall thickness
    L, W, H = 18.0, 6.0, 6.0
    shell = [((-t, -t, -t), (L + t, W + t, 0)), ((-t, -t, H), (L + t, W + t, H + t)),
             ((-t, -t, 0), (0, W + t, H)), ((L, -t, 0), (L + t, W + t, H)),
             ((0, -t, 0), (L, 0, H)), ((0, W, 0), (L, W + t, H))]
    walls = []
    for x in (6.0, 12.0):  # partitions with a 1.2 m doorway (2.2 m high) and a window upstairs
        walls += [((x - t / 2, 0, 0), (x + t / 2, 2.4, H)), ((x - t / 2, 3.6, 0), (x + t / 2, W, H)),
                  ((x - t / 2, 2.4, 2.2), (x + t / 2, 3.6, H))]
    # mid-level floor (3 m) over rooms 1 and 2 except a 2 m light well, and half of room 3 (the gallery)
    floors = [((0, 0, 3.0), (6.0, W, 3.2)), ((6.0, 0, 3.0), (12.0, 2.0, 3.2)), ((6.0, 4.0, 3.0), (12.0, W, 3.2)),
              ((12.0, 3.0, 3.0), (L, W, 3.2))]
    columns = [((x - 0.2, y - 0.2, 0), (x + 0.2, y + 0.2, 3.0)) for x in (7.5, 9.0, 10.5) for y in (1.5, 4.5)]
    stairs = [((13.0 + 0.3 * i, 0.4, 0), (13.3 + 0.3 * i, 2.6, 0.2 * (i + 1))) for i in range(15)]
    rail_bars = [((12.1 + 0.3 * i, 2.9, 3.2), (12.14 + 0.3 * i, 2.94, 4.1)) for i in range(20)]
    rails = rail_bars + [((12.0, 2.88, 4.1), (L, 2.96, 4.16))]
    objects = [
        _boxes_object("Shell", shell, (0.75, 0.73, 0.7)),
        _boxes_object("Partitions", walls, (0.7, 0.7, 0.72)),
        _boxes_object("UpperFloors", floors, (0.6, 0.55, 0.5)),
        _boxes_object("Columns", columns, (0.8, 0.78, 0.74)),
        _boxes_object("Stairs", stairs, (0.5, 0.45, 0.4)),
        _boxes_object("Railings", rails, (0.3, 0.3, 0.32)),
    ]
    for name, location, watts in lamps:
        data = bpy.data.lights.new(name, "POINT")
        data.energy = watts
        data.shadow_soft_size = 0.0
        light = bpy.data.objects.new(name, data)
        light.location = location
        bpy.context.scene.collection.objects.link(light)
    return objects


LAMP_GRID_X = (1.0, 3.0, 5.0, 7.0, 9.75, 11.0, 13.5, 15.5)
LAMP_GRID_Y = (1.0, 2.5, 4.0, 5.5)
LAMP_GRID_Z = (2.0, 5.0)
"""Where :func:`load_occluded_lamps` hangs its lamps: every room and storey, each lamp 0.2 m or more from the
walls, columns, stairs and railings of :func:`load_occluded` (8 x 4 x 2 = 64 places)."""


def load_occluded_lamps(count: int = 64) -> list:
    """:func:`load_occluded` with its two 800 W lamps replaced by ``count`` point lamps of the same total
    power, the first ``count`` places of the grid (LAMP_GRID_X, LAMP_GRID_Y, LAMP_GRID_Z) taken upstairs and
    down alternately: a level lit by many small lamps, most of them behind a wall from any one point."""
    places = [(x, y, z) for x in LAMP_GRID_X for y in LAMP_GRID_Y for z in LAMP_GRID_Z]
    if not 1 <= count <= len(places):
        raise ValueError(f"load_occluded_lamps: count must be 1-{len(places)}, got {count}")
    watts = sum(w for _, _, w in OCCLUDED_LAMPS) / count
    return load_occluded([(f"Lamp{i:02d}", location, watts) for i, location in enumerate(places[:count])])


PANEL_PLACES = (
    # under the mid-level floor (3 m): room 1, room 2 beside its light well, room 3 under the gallery
    (1.5, 1.5, 2.97), (4.5, 1.5, 2.97), (1.5, 4.5, 2.97), (4.5, 4.5, 2.97), (9.0, 0.8, 2.97), (9.0, 5.2, 2.97),
    (14.0, 4.5, 2.97), (16.5, 4.5, 2.97),
    # under the roof (6 m): both storeys' upper rooms, over the light well and the gallery
    (1.5, 3.0, 5.97), (4.5, 3.0, 5.97), (7.5, 1.0, 5.97), (9.0, 3.0, 5.97), (10.5, 5.0, 5.97), (13.5, 1.5, 5.97),
    (15.0, 3.0, 5.97), (16.5, 4.5, 5.97))
"""Where :func:`load_occluded_panels` hangs its ceiling panels: 3 cm under a ceiling, 0.25 m or more clear of
walls and column tops, eight per storey (the lower storey only where the mid-level floor covers it)."""
PANEL_SIZE = 0.5
"""Side of :func:`load_occluded_panels`' square area lights, m."""


def load_occluded_panels(count: int = len(PANEL_PLACES)) -> list:
    """:func:`load_occluded` lit by ``count`` square area lights (``PANEL_SIZE``, facing down) under its
    ceilings instead of its two 800 W point lamps, the same total power: soft lamps, which share their shadow
    rays (deviation light-budget), as a level lit by ceiling panels is."""
    if not 1 <= count <= len(PANEL_PLACES):
        raise ValueError(f"load_occluded_panels: count must be 1-{len(PANEL_PLACES)}, got {count}")
    objects = load_occluded(lamps=())
    watts = sum(w for _, _, w in OCCLUDED_LAMPS) / count
    for i, location in enumerate(PANEL_PLACES[:count]):
        data = bpy.data.lights.new(f"Panel{i:02d}", "AREA")
        data.energy = watts
        data.shape = "SQUARE"
        data.size = PANEL_SIZE
        light = bpy.data.objects.new(data.name, data)
        light.location = location  # an area light faces -Z unrotated
        bpy.context.scene.collection.objects.link(light)
    return objects


# --------------------------------------------------------------------------- to the core
def area_resolution(obj, settings, tris=None) -> int:
    """The light-map side ``settings`` give ``obj``'s world surface area (``tris``: its
    ``uvmaps.mesh_triangles``, read when None): the add-on's sizing up to session 16."""
    from pdic.core import unwrap
    from pdic.pdic_addon import uvmaps

    tris = tris if tris is not None else uvmaps.mesh_triangles(obj.data)
    return unwrap.choose_resolution(tris.surface_area(tuple(obj.matrix_world.to_scale())), settings.texel_density,
                                    settings.default_resolution, settings.min_resolution, settings.max_resolution)


def fit_resolutions(objects: list, settings, cache_dir: Path) -> dict:
    """Per-object resolution overrides: the settings' choice, doubled until xatlas packs the charts.

    Sponza's pillars and curtains have hundreds of small charts that do not fit the
    resolution their area asks for. Unwraps land in ``cache_dir`` under the job's keys,
    so the job's own unwrap reads them back. Needs the add-on's properties registered.
    """
    from pdic.core import unwrap
    from pdic.pdic_addon import uvmaps

    chosen = {}
    for obj in objects:
        tris = uvmaps.mesh_triangles(obj.data)
        scale = np.asarray(tuple(obj.matrix_world.to_scale()), np.float64)
        res = area_resolution(obj, settings, tris)
        while True:
            try:
                unwrap.unwrap(tris.positions * scale, tris.triangles, res, settings.padding, cache_dir=cache_dir,
                              triangle_polygon=tris.polygon)
                break
            except RuntimeError:
                if res >= settings.max_resolution:
                    raise
                res = min(2 * res, settings.max_resolution)
        obj.pdic.resolution = res
        chosen[obj.name] = res
    return chosen


def prepare(objects: list, settings, cache_dir: Path, area_sized: bool = True):
    """The add-on's prepare step (unwrap with a cache folder, extract): (job, core scene).

    area_sized : each object's map side from its surface area (:func:`fit_resolutions`, as
        resolution overrides), the bench's scenes since session 9; False: the add-on's own
        sizing, which grows a map until its charts hold ``settings.texel_density``."""
    from pdic.pdic_addon.job import BakeJob

    cache_dir.mkdir(parents=True, exist_ok=True)
    if area_sized:
        fit_resolutions(objects, settings, cache_dir / "unwrap")
    job = BakeJob(bpy.context, settings, objects=objects, output_folder=str(cache_dir / "out"),
                  cache_dir=cache_dir / "unwrap")
    job.prepare()
    return job, job.extraction.scene


def extract_lightmap_uv(objects: list, res: int):
    """Core scene of objects that already have a ``LightMap`` UV layer (the sample scenes)."""
    from pdic.pdic_addon.extract import extract_scene

    depsgraph = bpy.context.evaluated_depsgraph_get()
    return extract_scene(depsgraph, objects, "LightMap", {o.name: (res, res) for o in objects}).scene


def texel_counts(scene) -> int:
    return int(sum(t.width * t.height for t in scene.targets))


def triangles(scene) -> int:
    return int(scene.geometry.count)


__all__ = ["load_cornell", "load_sponza", "load_occluded", "load_occluded_lamps", "load_occluded_panels", "prepare",
           "extract_lightmap_uv", "np"]
