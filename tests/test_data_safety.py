"""A bake never loses the user's work (issue 14): joined meshes, file names, edited copies,
failures inside the commit, shared meshes, partial bakes, renames and odd materials."""
from __future__ import annotations

import os
import stat
import threading

import numpy as np
import pytest
from addon_scenes import fast_settings, lamp
from snapshot import snapshot

from pdic.core import manifest
from pdic.core.executor import Cancelled, Progress
from pdic.pdic_addon import job as job_module
from pdic.pdic_addon import writeback
from pdic.pdic_addon.properties import to_settings
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

RES = 32
OUT = "pdic_lightmaps"


# --------------------------------------------------------------------------- scene
def material(bpy, name, color=(0.8, 0.8, 0.8)):
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*color, 1.0)
    return mat


def mesh_object(bpy, name, kind="cube", location=(0, 0, 0.5), mat=None, mesh=None):
    if mesh is not None:
        obj = bpy.data.objects.new(name, mesh)
        obj.location = location
        bpy.context.scene.collection.objects.link(obj)
    else:
        if kind == "plane":
            bpy.ops.mesh.primitive_plane_add(size=6, location=location)
        else:
            bpy.ops.mesh.primitive_cube_add(size=1, location=location)
        obj = bpy.context.object
        obj.name = name
        if mat is not None:
            obj.data.materials.append(mat)
    bpy.context.view_layer.update()
    return obj


def save(bpy, tmp_path, name="scene.blend"):
    fast_settings(bpy, RES, "EXR_FLOAT")
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / name))


def floor_and_box(bpy, tmp_path):
    floor = mesh_object(bpy, "Floor", "plane", (0, 0, 0), material(bpy, "FloorMat", (0.8, 0.2, 0.2)))
    box = mesh_object(bpy, "Box", "cube", (0, 0, 0.5), material(bpy, "BoxMat", (0.2, 0.2, 0.8)))
    lamp(bpy)
    save(bpy, tmp_path)
    return floor, box


def linked_duplicates(bpy, tmp_path):
    """A floor and two cubes BallA, BallB sharing one mesh, lit and saved; returns the cubes."""
    mesh_object(bpy, "Floor", "plane", (0, 0, 0), material(bpy, "FloorMat"))
    a = mesh_object(bpy, "BallA", "cube", (1.5, 0, 0.5), material(bpy, "BallMat"))
    b = mesh_object(bpy, "BallB", mesh=a.data, location=(-1.5, 0, 0.5))
    lamp(bpy)
    save(bpy, tmp_path)
    return a, b


def new_job(bpy, settings=None, **kwargs):
    return job_module.BakeJob(bpy.context, to_settings(bpy.context.scene.pdic, **(settings or {})), **kwargs)


def folder_bytes(folder):
    if not folder.exists():
        return None
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def pixels(image):
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


def join(bpy, active, *others):
    objects = [active, *others]
    with bpy.context.temp_override(active_object=active, object=active, selected_objects=objects,
                                   selected_editable_objects=objects):
        assert bpy.ops.object.join() == {"FINISHED"}


