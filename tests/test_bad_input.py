"""Bad input gives a clear message naming the culprit and leaves the .blend as it was.

Covered elsewhere, not repeated here (tests/test_writeback.py): a scene without
lights, an unsaved .blend (images packed, the report says so), a read-only output
folder, nothing selected / Bake Light Map off, a folder path under a file.
Errors are checked through the operator (what the user sees: a RuntimeError in
background mode carrying the report); warnings through :class:`BakeJob`'s report.
"""
from __future__ import annotations

import numpy as np
import pytest
from addon_scenes import fast_settings, lamp
from snapshot import snapshot

from pdic.pdic_addon import job as job_module
from pdic.pdic_addon import writeback

RES = 32
OUTPUT = "pdic_lightmaps"


# --------------------------------------------------------------------------- scene
def _mesh(bpy, name, verts, faces=(), edges=()):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, list(edges), list(faces))
    mesh.update()
    ob = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.update()  # new objects join view_layer.objects on update
    return ob


def _floor(bpy, material=None):
    bpy.ops.mesh.primitive_plane_add(size=4)
    floor = bpy.context.object
    floor.name = "Floor"
    floor.data.materials.append(material or bpy.data.materials.new("FloorMat"))
    return floor


def _lamp(bpy):
    lamp(bpy)


def _save(bpy, tmp_path):
    fast_settings(bpy, RES)
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))


def _run_job(bpy):
    from pdic.pdic_addon.properties import to_settings

    return job_module.BakeJob(bpy.context, to_settings(bpy.context.scene.pdic)).run()


def _lightmap(bpy, name):
    image = bpy.data.images[writeback.image_name(name)]
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


# --------------------------------------------------------------------------- errors
def test_no_bakeable_mesh_names_every_skipped_object_and_changes_nothing(blender, registered, tmp_path):
    _lamp(blender)
    blender.ops.object.empty_add(location=(1, 0, 0))
    blender.context.object.name = "Marker"
    blender.ops.curve.primitive_bezier_curve_add()
    blender.context.object.name = "Path"
    _mesh(blender, "Wire", [(0, 0, 0), (1, 0, 0)], edges=[(0, 1)])  # edges only: no faces
    _save(blender, tmp_path)
    before = snapshot(blender)
    with pytest.raises(RuntimeError, match="nothing to bake") as error:
        blender.ops.pdic.bake()
    message = str(error.value)
    for expected in ("'Wire' has no faces", "'Marker' is not a mesh (EMPTY)", "'Path' is not a mesh (CURVE)"):
        assert expected in message
    assert snapshot(blender) == before
    assert not (tmp_path / OUTPUT).exists()


@pytest.mark.parametrize("bake_broken", [pytest.param(True, id="target"),
                                         pytest.param(False, id="occluder")])
def test_nan_vertex_fails_naming_the_object_and_changes_nothing(blender, registered, tmp_path, bake_broken):
    _floor(blender)
    _lamp(blender)
    broken = _mesh(blender, "Broken", [(0, 0, 1), (1, 0, 1), (float("nan"), 1, 1)], faces=[(0, 1, 2)])
    broken.pdic.bake = bake_broken  # a shadow caster with a NaN breaks the bake just the same
    _save(blender, tmp_path)
    before = snapshot(blender)
    with pytest.raises(RuntimeError, match="'Broken'.*non-finite vertex"):
        blender.ops.pdic.bake()
    assert snapshot(blender) == before  # the floor's new UV map was rolled back
    assert not (tmp_path / OUTPUT).exists()


# --------------------------------------------------------------------------- warnings
def test_degenerate_triangles_bake_with_a_warning_naming_object_and_count(blender, registered, tmp_path):
    _floor(blender)
    _lamp(blender)
    verts = [(-0.5, -0.5, 1), (0.5, -0.5, 1), (0.5, 0.5, 1), (-0.5, 0.5, 1),  # a good quad (2 triangles)
             (1, 1, 1), (1.5, 1, 1), (2, 1, 1),  # collinear corners
             (-1, 1, 1), (-1, 1, 1), (-1, 1, 1)]  # three corners at one point
    _mesh(blender, "Sliver", verts, faces=[(0, 1, 2, 3), (4, 5, 6), (7, 8, 9)])
    _save(blender, tmp_path)
    before = snapshot(blender)
    report = _run_job(blender)
    assert {e["name"] for e in report.objects} == {"Floor", "Sliver"}
    assert any("'Sliver'" in w and "2 degenerate" in w for w in report.warnings), report.warnings
    sliver = _lightmap(blender, "Sliver")
    assert np.isfinite(sliver).all()
    assert (sliver[..., 3] > 0).sum() > 0.2 * RES * RES and sliver[..., :3].max() > 0
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert snapshot(blender) == before


def test_mesh_of_only_degenerate_triangles_is_skipped_with_a_warning(blender, registered, tmp_path):
    _floor(blender)
    _lamp(blender)
    _mesh(blender, "Dust", [(0, 0, 1), (0, 0, 1), (0, 0, 1)], faces=[(0, 1, 2)])
    _save(blender, tmp_path)
    report = _run_job(blender)
    assert [e["name"] for e in report.objects] == ["Floor"]
    assert any("'Dust'" in w for w in report.warnings), report.warnings


def test_missing_image_file_bakes_with_a_warning_naming_path_and_material(blender, registered, tmp_path):
    missing = tmp_path / "textures" / "brick_albedo.png"
    image = blender.data.images.new("BrickAlbedo", 4, 4)
    image.source = "FILE"
    image.filepath = str(missing)
    material = blender.data.materials.new("Brick")
    tree = material.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.6, 0.3, 0.2, 1.0)
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    _floor(blender, material)
    _lamp(blender)
    _save(blender, tmp_path)
    before = snapshot(blender)
    path = image.filepath  # saving made it relative: //textures/brick_albedo.png
    report = _run_job(blender)
    # the warning names the material and the path, as Blender shows it and resolved
    assert any(path in w and str(missing) in w and "'Brick'" in w for w in report.warnings), report.warnings
    floor = _lightmap(blender, "Floor")
    assert np.isfinite(floor).all() and floor[..., :3].max() > 0.5  # 300 W at 3 m: E/pi ~ 0.84 below it
    assert blender.data.images["BrickAlbedo"].filepath == path  # the user's image is untouched
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert snapshot(blender) == before
