"""No light-map UV layout the add-on writes overlaps: sample blends, Sponza as one object,
meshes built here (n-gons, seams, split normals, degenerate and duplicate faces)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdic.core.uv_overlap import uv_overlaps
from pdic.pdic_addon import uvmaps

ROOT = Path(__file__).resolve().parents[1]
SPONZA = ROOT.parent / "shared" / "scenes" / "sponza" / "sponza.obj"


def lightmap_overlaps(obj, resolution) -> int:
    """Texel centres inside two or more triangles of ``obj``'s PDIC_Lightmap, as written."""
    tris = uvmaps.mesh_triangles(obj.data)
    return uv_overlaps(uvmaps.read_uv(obj.data), tris.loops, resolution, resolution)


def prepared_job(bpy, objects, settings=None):
    """The add-on's prepare step (unwrap, write-back, extraction), at the default settings unless given."""
    from pdic.core.settings import BakeSettings
    from pdic.pdic_addon.job import BakeJob

    if not any(o.type == "LIGHT" for o in bpy.context.scene.objects):
        bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
    job = BakeJob(bpy.context, settings or BakeSettings(), objects=objects, output_folder="//pdic_lightmaps/")
    job.prepare()
    return job


@pytest.mark.parametrize("name", ["cornell_point", "cornell_area", "textured_room"])
def test_sample_blend_lightmap_uvs_do_not_overlap(blender, registered, name):
    blender.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{name}.blend"))
    objects = [o for o in blender.context.scene.objects if o.type == "MESH"]
    job = prepared_job(blender, objects)
    for obj in objects:
        assert lightmap_overlaps(obj, job.resolutions[obj.name][0]) == 0, obj.name
    job.rollback()


def test_sponza_as_one_object_unwraps_at_the_defaults_without_overlap(blender, registered):
    """Sponza's OBJ imports as one 66k-triangle object: at the default 256^2 its 4,800 charts
    did not pack ("could not pack the charts into 256x256"), and at 1024^2 12 texel centres
    lay inside two triangles (a chart xatlas folded over stacked faces)."""
    blender.ops.wm.obj_import(filepath=str(SPONZA))
    (sponza,) = [o for o in blender.context.scene.objects if o.type == "MESH"]
    job = prepared_job(blender, [sponza])
    res = job.resolutions[sponza.name][0]
    assert res > 256 and any("256x256" in w and f"{res}x{res}" in w for w in job.warnings)
    assert lightmap_overlaps(sponza, res) == 0
    job.rollback()
    tris = uvmaps.mesh_triangles(sponza.data)
    from pdic.core.unwrap import unwrap

    r = unwrap(tris.positions, tris.triangles, 1024, 2, triangle_polygon=tris.polygon, max_resolution=4096)
    assert r.resolution == 1024 and r.polygons_detached > 0
    assert uv_overlaps(r.uv, None, 1024, 1024) == 0


def test_sponza_as_one_object_unwraps_at_16_texels_per_metre(blender, registered):
    """At Texel Density 16 the map grows to hold Sponza's charts, and xatlas folded round columns' cap
    triangles a hundredth of a texel over their side triangles, across texel centres: the bake
    stopped ("9 texel centres of the 1760x1760 light map lie inside two or more UV triangles after
    repair") while the repair tested only 2x2 points per texel (tests/test_unwrap.py)."""
    from pdic.core.settings import BakeSettings

    blender.ops.wm.obj_import(filepath=str(SPONZA))
    (sponza,) = [o for o in blender.context.scene.objects if o.type == "MESH"]
    job = prepared_job(blender, [sponza], BakeSettings(texel_density=16.0))
    res = job.resolutions[sponza.name][0]
    assert res > 1388  # grown past the area's size to hold the charts at 16 per metre
    assert lightmap_overlaps(sponza, res) == 0
    job.rollback()


def _ngon_mesh(bpy):
    """A non-planar 12-gon, a fan of quads around it and a degenerate quad (three collinear corners)."""
    angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    inner = [(np.cos(a), np.sin(a), 0.15 * np.sin(3 * a)) for a in angles]
    outer = [(2 * np.cos(a), 2 * np.sin(a), 0.5 * np.cos(2 * a)) for a in angles]
    verts = inner + outer + [(3, 0, 0), (3.5, 0, 0), (4, 0, 0), (3.5, 1, 0)]
    faces = [tuple(range(12))] + [(i, (i + 1) % 12, 12 + (i + 1) % 12, 12 + i) for i in range(12)]
    faces.append((24, 25, 26, 27))  # 24, 25, 26 collinear
    mesh = bpy.data.meshes.new("Ngons")
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = bpy.data.objects.new("Ngons", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _built_objects(bpy):
    bpy.ops.mesh.primitive_monkey_add()
    monkey = bpy.context.object
    monkey.data.shade_smooth()
    for i, edge in enumerate(monkey.data.edges):  # split normals and seams along every 7th edge
        edge.use_edge_sharp = edge.use_seam = i % 7 == 0
    bpy.ops.mesh.primitive_cylinder_add(vertices=48, location=(4, 0, 0))  # two 48-gon caps
    bpy.ops.mesh.primitive_uv_sphere_add(location=(-4, 0, 0))  # triangle fans at the poles
    bpy.ops.mesh.primitive_cube_add(location=(0, 4, 0), scale=(3, 0.05, 1))  # a thin slab
    return [monkey, *[o for o in bpy.context.scene.objects if o.type == "MESH" and o is not monkey],
            _ngon_mesh(bpy)]


def test_built_meshes_lightmap_uvs_do_not_overlap(blender, registered):
    objects = _built_objects(blender)
    blender.context.view_layer.update()
    job = prepared_job(blender, objects)
    for obj in objects:
        assert lightmap_overlaps(obj, job.resolutions[obj.name][0]) == 0, obj.name
    job.rollback()


def test_object_scaled_to_zero_fails_naming_the_object(blender, registered):
    from pdic.pdic_addon.job import BakeError

    blender.ops.mesh.primitive_cube_add()
    hidden = blender.context.object
    hidden.name = "Hidden"
    hidden.scale = (0, 0, 0)
    blender.context.view_layer.update()
    with pytest.raises(BakeError, match="'Hidden'.*scaled to 0"):
        prepared_job(blender, [hidden])


def test_cube_at_resolution_8_grows_its_map_and_says_so(blender, registered):
    """``--resolution 8`` on a cube failed the whole bake ("could not pack the charts into 8x8")."""
    blender.ops.mesh.primitive_cube_add()
    cube = blender.context.object
    cube.pdic.resolution = 8
    job = prepared_job(blender, [cube])
    res = job.resolutions[cube.name][0]
    assert res > 8 and any("8x8" in w and f"{res}x{res}" in w for w in job.warnings)
    assert job.extraction.scene.targets[0].width == res
    assert lightmap_overlaps(cube, res) == 0
    job.rollback()
