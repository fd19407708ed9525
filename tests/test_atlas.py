"""Shared light-map atlases (core/atlas.py, pdic_addon/atlas_bake.py).

Overlap check: u-unwrap is adding ``uv_overlaps`` to core/unwrap.py; until it lands this file
checks from the UVs itself: no two triangles share a sample point (core.raster.overlapping) and no
texel is covered by two objects (conservative rasterisation, core.raster.rasterize).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdic.core import atlas, raster

ROOT = Path(__file__).resolve().parents[1]
SPONZA = ROOT.parent / "shared" / "scenes" / "sponza" / "sponza.obj"
ATLAS = 2048


def quad_input(name: str, size: float, offset=(0.0, 0.0, 0.0)) -> atlas.AtlasInput:
    p = np.array([[0, 0, 0], [size, 0, 0], [size, size, 0], [0, size, 0]], float) + offset
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    return atlas.AtlasInput(name, p, tri, uv)


def assert_no_overlap(layout: atlas.AtlasLayout) -> None:
    """No texel holds two charts or two objects; triangles overlap only inside a chart, rarely.

    Folds inside one xatlas chart come from the object's own unwrap (core/unwrap.py: Sponza as one
    object has 4-9 such triangles at 256-2048 texels before any atlas packing), not from the atlas.
    """
    for a in range(layout.atlas_count):
        members = [p for p in layout.placements if p.atlas == a]
        uv = np.concatenate([p.uv for p in members])
        folded = raster.overlapping(uv, layout.size, layout.size, 2).sum()
        assert folded <= max(2, 2e-3 * len(uv)), f"atlas {a}: {folded} of {len(uv)} triangles overlap"
        coverage = sum(raster.rasterize(p.uv, layout.size, layout.size, 1).coverage.astype(int) for p in members)
        assert coverage.max() <= 1, f"atlas {a}: {(coverage > 1).sum()} texels covered by two objects"
        for p in members:
            samples = raster.rasterize(p.uv, layout.size, layout.size, 1)
            pairs = np.unique(np.stack([samples.texel, p.chart[samples.triangle]], axis=1), axis=0)
            _, charts_per_texel = np.unique(pairs[:, 0], return_counts=True)
            assert charts_per_texel.max(initial=1) == 1, f"atlas {a}: {p.name!r} has charts sharing texels"


def object_inputs(objects, cache_dir) -> list:
    from pdic.pdic_addon import atlas_bake, uvmaps

    inputs = []
    for obj in objects:
        tris = uvmaps.mesh_triangles(obj.data)
        scale = np.asarray(tuple(obj.matrix_world.to_scale()), np.float64)
        result = atlas_bake.object_charts(tris, scale, 2, cache_dir, 4096)
        inputs.append(atlas.AtlasInput(obj.name, tris.positions * scale, tris.triangles, result.uv))
    return inputs


# --------------------------------------------------------------------------- pure packing
def test_auto_density_fits_everything_in_one_atlas_without_overlap():
    inputs = [quad_input(f"q{i}", 1.0 + i) for i in range(6)]
    layout = atlas.pack_atlases(inputs, 256, 2)
    assert layout.atlas_count == 1
    assert_no_overlap(layout)
    side = [np.ptp(p.uv[..., 0]) for p in layout.placements]  # uniform density: side grows with size
    assert np.allclose(np.array(side) / side[0], [1 + i for i in range(6)], rtol=0.1)


def test_fixed_density_overflows_into_more_atlases_each_object_in_one():
    inputs = [quad_input(f"q{i}", 1.0) for i in range(8)]
    layout = atlas.pack_atlases(inputs, 128, 2, texels_per_unit=50.0)  # 8 x 52^2 texels > 128^2
    assert 2 <= layout.atlas_count <= 4
    assert_no_overlap(layout)
    for p in layout.placements:
        assert 0.0 <= p.uv.min() and p.uv.max() <= 1.0
        assert np.ptp(p.uv[..., 0]) * 128 == pytest.approx(50.0, abs=2.0)


def test_object_larger_than_an_atlas_is_named():
    with pytest.raises(ValueError, match="'big'"):
        atlas.pack_atlases([quad_input("big", 10.0)], 64, 2, texels_per_unit=100.0)


def test_packing_in_the_child_process_equals_packing_in_process():
    """The bake packs in a child process (a crash or hang of xatlas cannot take Blender down);
    what comes back is the in-process packing, bit for bit."""
    inputs = [quad_input(f"q{i}", 1.0 + 0.5 * i) for i in range(4)]
    child = atlas.pack_atlases(inputs, 128, 2)
    here = atlas.pack_atlases(inputs, 128, 2, in_process=True)
    assert (child.size, child.padding, child.texels_per_unit, child.atlas_count) == \
        (here.size, here.padding, here.texels_per_unit, here.atlas_count)
    for a, b in zip(child.placements, here.placements):
        assert (a.name, a.atlas, a.window) == (b.name, b.atlas, b.window)
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.chart, b.chart)


def test_packing_child_that_gives_no_answer_in_time_is_killed_retried_and_reported(monkeypatch):
    """xatlas's packing once hung in the bake's own process (every thread in a futex wait): the
    child is killed past its time limit, tried again, and the error says neither answered."""
    monkeypatch.setattr(atlas, "CHILD_SECONDS_BASE", 0.0)
    monkeypatch.setattr(atlas, "CHILD_SECONDS_PER_TRIANGLE", 0.0)
    with pytest.raises(atlas.UnwrapError, match="; ".join(["no answer within 0 s"] * atlas.PACK_ATTEMPTS)):
        atlas.pack_atlases([quad_input("q", 1.0)], 64, 2)


def test_cancelled_packing_stops_its_child_and_raises_cancelled():
    from pdic.core.executor import Cancelled

    with pytest.raises(Cancelled):
        atlas.pack_atlases([quad_input("q", 1.0)], 64, 2, cancelled=lambda: True)


def test_density_scale_doubles_an_objects_texels():
    a, b = quad_input("a", 1.0), quad_input("b", 1.0)
    b = atlas.AtlasInput("b", b.positions, b.triangles, b.uv_chart, density_scale=2.0)
    layout = atlas.pack_atlases([a, b], 256, 2, texels_per_unit=40.0)
    ratio = np.ptp(layout.placement("b").uv[..., 0]) / np.ptp(layout.placement("a").uv[..., 0])
    assert ratio == pytest.approx(2.0, rel=0.1)


def test_window_uv_addresses_the_same_texels_as_the_atlas():
    layout = atlas.pack_atlases([quad_input(f"q{i}", 1.0) for i in range(3)], 128, 2)
    for p in layout.placements:
        x0, y0, w, h = p.window
        whole = raster.rasterize(p.uv, 128, 128, 2).coverage
        window = raster.rasterize(p.window_uv(128), w, h, 2).coverage
        assert whole.sum() == window.sum()
        assert np.array_equal(whole[y0:y0 + h, x0:x0 + w], window)


def test_composite_keeps_covered_texels_bit_for_bit_and_fills_gutters():
    layout = atlas.pack_atlases([quad_input(f"q{i}", 1.0 + 0.5 * i) for i in range(3)], 128, 2)
    rng = np.random.default_rng(1)
    maps, cover = {}, {}
    for p in layout.placements:
        _, _, w, h = p.window
        cover[p.name] = raster.rasterize(p.window_uv(128), w, h, 2).coverage
        maps[p.name] = rng.random((h, w, 4)).astype(np.float32)
    images, conflicts = atlas.composite(layout, maps, cover, dilation=4)
    assert conflicts == 0 and len(images) == 1
    for p in layout.placements:
        x0, y0, w, h = p.window
        view = images[0][y0:y0 + h, x0:x0 + w]
        assert np.array_equal(view[..., :3][cover[p.name]], maps[p.name][..., :3][cover[p.name]])
    # every texel within the padding of a chart holds a value (no seam beyond the dilation's)
    covered = np.zeros((128, 128), bool)
    for p in layout.placements:
        x0, y0, w, h = p.window
        covered[y0:y0 + h, x0:x0 + w] |= cover[p.name]
    from scipy.ndimage import binary_dilation

    near = binary_dilation(covered, np.ones((3, 3), bool), iterations=layout.padding)
    assert (images[0][..., 3][near] == 1).all()


# --------------------------------------------------------------------------- acceptance scenes
def test_cornell_packs_into_one_2048_atlas_without_overlap(blender, tmp_path):
    import blend_scenes as scenes

    objects = scenes.load_cornell()
    layout = atlas.pack_atlases(object_inputs(objects, tmp_path), ATLAS, 2)
    assert layout.atlas_count == 1
    assert_no_overlap(layout)


def test_cornell_as_one_object_packs_into_one_atlas(blender, tmp_path):
    import bpy
    import blend_scenes as scenes

    objects = scenes.load_cornell()
    with bpy.context.temp_override(active_object=objects[0], selected_editable_objects=objects):
        bpy.ops.object.join()
    layout = atlas.pack_atlases(object_inputs([objects[0]], tmp_path), ATLAS, 2)
    assert layout.atlas_count == 1
    assert_no_overlap(layout)


@pytest.mark.parametrize("separate", [False, True])
def test_sponza_packs_into_at_most_two_2048_atlases_without_overlap(separate, blender, tmp_path):
    import bpy
    import blend_scenes as scenes

    assert SPONZA.is_file(), f"Sponza missing at {SPONZA}"
    objects = scenes.load_sponza()
    if separate:  # one object per material, as a game level is organised
        with bpy.context.temp_override(active_object=objects[0], selected_objects=objects):
            bpy.context.view_layer.objects.active = objects[0]
            bpy.ops.object.mode_set(mode="EDIT")
            bpy.ops.mesh.select_all(action="SELECT")
            bpy.ops.mesh.separate(type="MATERIAL")
            bpy.ops.object.mode_set(mode="OBJECT")
        objects = [o for o in bpy.context.scene.objects if o.type == "MESH" and len(o.data.polygons)]
        assert len(objects) > 10
    layout = atlas.pack_atlases(object_inputs(objects, tmp_path), ATLAS, 2)
    assert layout.atlas_count <= 2
    assert_no_overlap(layout)


# --------------------------------------------------------------------------- the bake in atlas mode
def test_atlas_bake_gives_each_object_the_texels_it_gets_baked_alone(tmp_path, registered):
    """Direct light: an object's texels in the shared atlas equal those of baking it as the only
    target, bit for bit (rasterisation and random streams depend on the target alone). Indirect light
    comes from one scene-wide cache whose R_min follows the largest texel of the baked targets, so
    it is compared through the composite: atlas texels = the bake's own window texels, bit for bit."""
    import json
    from dataclasses import replace

    import bpy

    from pdic.core import pipeline
    from pdic.core.settings import preset
    from pdic.pdic_addon import atlas_bake, writeback
    from pdic.pdic_addon.job import BakeJob

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    settings = preset("PREVIEW", photons=20_000, threads=2)
    job = BakeJob(bpy.context, settings, output_folder=str(tmp_path / "maps"), atlas_size=256)
    report = job.run()
    layout, scene = job.atlas_layout, job.extraction.scene
    images, conflicts = atlas_bake.atlas_images(layout, job.result, settings.padding)
    assert conflicts == 0 and list(images) == ["Atlas0"]
    for name in ("Floor", "TallBlock"):
        x0, y0, w, h = layout.placement(name).window
        cover = job.result.coverage[name]
        in_atlas = images["Atlas0"][y0:y0 + h, x0:x0 + w, :3][cover]
        assert np.array_equal(in_atlas, job.result.lightmaps[name][..., :3][cover])
        target = next(t for t in scene.targets if t.name == name)
        alone = pipeline.bake(replace(scene, targets=(target,)), replace(settings, indirect=False))
        assert np.array_equal(alone.coverage[name], cover)
        assert np.array_equal(alone.direct[name], job.result.direct[name])
    # the manifest says which atlas image holds each object, and where
    manifest = json.loads(report.manifest_path.read_text())
    filename = writeback.image_filename("Atlas0")  # cornell_point.PDIC_Atlas0.exr
    for entry in manifest["objects"]:
        assert entry["image"] == filename and entry["width"] == 256 and entry["atlas"] == 0
        assert entry["image_name"] == "PDIC_Atlas0"
        assert entry["atlas_window"] == list(layout.placement(entry["name"]).window)
    assert (tmp_path / "maps" / filename).is_file()


def test_atlas_mode_refuses_objects_sharing_a_mesh_and_leaves_the_file_unchanged(tmp_path, registered):
    import bpy

    from pdic.core.settings import preset
    from pdic.pdic_addon.job import BakeError, BakeJob

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    floor = bpy.data.objects["Floor"]
    twin = floor.copy()  # linked duplicate: same mesh
    bpy.context.scene.collection.objects.link(twin)
    bpy.context.view_layer.update()
    uv_maps = [l.name for l in floor.data.uv_layers]
    job = BakeJob(bpy.context, preset("PREVIEW", photons=5_000), output_folder=str(tmp_path / "maps"),
                  atlas_size=256)
    with pytest.raises(BakeError, match="share mesh"):
        job.run()
    assert [l.name for l in floor.data.uv_layers] == uv_maps
    assert not (tmp_path / "maps").exists()
