"""The Blender experience: operators in background mode, settings across save/reload, clean
(re)registration, panel drawing, the cache overlay's batches and the preferences."""
from __future__ import annotations

import dataclasses
import json
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from pdic import pdic_addon
from pdic.pdic_addon import properties  # noqa: F401 (pdic_addon.properties below)
from pdic.core.executor import Cancelled, Progress
from pdic.pdic_addon import job as job_module
from pdic.pdic_addon import operators, overlay, panels, preferences
from snapshot import snapshot  # "everything a bake could touch", as plain comparable data
from tools.ui_recorder import RecordingLayout, _disable_preferences, _enable_preferences, draw_panel  # noqa: F401

RES = 32


# --------------------------------------------------------------------------- fixtures
@pytest.fixture
def addon(blender):
    """The add-on registered and "enabled" (its preferences exist); unregistered afterwards."""
    pdic_addon.register()
    prefs = _enable_preferences(blender)
    yield prefs
    _disable_preferences(blender)
    pdic_addon.unregister()


def build_scene(bpy, tmp_path=None):
    """A 4 m floor, a 1 m box on it (one material each), a 300 W point light; tiny Custom settings.
    Saved to ``tmp_path/scene.blend`` if given."""
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.context.object.name = "Floor"
    bpy.context.object.data.materials.append(bpy.data.materials.new("FloorMat"))
    bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, 0.5))
    bpy.context.object.name = "Box"
    bpy.context.object.data.materials.append(bpy.data.materials.new("BoxMat"))
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 2.5))
    bpy.context.object.data.energy = 300.0
    bpy.ops.object.select_all(action="DESELECT")
    props = bpy.context.scene.pdic
    props.quality = "CUSTOM"
    props.photons = 3000
    props.max_bounces = 2
    props.hemisphere_theta = 2
    props.hemisphere_phi = 4
    props.default_resolution = RES
    if tmp_path is not None:
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))