# --------------------------------------------------------------------------- 2. join
def test_clear_after_join_restores_the_users_materials(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    join(blender, floor, box)
    assert all(writeback.is_pdic(m) for m in floor.data.materials)  # Join made the copies mesh data
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert [m and m.name for m in floor.data.materials] == ["FloorMat", "BoxMat"]
    assert [s.material and s.material.name for s in floor.material_slots] == ["FloorMat", "BoxMat"]
    assert not writeback.owned_materials() and not writeback.owned_images()


def test_rebake_after_join_builds_copies_from_the_users_materials(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    join(blender, floor, box)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    shown = [s.material for s in floor.material_slots]
    assert [m.get(writeback.SOURCE).name for m in shown] == ["FloorMat", "BoxMat"]
    assert [m.name for m in floor.data.materials] == ["FloorMat", "BoxMat"]
    assert {m[writeback.OWNER] for m in writeback.owned_materials()} == {"Floor"}  # Box's are gone with Box
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert [m.name for m in floor.data.materials] == ["FloorMat", "BoxMat"]


# --------------------------------------------------------------------------- 3. file names
COLLIDING = ("Wall.001", "Wall_001", "Wall 1", "Wall_1", "M\u00e8sa", "M\u00e9sa")


def test_objects_whose_cleaned_names_collide_get_their_own_files(blender, registered, tmp_path):
    for i, name in enumerate(COLLIDING):
        mesh_object(blender, name, "cube", (2 * i - 5, 0, 0.5), material(blender, "M"))
    lamp(blender, 3000.0)
    save(blender, tmp_path)
    report = new_job(blender).run()
    files = {e["name"]: e["image"] for e in report.objects}
    assert set(files) == set(COLLIDING) and len(set(files.values())) == len(COLLIDING)
    for name, file in files.items():  # each file holds its own object's map
        loaded = blender.data.images.load(str(tmp_path / OUT / file))
        np.testing.assert_array_equal(pixels(loaded), pixels(writeback.owned_images(name)[0]))
    assert new_job(blender).run() and {e["name"]: e["image"] for e in report.objects} == files  # stable
    assert sorted(p.name for p in (tmp_path / OUT).glob("*.exr")) == sorted(files.values())


def test_two_blend_files_sharing_an_output_folder_keep_their_own_maps(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    blender.ops.wm.save_as_mainfile(filepath=str(tmp_path / "a.blend"))
    report_a = new_job(blender).run()
    maps_a = {e["image"]: (tmp_path / OUT / e["image"]).read_bytes() for e in report_a.objects}
    blender.data.lights[0].energy = 900.0
    blender.ops.wm.save_as_mainfile(filepath=str(tmp_path / "b.blend"))
    report_b = new_job(blender).run()
    assert not set(maps_a) & {e["image"] for e in report_b.objects}
    assert {name: (tmp_path / OUT / name).read_bytes() for name in maps_a} == maps_a
    doc = manifest.read_manifest(tmp_path / OUT)
    assert sorted((e["blend"], e["name"]) for e in doc["objects"]) == [
        ("a.blend", "Box"), ("a.blend", "Floor"), ("b.blend", "Box"), ("b.blend", "Floor")]


# --------------------------------------------------------------------------- 4. edited copies
def test_edit_of_the_shown_copy_is_kept_with_a_warning_at_rebake_and_clear(blender, registered, tmp_path):
    floor, _ = floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    copy = floor.material_slots[0].material
    copy.node_tree.nodes.new("ShaderNodeRGB").name = "MyEdit"
    report = new_job(blender).run()
    kept = blender.data.materials.get("FloorMat.PDIC.Floor" + writeback.EDITED_SUFFIX)
    assert kept is not None and "MyEdit" in kept.node_tree.nodes and not writeback.is_pdic(kept)
    assert any("FloorMat.PDIC.Floor" in w and "edited" in w and "FloorMat" in w for w in report.warnings)
    fresh = floor.material_slots[0].material
    assert writeback.is_pdic(fresh) and "MyEdit" not in fresh.node_tree.nodes
    fresh.node_tree.nodes.new("ShaderNodeRGB").name = "Again"
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert not writeback.owned_materials()
    assert [m.name for m in blender.data.materials if "Again" in m.node_tree.nodes] == [
        "FloorMat.PDIC.Floor (edited).001"]
    assert "MyEdit" in blender.data.materials["FloorMat.PDIC.Floor (edited)"].node_tree.nodes


def test_unedited_copies_are_not_reported_as_edited(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    assert not any(writeback.is_edited(m) for m in writeback.owned_materials())
    blender.ops.wm.save_mainfile()
    blender.ops.wm.open_mainfile(filepath=str(tmp_path / "scene.blend"))  # digest survives save and load
    assert writeback.owned_materials() and not any(writeback.is_edited(m) for m in writeback.owned_materials())


# --------------------------------------------------------------------------- 5. failure inside the commit
def test_exception_while_showing_the_second_object_keeps_the_previous_bake(blender, registered, tmp_path,
                                                                            monkeypatch):
    floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    blender.context.scene.pdic.seed = 3
    before, files = snapshot(blender), folder_bytes(tmp_path / OUT)
    calls, assign = [], writeback.assign_copies

    def failing(obj, copies, txn=None):
        calls.append(obj.name)
        if len(calls) == 2:
            raise RuntimeError("injected")
        return assign(obj, copies, txn)

    monkeypatch.setattr(writeback, "assign_copies", failing)
    with pytest.raises(RuntimeError, match="injected"):
        blender.ops.pdic.bake()
    assert snapshot(blender) == before
    assert folder_bytes(tmp_path / OUT) == files


# --------------------------------------------------------------------------- 11. unwrap in the worker
def test_unwrap_runs_on_the_worker_thread_with_progress_and_cancel(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    before = snapshot(blender)
    stages = {}
    progress = Progress(lambda stage, *_: stages.setdefault(stage, threading.current_thread().name))
    runner = job_module.JobRunner(new_job(blender), progress)
    assert runner.advance() is False  # choose ran here; the unwrap now runs on a worker thread
    assert runner.thread is not None and runner.thread.name == "pdic-unwrap"
    runner.thread.join()
    assert stages["Unwrapping"] == "pdic-unwrap"
    assert snapshot(blender) == before  # the worker wrote nothing into the file
    progress.cancel()
    assert runner.advance() is True and isinstance(runner.error, Cancelled)
    assert snapshot(blender) == before and not (tmp_path / OUT).exists()


def test_runner_finishes_stepwise_like_the_blocking_run(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    runner = job_module.JobRunner(new_job(blender))
    while not runner.advance():
        if runner.thread is not None:
            runner.thread.join()
    assert runner.error is None and {e["name"] for e in runner.job.report.objects} == {"Floor", "Box"}


# --------------------------------------------------------------------------- 13. memory
@pytest.mark.parametrize("field, value, named", [("photons", 10 ** 12, "Photons"),
                                                  ("texel_density", 1e9, "Texel Density")])
def test_bake_too_big_for_memory_is_refused_with_the_estimate(blender, registered, tmp_path, field, value, named):
    floor_and_box(blender, tmp_path)
    for i in range(8):  # 10 objects at the 4096^2 cap: ~110 GiB, more than any test machine has
        mesh_object(blender, f"Cube{i}", "cube", (i, 3, 0.5))
    before = snapshot(blender)
    with pytest.raises(job_module.BakeError, match=f"{named}.*GiB of memory"):
        new_job(blender, {field: value}).run()
    assert snapshot(blender) == before and not (tmp_path / OUT).exists()


# --------------------------------------------------------------------------- 17. shared meshes
def test_bake_selected_on_one_linked_duplicate_rebakes_the_other_too(blender, registered, tmp_path):
    a, b = linked_duplicates(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    old_b = pixels(writeback.owned_images(b)[0])
    blender.context.scene.pdic.default_resolution = 2 * RES  # a new layout for the shared mesh
    a.select_set(True)
    report = new_job(blender, selected_only=True).run()
    assert {e["name"] for e in report.objects} == {"BallA", "BallB"}
    assert any("'BallB' shares mesh" in w for w in report.warnings)
    new_b = pixels(writeback.owned_images(b)[0])
    assert new_b.shape[0] == 2 * RES and old_b.shape[0] == RES


# --------------------------------------------------------------------------- 19. partial bakes
def test_manifest_after_a_partial_bake_keeps_the_maps_still_in_use(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    new_job(blender).run()
    new_job(blender, objects=[box]).run()
    doc = manifest.read_manifest(tmp_path / OUT)
    assert sorted(e["name"] for e in doc["objects"]) == ["Box", "Floor"]
    blender.data.objects.remove(floor)
    new_job(blender, objects=[box]).run()
    assert [e["name"] for e in manifest.read_manifest(tmp_path / OUT)["objects"]] == ["Box"]


# --------------------------------------------------------------------------- 20. silent losses
def test_zero_photons_with_indirect_on_is_a_warning_in_report_and_manifest(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    report = new_job(blender, {"photons": 0}).run()
    assert any("Photons is 0" in w for w in report.warnings)
    assert any("Photons is 0" in w for w in manifest.read_manifest(tmp_path / OUT)["warnings"])


def test_half_float_clamp_is_a_warning_and_the_file_holds_no_infinity(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    blender.data.lights[0].energy = 1e9  # ~2.6e7 below the lamp: past half float's 65504
    blender.context.scene.pdic.image_format = "EXR_HALF"
    report = new_job(blender).run()
    assert any("'Floor'" in w and "65504" in w and "EXR_FLOAT" in w for w in report.warnings)
    loaded = blender.data.images.load(str(tmp_path / OUT / report.objects[0]["image"]))
    px = pixels(loaded)
    assert np.isfinite(px).all() and px[..., :3].max() == pytest.approx(65504, rel=1e-3)


# --------------------------------------------------------------------------- 21. messages and leftovers
def test_object_in_another_scene_is_named_as_such_and_gets_no_uv_map(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    other = blender.data.scenes.new("Other")
    elsewhere = blender.data.objects.new("Elsewhere", blender.data.meshes.new("ElsewhereMesh"))
    elsewhere.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    other.collection.objects.link(elsewhere)
    with pytest.raises(job_module.BakeError, match="'Elsewhere' is not in view layer.*it is in 'Other'"):
        new_job(blender, objects=[elsewhere]).run()
    assert LIGHTMAP_UV not in elsewhere.data.uv_layers


def test_manifest_and_records_get_the_umask_mode(blender, registered, tmp_path):
    floor_and_box(blender, tmp_path)
    old = os.umask(0o022)
    try:
        report = new_job(blender).run()
    finally:
        os.umask(old)
    for path in (report.manifest_path, report.records_path, tmp_path / OUT / report.objects[0]["image"]):
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o644, path


def test_renaming_an_object_between_bakes_leaves_no_stale_copies(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    box.name = "Crate"
    assert blender.ops.pdic.bake() == {"FINISHED"}
    assert sorted(m.name for m in writeback.owned_materials()) == ["BoxMat.PDIC.Crate", "FloorMat.PDIC.Floor"]
    assert sorted(i.name for i in writeback.owned_images()) == ["PDIC_Crate", "PDIC_Floor"]
    assert not [m for m in blender.data.materials if ".PDIC.Box" in m.name]


def test_emission_only_copy_keeps_its_glow(blender, registered, tmp_path):
    glow = blender.data.materials.new("Glow")
    tree = glow.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    emission.inputs["Strength"].default_value = 4.0
    tree.links.new(emission.outputs["Emission"], tree.nodes["Material Output"].inputs["Surface"])
    mesh_object(blender, "Floor", "plane", (0, 0, 0), material(blender, "FloorMat"))
    panel = mesh_object(blender, "Panel", "cube", (0, 0, 1.5), glow)
    lamp(blender)
    save(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    copy_tree = panel.material_slots[0].material.node_tree
    add = next(n for n in copy_tree.nodes if n.type == "VECT_MATH" and n.operation == "ADD")
    np.testing.assert_allclose(add.inputs[1].default_value, (4.0, 2.0, 1.0), rtol=1e-6)
    multiply = next(n for n in copy_tree.nodes if n.type == "VECT_MATH" and n.operation == "MULTIPLY")
    np.testing.assert_allclose(multiply.inputs[1].default_value, (0, 0, 0))  # an emitter reflects nothing


def test_full_disk_is_reported_as_such(tmp_path):
    import errno

    from pdic.core import atomic

    message = atomic.describe_os_error(OSError(errno.ENOSPC, "Invalid argument"), tmp_path)
    assert "no space left" in message and str(tmp_path) in message



def test_manifest_entries_from_before_blend_keys_are_replaced_not_duplicated(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    new_job(blender).run()
    folder = tmp_path / OUT
    doc = manifest.read_manifest(folder)
    legacy = [{k: v for k, v in e.items() if k != "blend"} for e in doc["objects"]]
    manifest.write_manifest(folder, legacy, doc["stats"], doc["settings"], [])
    new_job(blender, objects=[box]).run()
    entries = manifest.read_manifest(folder)["objects"]
    assert sorted(e["name"] for e in entries) == ["Box", "Floor"]
    assert [e.get("blend") for e in entries if e["name"] == "Box"] == ["scene.blend"]


def test_linked_duplicate_that_cannot_be_rebaked_is_warned_about(blender, registered, tmp_path):
    a, b = linked_duplicates(blender, tmp_path)
    new_job(blender).run()
    b.pdic.bake = False
    report = new_job(blender, objects=[a]).run()
    assert [e["name"] for e in report.objects] == ["BallA"]
    assert any("'BallB'" in w and "Bake Light Map off" in w and "no longer matches" in w for w in report.warnings)


# --------------------------------------------------------------------------- 11. unwrap hooks and growth
def test_unwrap_hooks_are_unwraps_own_keywords_and_carry_the_cancel():
    import inspect

    from pdic.core import unwrap

    progress = Progress()
    hooks = job_module._unwrap_hooks(progress, "Box", 0.5)
    assert set(hooks) <= set(inspect.signature(unwrap.unwrap).parameters)
    assert set(hooks) == {"cancelled", "progress"}
    hooks["progress"]("unwrapping (xatlas)")
    assert progress.stage == "Unwrapping 'Box': unwrapping (xatlas)" and progress.fraction == 0.5
    assert hooks["cancelled"]() is False
    progress.cancel()
    assert hooks["cancelled"]() is True
    with pytest.raises(Cancelled):  # a retry message after a cancel stops the unwrap too
        hooks["progress"]("unwrapping again with chart options 1")


def test_map_too_small_for_the_charts_grows_with_a_warning_in_report_and_manifest(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    blender.ops.mesh.primitive_uv_sphere_add(radius=0.4, segments=24, ring_count=12, location=(1.5, 0, 0.4))
    ball = blender.context.object
    ball.name = "Ball"
    ball.pdic.resolution = 12  # far too small for a 24x12 sphere's charts with 2 texels of padding
    save(blender, tmp_path)
    report = new_job(blender, objects=[ball]).run()
    entry = report.objects[0]
    assert entry["resolution_requested"] == 12 and entry["width"] > 12
    grew = [w for w in report.warnings if f"mesh {ball.data.name!r}" in w and "do not fit 12x12" in w]
    assert len(grew) == 1 and f"{entry['width']}x{entry['width']} instead" in grew[0]
    assert tuple(writeback.owned_images(ball)[0].size) == (entry["width"], entry["height"])
    doc = manifest.read_manifest(tmp_path / OUT)
    assert grew[0] in doc["warnings"]


# --------------------------------------------------------------------------- atlas mode
def test_atlas_rebakes_keep_one_atlas_image_and_retire_it_only_when_unused(blender, registered, tmp_path):
    floor, box = floor_and_box(blender, tmp_path)
    new_job(blender, atlas_size=128).run()
    atlas_images = lambda: sorted(i.name for i in writeback.owned_images("Atlas0"))  # noqa: E731
    assert atlas_images() == ["PDIC_Atlas0"] and not writeback.owned_images(floor)
    blender.context.scene.pdic.seed = 3
    report = new_job(blender, atlas_size=128).run()  # re-bake: the new atlas replaces the old one
    assert atlas_images() == ["PDIC_Atlas0"] and report.objects[0]["image_name"] == "PDIC_Atlas0"
    files = sorted(p.name for p in (tmp_path / OUT).iterdir() if p.suffix == ".exr")
    assert files == [writeback.image_filename("Atlas0")]
    new_job(blender, objects=[box]).run()  # a map of its own for Box; Floor still shows the atlas
    assert atlas_images() == ["PDIC_Atlas0"] and writeback.owned_images(box)
    new_job(blender, objects=[floor]).run()  # nothing shows the atlas any more: retired
    assert atlas_images() == [] and writeback.owned_images(floor)
    doc = manifest.read_manifest(tmp_path / OUT)
    assert sorted(e["name"] for e in doc["objects"]) == ["Box", "Floor"]
    assert not any("atlas" in e for e in doc["objects"])
