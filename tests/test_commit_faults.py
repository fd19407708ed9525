"""Fault injection: an exception at any step of a re-bake leaves the .blend and the output folder
exactly as they were (issue 14, acceptance).

Every function that changes the file or the folder (each object's image and file, each material
copy, each slot assignment, each rename and retirement of the previous outputs, the manifest,
the records, the UV maps) is wrapped to raise at its k-th call, for k = 0, 1, ... until a bake
runs through; after each failure the snapshot and the bytes of every file must equal the ones
before the bake.
"""
from __future__ import annotations

import pytest
from snapshot import snapshot

from pdic.core import manifest
from pdic.pdic_addon import job as job_module
from pdic.pdic_addon import overlay, uvmaps, writeback
from pdic.pdic_addon.properties import to_settings

STEPS = (
    (uvmaps, "write_lightmap_uv"), (writeback, "release_mesh_copies"), (writeback, "set_shading"),
    (writeback, "ensure_directory"), (writeback, "write_image"), (writeback, "_save_exr"),
    (writeback, "replace_file"), (writeback, "build_copy"), (writeback, "assign_copy"),
    (writeback, "retire_outputs"), (writeback, "_set_aside"), (writeback, "rename"), (writeback, "tag_owner"),
    (manifest, "write_manifest"), (overlay, "save_records"),
)


class InjectedFault(Exception):
    pass


def _scene(bpy, tmp_path):
    """Floor, a two-material box, two spheres sharing a mesh (one with an OBJECT-linked slot), a lamp."""
    def mat(name, rgb):
        m = bpy.data.materials.new(name)
        m.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*rgb, 1)
        return m

    bpy.ops.mesh.primitive_plane_add(size=6)
    bpy.context.object.name = "Floor"
    bpy.context.object.data.materials.append(mat("FloorMat", (0.8, 0.3, 0.3)))
    bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, 0.5))
    box = bpy.context.object
    box.name = "Box"
    box.data.materials.append(mat("BoxA", (0.2, 0.2, 0.8)))
    box.data.materials.append(mat("BoxB", (0.2, 0.8, 0.2)))
    box.data.polygons[0].material_index = 1
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, segments=8, ring_count=4, location=(1.5, 0, 0.4))
    ball = bpy.context.object
    ball.name = "BallA"
    ball.data.materials.append(bpy.data.materials["FloorMat"])
    twin = bpy.data.objects.new("BallB", ball.data)
    twin.location = (-1.5, 0, 0.4)
    bpy.context.scene.collection.objects.link(twin)
    twin.material_slots[0].link = "OBJECT"
    twin.material_slots[0].material = mat("TwinMat", (0.9, 0.9, 0.1))
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
    bpy.context.object.data.energy = 300.0
    props = bpy.context.scene.pdic
    props.quality, props.photons, props.max_bounces = "CUSTOM", 2000, 1
    props.hemisphere_theta, props.hemisphere_phi = 2, 4
    props.default_resolution = 32
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))


def _folder(path):
    return {p.name: p.read_bytes() for p in sorted(path.iterdir())} if path.exists() else None


def _inject(monkeypatch, fail_at: int, after: bool) -> dict:
    """Wrap every step; the ``fail_at``-th call (0-based, over all of them) raises InjectedFault,
    before the step does anything or (``after``) once it has done all of it."""
    calls = {"n": 0, "where": None}
    for module, name in STEPS:
        original = getattr(module, name)

        def wrapper(*args, _original=original, _name=name, **kwargs):
            calls["n"] += 1
            fail = calls["n"] == fail_at + 1
            if fail and not after:
                calls["where"] = _name
                raise InjectedFault(f"injected at step {fail_at} ({_name})")
            result = _original(*args, **kwargs)
            if fail:
                calls["where"] = _name
                raise InjectedFault(f"injected after step {fail_at} ({_name})")
            return result

        monkeypatch.setattr(module, name, wrapper)
    return calls


@pytest.mark.parametrize("first_bake, after, atlas", [pytest.param(False, False, 0, id="first-bake"),
                                                      pytest.param(True, False, 0, id="rebake"),
                                                      pytest.param(True, True, 0, id="rebake-fault-after-step"),
                                                      pytest.param(True, False, 128, id="atlas-rebake"),
                                                      pytest.param(True, True, 128, id="atlas-rebake-fault-after-step")])
def test_exception_at_every_step_leaves_file_and_folder_unchanged(blender, registered, tmp_path, first_bake, after,
                                                                  atlas):
    _scene(blender, tmp_path)
    if atlas:  # atlas mode: one shared image; objects sharing a mesh are refused, so the twin gets its own
        twin = blender.data.objects["BallB"]
        twin.data = twin.data.copy()
        blender.context.scene.pdic.atlas_size = atlas
        blender.ops.wm.save_mainfile()
    if first_bake:
        job_module.BakeJob(blender.context, to_settings(blender.context.scene.pdic)).run()
        blender.context.scene.pdic.seed = 9  # different maps: a leaked file would show
    before, files = snapshot(blender), _folder(tmp_path / "pdic_lightmaps")
    steps_seen = set()
    for k in range(500):
        with pytest.MonkeyPatch.context() as mp:
            calls = _inject(mp, k, after)
            job = job_module.BakeJob(blender.context, to_settings(blender.context.scene.pdic))
            try:
                job.run()
            except (InjectedFault, job_module.BakeError) as e:
                assert "injected" in str(e)
            else:
                assert calls["where"] is None
                break
        steps_seen.add(calls["where"])
        assert snapshot(blender) == before, f"file changed after a fault at step {k} ({calls['where']})"
        assert _folder(tmp_path / "pdic_lightmaps") == files, f"folder changed at step {k} ({calls['where']})"
    else:
        pytest.fail("the bake never ran through")
    print(f"{k} injection points walked, steps: {sorted(steps_seen)}")
    assert k > 30  # every object, file and slot was walked
    expected = {"write_lightmap_uv", "write_image", "_save_exr", "replace_file", "build_copy", "assign_copy",
                "rename", "write_manifest", "save_records"}
    if first_bake:
        expected |= {"retire_outputs", "_set_aside"}
    assert expected <= steps_seen
    assert [i.name for i in writeback.owned_images("Atlas0")] == (["PDIC_Atlas0"] if atlas else [])