# --------------------------------------------------------------------------- a layout outside drawing
# --------------------------------------------------------------------------- operators, background mode
def test_bake_operator_in_background_stores_stats_records_and_manifest_path(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    props = blender.context.scene.pdic
    stats = panels.parse_stats(props.last_stats)
    assert stats["objects"] == ["Floor", "Box"] and stats["quality"] == "CUSTOM"
    counters = stats["counters"]
    assert counters["photons_emitted"] > 0 and counters["records"] > 0 and counters["rays_cast"] > 0
    manifest = blender.path.abspath(props.manifest_file)
    assert props.manifest_file.startswith("//") and json.load(open(manifest))["stats"]["counters"] == counters
    records = overlay.load_records(blender.path.abspath(props.records_file))
    assert len(records) == counters["records_total"]
    # Records sit on the floor (z = 0) or the box (0..1 m, |x|,|y| <= 0.5): world positions, not scene-local.
    p = records.p_world
    on_floor = np.abs(p[:, 2]) < 1e-4
    on_box = (p[:, 2] > -1e-4) & (p[:, 2] < 1 + 1e-4) & (np.abs(p[:, :2]) < 0.5 + 1e-4).all(axis=1)
    assert (on_floor | on_box).all()
    assert np.allclose(np.linalg.norm(records.n, axis=1), 1.0, atol=1e-4)
    assert (records.E >= 0).all() and records.E.max() > 0 and records.a == pytest.approx(props.a)


def test_bake_selected_bakes_only_the_selection(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    blender.data.objects["Box"].select_set(True)
    assert blender.ops.pdic.bake(scope="SELECTED") == {"FINISHED"}
    assert panels.parse_stats(blender.context.scene.pdic.last_stats)["objects"] == ["Box"]
    assert "PDIC_Box" in blender.data.images and "PDIC_Floor" not in blender.data.images


def test_clear_forgets_the_last_bake_and_restores_the_file(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    before = snapshot(blender)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    assert blender.ops.pdic.clear() == {"FINISHED"}
    props = blender.context.scene.pdic
    assert (props.last_stats, props.manifest_file, props.records_file) == ("", "", "")
    assert snapshot(blender) == before


def test_undo_after_bake_restores_the_file_and_redo_brings_the_bake_back(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    blender.ops.ed.undo_push(message="before bake")
    before = snapshot(blender)
    # As a button calls it: Python calls push no undo step unless asked (the second argument).
    assert blender.ops.pdic.bake("EXEC_DEFAULT", True) == {"FINISHED"}
    baked = snapshot(blender)
    assert baked != before
    blender.ops.ed.undo()
    assert snapshot(blender) == before and blender.context.scene.pdic.last_stats == ""
    blender.ops.ed.redo()
    assert snapshot(blender) == baked and blender.context.scene.pdic.last_stats != ""


def test_cancel_from_another_thread_stops_compute_and_rollback_restores_the_file(addon, blender, tmp_path):
    """The modal operator's path without its window: prepare on the main thread, compute on a
    worker thread, cancel from the main thread at the first progress report, roll back."""
    build_scene(blender, tmp_path)
    before = snapshot(blender)
    job = job_module.BakeJob(blender.context, operators._settings(blender.context))
    job.prepare()
    assert snapshot(blender) != before  # the light-map UV maps exist now
    reported, cancelled = threading.Event(), threading.Event()

    def on_progress(stage, fraction, eta):  # hold the worker until the main thread has cancelled
        reported.set()
        cancelled.wait(30)

    progress = Progress(on_progress)
    errors = []

    def compute():
        try:
            job.compute(progress)
        except BaseException as e:
            errors.append(e)

    worker = threading.Thread(target=compute)
    worker.start()
    assert reported.wait(30)
    progress.cancel()
    cancelled.set()
    worker.join(60)
    assert not worker.is_alive()
    assert len(errors) == 1 and isinstance(errors[0], Cancelled)
    assert job.rollback() == []
    assert snapshot(blender) == before


def test_undo_during_a_bake_cancels_and_rolls_it_back_before_blender_undoes(addon, blender, tmp_path):
    """A real undo fires the add-on's undo_pre handler, which runs the bake operator's real
    ``abort`` on the running bake. The running modal operator itself cannot exist headless
    (invoke falls back to execute in background mode), so a plain object carries the state
    ``abort`` uses: the job, its worker thread and its Progress."""
    build_scene(blender, tmp_path)
    blender.ops.ed.undo_push(message="scene")
    blender.ops.ed.undo_push(message="before bake")
    job = job_module.BakeJob(blender.context, operators._settings(blender.context))
    job.prepare()
    assert len(job.txn) > 0
    progress = Progress(lambda *_: progress.cancel_requested.wait(30))  # the worker waits for a cancel
    errors = []
    running = SimpleNamespace(job=job, progress=progress, aborted=False, thread=threading.Thread(
        target=lambda: _capture(errors, job.compute, progress)))
    running.abort = lambda: operators.PDIC_OT_bake.abort(running)
    running.thread.start()
    operators.PDIC_OT_bake._active = running
    try:
        blender.ops.ed.undo()
    finally:
        operators.PDIC_OT_bake._active = None
    assert running.aborted and not running.thread.is_alive()
    assert len(errors) == 1 and isinstance(errors[0], Cancelled)
    assert len(job.txn) == 0  # rolled back while its references were still valid
    assert not any(m.uv_layers.get("PDIC_Lightmap") for m in blender.data.meshes)


def _capture(errors, fn, *args):
    try:
        fn(*args)
    except BaseException as e:
        errors.append(e)


def test_status_text_names_stage_percent_and_time_left():
    assert operators.status_text("Pass 1: tracing photons", 0.42, 12.4) == \
        "PDIC: Pass 1: tracing photons 42%, 12 s left (Esc to cancel)"
    assert "left" not in operators.status_text("Building BVH", 0.0, None)


def test_nothing_to_bake_says_why_through_the_operator(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    blender.data.objects["Floor"].pdic.bake = False
    blender.data.objects["Box"].hide_render = True
    with pytest.raises(RuntimeError, match=r"'Floor' has Bake Light Map off.*'Box' is hidden from render"):
        blender.ops.pdic.bake()
    assert blender.context.scene.pdic.last_stats == ""


# --------------------------------------------------------------------------- settings in the .blend
def _values(group):
    return {p.identifier: (tuple(getattr(group, p.identifier)) if getattr(p, "is_array", False)
                           else getattr(group, p.identifier))
            for p in group.bl_rna.properties if p.identifier not in ("rna_type", "name")}


def test_settings_survive_save_and_reload(addon, blender, tmp_path):
    build_scene(blender)
    props = blender.context.scene.pdic
    changed = dict(quality="PREVIEW", photons=123_456, max_bounces=9, density_control=48, a=0.25, hemisphere_theta=7,
                   hemisphere_phi=15, direct_samples=40, texel_density=12.5, default_resolution=64, atlas_size=1024, direct=False, indirect=True,
                   seed=42, output_folder="//maps/", image_format="EXR_FLOAT", show_records=True,
                   show_record_discs=True, record_point_size=7.0, last_stats='{"x": 1}',
                   manifest_file="//maps/pdic_manifest.json", records_file="//maps/pdic_records.npz")
    assert set(changed) == set(_values(props)), "every scene setting is exercised"
    for k, v in changed.items():
        setattr(props, k, v)
    box = blender.data.objects["Box"]
    box.pdic.bake, box.pdic.resolution, box.pdic.uv_map = False, 96, "UVMap"
    expected_scene, expected_box = _values(props), _values(box.pdic)
    path = tmp_path / "settings.blend"
    blender.ops.wm.save_as_mainfile(filepath=str(path))
    blender.ops.wm.read_factory_settings(use_empty=True)
    assert _values(blender.context.scene.pdic)["photons"] != 123_456
    blender.ops.wm.open_mainfile(filepath=str(path))
    assert _values(blender.context.scene.pdic) == expected_scene
    assert _values(blender.data.objects["Box"].pdic) == expected_box
    assert blender.data.objects["Floor"].pdic.bake is True


def test_baked_statistics_and_records_survive_save_and_reload(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    stats = blender.context.scene.pdic.last_stats
    blender.ops.wm.save_mainfile()
    blender.ops.wm.open_mainfile(filepath=str(tmp_path / "scene.blend"))
    props = blender.context.scene.pdic
    assert props.last_stats == stats
    assert len(overlay.load_records(blender.path.abspath(props.records_file))) > 0


# --------------------------------------------------------------------------- registration
ALL_CLASSES = (preferences.classes + pdic_addon.properties.classes + operators.classes + panels.classes)


def _registration_state(bpy):
    handlers = {name: len(getattr(bpy.app.handlers, name)) for name in operators.HANDLERS}
    return dict(
        types=sorted(n for n in dir(bpy.types) if "pdic" in n.lower()),
        registered=sorted(c.__name__ for c in ALL_CLASSES if c.is_registered),
        scene=sorted(bpy.types.Scene.bl_rna.properties.keys()),
        object=sorted(bpy.types.Object.bl_rna.properties.keys()),
        handlers=handlers,
        draw_handler=overlay.STATE.handle is not None,
    )


def test_register_unregister_is_clean_and_repeatable(blender):
    baseline = _registration_state(blender)
    assert baseline["types"] == baseline["registered"] == [] and not baseline["draw_handler"]
    for _ in range(3):
        pdic_addon.register()
        try:
            state = _registration_state(blender)
            assert state["registered"] == sorted(c.__name__ for c in ALL_CLASSES)
            assert {"PDIC_OT_bake", "PDIC_OT_clear", "PDIC_OT_toggle_shading", "PDIC_OT_cancel_bake",
                    "VIEW3D_PT_pdic", "OBJECT_PT_pdic"} <= set(state["types"])
            assert "pdic" in state["scene"] and "pdic" in state["object"] and state["draw_handler"]
            assert all(state["handlers"][k] == baseline["handlers"][k] + 1 for k in operators.HANDLERS)
            handle = overlay.STATE.handle
        finally:
            pdic_addon.unregister()
        assert _registration_state(blender) == baseline
        with pytest.raises(ValueError):  # the draw handler was really removed
            blender.types.SpaceView3D.draw_handler_remove(handle, "WINDOW")


def test_preferences_register_under_the_root_package():
    # "pdic" here; "bl_ext.<repo>.pdic" in an installed extension (the package minus ".pdic_addon").
    assert preferences.ROOT_PACKAGE == pdic_addon.__package__.rpartition(".")[0] == "pdic"
    assert preferences.PDIC_AddonPreferences.bl_idname == "pdic"


# --------------------------------------------------------------------------- panels
def test_custom_settings_are_drawn_only_for_custom_quality(addon, blender):
    build_scene(blender)
    props = blender.context.scene.pdic
    custom_only = {"photons", "max_bounces", "a", "hemisphere_theta", "hemisphere_phi", "direct_samples"}
    always = {"texel_density", "default_resolution", "direct", "indirect", "seed"}
    for quality in ("PREVIEW", "FINAL", "CUSTOM"):
        props.quality = quality
        drawn = set(draw_panel(panels.VIEW3D_PT_pdic_settings, blender.context).props())
        assert always <= drawn
        assert (custom_only <= drawn) if quality == "CUSTOM" else not (custom_only & drawn)
    props.quality = "FINAL"
    main = draw_panel(panels.VIEW3D_PT_pdic, blender.context)
    assert "photons" in main.labels()[0] and "quality" in main.props()


def test_resolution_is_inactive_while_a_texel_density_is_set(addon, blender):
    build_scene(blender)
    props = blender.context.scene.pdic
    for density, active in ((0.0, True), (16.0, False)):
        props.texel_density = density
        layout = draw_panel(panels.VIEW3D_PT_pdic_settings, blender.context)
        node = next(e[1] for e in layout.log if e[0] == "prop" and e[3] == "default_resolution")
        assert node.is_active() is active


def test_every_panel_draws_documented_properties_and_registered_operators(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    states = ["nothing baked, no active object"]
    blender.context.view_layer.objects.active = None
    seen_props, seen_ops = set(), set()

    def draw_all():
        for cls in panels.classes:
            if cls.poll(blender.context) if hasattr(cls, "poll") else True:
                layout = draw_panel(cls, blender.context)
                for e in layout.log:
                    if e[0] == "prop":
                        assert e[5].description, f"{e[3]} has no tooltip"
                        seen_props.add(e[3])
                    elif e[0] == "operator":
                        assert blender.ops.pdic.__getattr__(e[2].split(".")[1]).get_rna_type().description
                        seen_ops.add(e[2])

    draw_all()
    blender.context.view_layer.objects.active = blender.data.objects["Box"]
    states.append("active mesh")
    draw_all()
    assert blender.ops.pdic.bake() == {"FINISHED"}
    states.append("baked")
    draw_all()
    assert {"pdic.bake", "pdic.clear", "pdic.toggle_shading"} <= seen_ops
    assert {"quality", "bake", "resolution", "show_records", "show_record_discs", "output_folder",
            "image_format"} <= seen_props


def test_object_panel_shows_its_light_map_after_a_bake(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    box = blender.data.objects["Box"]
    blender.context.view_layer.objects.active = box
    assert "Not baked yet" in draw_panel(panels.OBJECT_PT_pdic, blender.context).labels()
    assert blender.ops.pdic.bake() == {"FINISHED"}
    layout = draw_panel(panels.OBJECT_PT_pdic, blender.context)
    assert f"Light map {RES}x{RES}: PDIC_Box" in layout.labels()
    assert layout.props() == ["bake", "resolution", "uv_map"]


def test_display_panel_toggles_shading_and_reflects_it(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    layout = draw_panel(panels.VIEW3D_PT_pdic_display, blender.context)
    toggle = next(e[1] for e in layout.log if e[0] == "operator")
    assert not toggle.is_active()  # nothing to toggle before a bake
    assert blender.ops.pdic.bake() == {"FINISHED"}
    assert panels.shading_state(blender.context.scene) == "BAKED"
    ops = draw_panel(panels.VIEW3D_PT_pdic_display, blender.context).operators()
    assert ops == [("pdic.toggle_shading", {"mode": "ORIGINAL"}, False),
                   ("pdic.toggle_shading", {"mode": "BAKED"}, True)]
    assert blender.ops.pdic.toggle_shading(mode="ORIGINAL") == {"FINISHED"}
    assert panels.shading_state(blender.context.scene) == "ORIGINAL"


def test_stats_panel_lists_pass_times_photons_records_and_rays(addon, blender, tmp_path):
    build_scene(blender, tmp_path)
    assert draw_panel(panels.VIEW3D_PT_pdic_stats, blender.context).labels() == ["No bake yet"]
    assert blender.ops.pdic.bake() == {"FINISHED"}
    labels = draw_panel(panels.VIEW3D_PT_pdic_stats, blender.context).labels()
    for expected in ("Pass 1: photons", "Pass 2: cache", "Pass 3: refine", "Total", "Photons emitted / stored",
                     "Records (pass 2)", "Rays cast"):
        assert expected in labels
    assert "Rays saved (photon paths)" not in labels  # standard gathering (the default) reuses no path


def test_stats_rows_sum_stages_without_double_counting_and_format_counters():
    stats = {"seconds": {"addon_unwrap": 0.5, "photons": 1.0, "refine": 2.0, "addon_compute": 3.1,
                         "new_stage": 0.25},
             "counters": {"photons_emitted": 250_000, "photons_stored": 612_345, "records": 1234,
                          "rays_cast": 12_345_678, "refine_virtual_rays": 40_000, "refine_cells_virtual": 300,
                          "refine_cells": 400}}
    rows = dict(panels.stats_rows(stats))
    assert rows["Total"] == "3.75 s"  # addon_compute spans the core stages: not added again
    assert rows["Unwrap UVs"] == "0.50 s" and rows["New stage"] == "0.25 s"
    assert rows["Photons emitted / stored"] == "250k / 612k"
    assert rows["Rays cast"] == "12.35M" and rows["Records (pass 2)"] == "1,234"
    assert rows["Rays saved (photon paths)"] == "40k (75% of cells)"
    assert "Addon compute" not in rows


def test_stats_rows_mark_a_stage_that_ran_beside_others_and_leave_it_out_of_the_total():
    stats = {"seconds": {"photons": 1.0, "cache": 2.0, "refine": 3.0, "direct": 2.5, "direct_wait": 0.5},
             "seconds_beside": ["direct"]}
    rows = dict(panels.stats_rows(stats))
    assert rows["Direct light (beside)"] == "2.50 s" and rows["Waiting for direct light"] == "0.50 s"
    assert rows["Total"] == "6.50 s"


def test_actions_show_progress_and_cancel_while_baking(addon):
    idle, busy = RecordingLayout(), RecordingLayout()
    panels.draw_actions(idle, None)
    panels.draw_actions(busy, (0.25, "Pass 1: tracing photons 25%"))
    assert [op[:2] for op in idle.operators()] == [("pdic.bake", {"scope": "ALL"}),
                                                   ("pdic.bake", {"scope": "SELECTED"}),
                                                   ("pdic.clear", {"scope": "ALL"}),
                                                   ("pdic.export_glb", {})]
    assert [op[0] for op in busy.operators()] == ["pdic.cancel_bake"]
    assert [e[2:] for e in busy.log if e[0] == "progress"] == [(0.25, "Pass 1: tracing photons 25%")]


def test_preset_summary_states_the_preset_numbers():
    assert panels.preset_summary("FINAL") == "1,000,000 photons, up to 64 bounces, a 0.40, 16x32 cells"
    assert panels.preset_summary("PREVIEW").endswith("no refinement")


# --------------------------------------------------------------------------- overlay batches
def _records(K=5, rng=None):
    rng = rng or np.random.default_rng(3)
    n = rng.normal(size=(K, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[0] = (0, 0, -1)  # the branch of the tangent frame for normals facing down
    return overlay.RecordSet(p_local=rng.uniform(-1, 1, (K, 3)).astype(np.float32),
                             origin_world=np.array([1000.0, -2000.0, 5.0]), n=n.astype(np.float32),
                             E=rng.uniform(0, 4, (K, 3)).astype(np.float32),
                             R=rng.uniform(0.1, 0.5, K).astype(np.float32), a=0.4)


def test_records_file_round_trips_in_world_coordinates(tmp_path):
    r = _records()
    path = overlay.save_records(tmp_path / "pdic_records.npz", r.p_local, r.n, r.E, r.R, r.origin_world, r.a)
    assert [p.name for p in tmp_path.iterdir()] == ["pdic_records.npz"]
    back = overlay.load_records(path)
    np.testing.assert_array_equal(back.p_local, r.p_local)
    np.testing.assert_allclose(back.p_world, r.p_local.astype(np.float64) + [1000.0, -2000.0, 5.0])
    assert back.a == 0.4 and back.E.dtype == np.float32


def test_records_file_rejects_non_finite_values_and_names_broken_files(tmp_path):
    r = _records()
    E = r.E.copy()
    E[2, 1] = np.nan
    with pytest.raises(ValueError, match="E has non-finite"):
        overlay.save_records(tmp_path / "x.npz", r.p_local, r.n, E, r.R, r.origin_world, r.a)
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="broken.npz"):
        overlay.load_records(tmp_path / "broken.npz")


def test_point_batch_puts_points_on_records_coloured_by_irradiance():
    r = _records(K=4)
    r = overlay.RecordSet(r.p_local, r.origin_world, r.n,
                          np.array([[0, 0, 0], [1, 1, 1], [2, 1, 0.5], [8, 8, 8]], np.float32), r.R, r.a)
    pos, col = overlay.point_arrays(r)
    assert pos.shape == (4, 3) and col.shape == (4, 4) and pos.dtype == col.dtype == np.float32
    lift = np.einsum("ij,ij->i", pos - r.p_world, r.n)
    assert np.allclose(pos, r.p_world + lift[:, None] * r.n, atol=1e-3) and (lift > 0).all()
    assert (col[0, :3] == 0).all()                              # no irradiance: black
    assert col[1, 0] < col[3, 0] and np.isclose(col[1, 0], col[1, 1])  # brighter E, brighter point; grey stays grey
    assert col[2, 0] > col[2, 1] > col[2, 2]                    # hue order kept
    assert ((0 <= col) & (col <= 1)).all() and (col[:, 3] == 1).all()


def test_disc_batch_triangles_span_circles_of_radius_a_R_orthogonal_to_n():
    r = _records(K=6)
    S = 12
    pos, col = overlay.disc_arrays(r, segments=S, alpha=0.3)
    assert pos.shape == (6 * S * 3, 3) and col.shape == (6 * S * 3, 4)
    tris = pos.reshape(6, S, 3, 3).astype(np.float64)
    centre = tris[:, :, 0]
    rim = tris[:, :, 1:].reshape(6, 2 * S, 3)
    offset = rim - centre[:, :1]
    n = r.n.astype(np.float64)
    radius = np.broadcast_to((r.a * r.R)[:, None], (6, 2 * S))
    np.testing.assert_allclose(np.linalg.norm(offset, axis=2), radius, rtol=1e-4, atol=2e-4)
    np.testing.assert_allclose(np.einsum("kij,kj->ki", offset, n), 0.0, atol=2e-4)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, :, 1] - centre, tris[:, :, 2] - centre), axis=2).sum(axis=1)
    polygon = 0.5 * S * np.sin(2 * np.pi / S) * (r.a * r.R) ** 2  # inscribed regular S-gon
    np.testing.assert_allclose(area, polygon, rtol=1e-3)
    assert np.allclose(col[:, 3], 0.3)


def test_tangent_frames_are_orthonormal_for_every_normal_direction():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(500, 3))
    n = np.vstack([n, [[0, 0, 1], [0, 0, -1], [1, 0, 0]]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t, b = overlay.tangent_frames(n)
    for u, v in ((t, b), (t, n), (b, n)):
        np.testing.assert_allclose(np.einsum("ij,ij->i", u, v), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-12)


def test_overlay_draw_callback_is_inert_in_background(addon, blender):
    blender.context.scene.pdic.show_records = True  # the update callback only tags redraws
    assert overlay.draw_records() is None and overlay.STATE.batches == []


# --------------------------------------------------------------------------- preferences
def test_preferences_thread_count_reaches_the_executor(addon, blender, tmp_path):
    """Threads = 1 runs every chunk on the calling thread; 2 runs them on the executor's pool."""
    build_scene(blender, tmp_path)
    names = {}
    for threads in (1, 2):
        addon.threads = threads
        settings = operators._settings(blender.context)
        assert settings.threads == threads
        # A seed of its own keeps the second run from reusing the first one's cached photon map.
        settings = dataclasses.replace(settings, seed=threads)
        job = job_module.BakeJob(blender.context, settings)
        job.prepare()
        seen = set()
        job.compute(Progress(lambda *_: seen.add(threading.current_thread().name)))
        job.rollback()
        names[threads] = seen
    assert names[1] == {threading.current_thread().name}
    assert any(n.startswith("pdic") for n in names[2])


def test_preferences_draw_threads_and_the_cache_folder_in_use(addon, tmp_path):
    layout = RecordingLayout()
    addon.cache_folder = str(tmp_path)
    preferences.draw_preferences(layout, addon)
    assert layout.props() == ["threads", "cache_folder", "scheduler"]
    assert layout.labels() == [f"In use: {tmp_path}"]


def test_cache_folder_preference_holds_unwraps_and_unsaved_records(addon, blender, tmp_path):
    addon.cache_folder = str(tmp_path / "cache")
    build_scene(blender)  # not saved: light maps are packed, records go to the cache folder
    job = job_module.BakeJob(blender.context, operators._settings(blender.context))
    assert job.cache_dir == tmp_path / "cache" / "unwrap_cache"
    report = job.run()
    assert report.records_path == tmp_path / "cache" / "records" / "Scene.npz"
    assert any((tmp_path / "cache" / "unwrap_cache").iterdir())
    assert blender.context.scene.pdic.records_file == str(report.records_path)
    _disable_preferences(blender)  # without the add-on enabled: defaults
    assert preferences.threads() == 0 and preferences.cache_dir().name == "pdic_cache"
