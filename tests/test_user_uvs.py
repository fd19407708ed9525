"""Light-map UVs of the user's own: checked like an unwrap, baked into as laid out, the user's map untouched."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core import manifest
from pdic.core.unwrap import uv_areas
from pdic.core.user_uvs import UserUVError, area_weighted_median, check_layout, resolution_for, texel_densities
from pdic.pdic_addon import job as job_module
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV, read_uv
from snapshot import snapshot

SQUARE = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
"""Two UV triangles filling the whole map."""


# --------------------------------------------------------------------------- core: the checks
def test_a_layout_filling_the_square_passes_and_reports_its_coverage():
    layout = check_layout(0.1 + 0.8 * SQUARE, np.ones(2), 32, "UV map 'L' of object 'O'")
    assert layout.resolution == 32 and layout.unmapped_area == 0.0
    assert layout.utilization == pytest.approx(0.64, rel=1e-6)


@pytest.mark.parametrize("uv, reason", [
    (SQUARE * 1.5, "2 of its 2 triangles lie partly outside the 0-1 UV square"),
    (np.concatenate([SQUARE, 0.5 * SQUARE]), "texel centres of the 16x16 light map lie inside two or more"),
    (np.where(np.arange(2)[:, None, None] == 0, np.nan, SQUARE), "1 triangles have non-finite UVs"),
    (np.zeros((2, 3, 2)), "UV triangles have no area"),
])
def test_a_layout_the_bake_cannot_use_is_refused_naming_the_map(uv, reason):
    with pytest.raises(UserUVError, match="UV map 'L' of object 'O'") as e:
        check_layout(uv, np.ones(len(uv)), 16, "UV map 'L' of object 'O'")
    assert reason in str(e.value)


def test_surface_without_uv_area_is_measured_as_unmapped():
    uv = np.concatenate([SQUARE, np.full((1, 3, 2), 0.5, np.float32)])
    layout = check_layout(uv, np.array([1.0, 1.0, 2.0]), 16, "x")
    assert layout.unmapped_area == pytest.approx(0.5)


def test_each_triangle_gets_the_density_of_its_share_of_the_map():
    """Two triangles of 2 units^2 each on UV areas 0.32 and 0.02 of a 100^2 map: sqrt(3200 / 2) = 40 and
    sqrt(200 / 2) = 10 texels per unit; half the surface has 10 or less, so the median is 10."""
    density = texel_densities(np.array([0.32, 0.02]), np.array([2.0, 2.0]), 100)
    np.testing.assert_allclose(density, [40.0, 10.0])
    assert area_weighted_median(density, np.array([2.0, 2.0])) == 10.0
    assert area_weighted_median(density, np.array([3.0, 1.0])) == 40.0
    assert area_weighted_median(np.zeros(0), np.zeros(0)) == 0.0


def test_the_map_size_gives_the_layout_the_texel_density():
    """6 x 6 units on 0.64 of the map at 8 texels per unit: 8 x sqrt(36 / 0.64) = 60 texels a side."""
    assert uv_areas(0.1 + 0.8 * SQUARE).sum() == pytest.approx(0.64, rel=1e-6)
    assert resolution_for(0.64, 36.0, 8.0, 256, 16, 4096) == 60
    assert resolution_for(0.64, 36.0, 8.1, 256, 16, 4096) == 64  # 60.75 up to a multiple of 4
    assert resolution_for(0.64, 36.0, 0.0, 256, 16, 4096) == 256
    assert resolution_for(0.64, 36.0, 1000.0, 256, 16, 4096) == 4096


# --------------------------------------------------------------------------- the add-on
def _scene(bpy):
    """A 6 x 6 floor with a light-map UV map of its own ('Lightmap', its square shrunk into
    [0.1, 0.9]), a cube PDIC unwraps, and a 300 W point light 3 units above the floor's centre."""
    bpy.ops.mesh.primitive_plane_add(size=6)
    floor = bpy.context.object
    floor.name = "Floor"
    layer = floor.data.uv_layers.new(name="Lightmap")
    uv = read_uv(floor.data, "UVMap")
    layer.uv.foreach_set("vector", (0.1 + 0.8 * uv).ravel())
    floor.data.uv_layers.active_index = 0
    bpy.ops.mesh.primitive_cube_add(size=1, location=(2, 2, 0.5))
    bpy.context.object.name = "Box"
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
    bpy.context.object.data.energy = 300.0
    props = bpy.context.scene.pdic
    props.quality = "PREVIEW"
    props.photons = 2000
    props.indirect = False
    props.texel_density = 8.0
    props.image_format = "EXR_FLOAT"
    floor.pdic.uv_map = "Lightmap"
    return floor


def _save(bpy, tmp_path):
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))


def test_a_bake_into_the_users_layout_keeps_it_and_lights_it_right(blender, registered, tmp_path):
    """The floor's light map is laid out in its own UV map, copied bit for bit into PDIC_Lightmap and
    sized for the texel density (8 x sqrt(36 / 0.64) = 60); under the lamp E/pi = 300 / (4 pi 3^2) / pi;
    the user's map is untouched and Clear gives the file back as it was."""
    floor = _scene(blender)
    _save(blender, tmp_path)
    before = snapshot(blender)
    mine = read_uv(floor.data, "Lightmap").copy()
    assert blender.ops.pdic.bake() == {"FINISHED"}
    assert np.array_equal(read_uv(floor.data, LIGHTMAP_UV), mine)
    assert np.array_equal(read_uv(floor.data, "Lightmap"), mine)
    assert floor.data.uv_layers.active.name == "UVMap"
    image = blender.data.images["PDIC_Floor"]
    assert tuple(image.size) == (60, 60)
    px = np.empty(60 * 60 * 4, np.float32)
    image.pixels.foreach_get(px)
    centre = px.reshape(60, 60, 4)[29:31, 29:31, :3].mean()  # the texels round UV (0.5, 0.5)
    assert centre == pytest.approx(300 / (4 * np.pi * 9) / np.pi, rel=0.01)
    entries = {e["name"]: e for e in manifest.read_manifest(tmp_path / "pdic_lightmaps")["objects"]}
    assert entries["Floor"]["uv_source"] == "Lightmap" and "charts" not in entries["Floor"]
    assert entries["Floor"]["texel_density_achieved"] == pytest.approx(8.0, rel=1e-3)
    assert entries["Floor"]["texel_density_median"] == pytest.approx(8.0, rel=1e-3)
    assert not any("not scaled" in w for w in manifest.read_manifest(tmp_path / "pdic_lightmaps")["warnings"])
    assert entries["Box"]["charts"] >= 1 and "uv_source" not in entries["Box"]
    assert blender.ops.pdic.clear() == {"FINISHED"}
    assert snapshot(blender) == before


def test_a_layout_not_scaled_to_its_surface_is_reported(blender, registered, tmp_path):
    """The floor's two triangles (18 units^2 each) laid out on UV areas 0.32 and 0.04 either side of their
    shared diagonal: half the surface gets sqrt((0.04 / 18) / (0.36 / 36)) = 0.47 of the density the map
    gives the layout on average; the bake warns and the manifest holds the median."""
    floor = _scene(blender)
    mesh = floor.data
    mesh.calc_loop_triangles()
    first, second = (set(t.loops) for t in mesh.loop_triangles)
    s0, s1 = sorted(first & second)
    uv = np.zeros((len(mesh.loops), 2), np.float32)
    uv[s0], uv[s1] = (0.05, 0.05), (0.85, 0.85)
    a, b = (first - second).pop(), (second - first).pop()
    uv[a], uv[b] = (0.05, 0.85), (0.5, 0.4)  # above the diagonal and below it: no overlap
    mesh.uv_layers["Lightmap"].uv.foreach_set("vector", uv.ravel())
    _save(blender, tmp_path)
    assert blender.ops.pdic.bake() == {"FINISHED"}
    doc = manifest.read_manifest(tmp_path / "pdic_lightmaps")
    entry = next(e for e in doc["objects"] if e["name"] == "Floor")
    assert entry["texel_density_median"] == pytest.approx(0.47 * entry["texel_density_achieved"], rel=0.02)
    assert any("'Lightmap' are not scaled to their surface" in w for w in doc["warnings"]), doc["warnings"]


def test_overlapping_user_uvs_stop_the_bake_naming_object_and_map(blender, registered, tmp_path):
    """The cube's every face on the whole square (a common texture layout, not a light map): refused
    before anything changes."""
    _scene(blender)
    box = blender.data.objects["Box"]
    layer = box.data.uv_layers.new(name="Stacked")
    square = np.tile(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), (len(box.data.polygons), 1))
    layer.uv.foreach_set("vector", square.ravel())
    box.pdic.uv_map = "Stacked"
    _save(blender, tmp_path)
    before = snapshot(blender)
    with pytest.raises(RuntimeError, match=r"object 'Box': its Light-Map UVs 'Stacked'.*two or more"):
        blender.ops.pdic.bake()
    assert snapshot(blender) == before
    assert not (tmp_path / "pdic_lightmaps").exists()


@pytest.mark.parametrize("name, reason", [("UV2", "is not a UV map of mesh"),
                                          (LIGHTMAP_UV, "the map PDIC writes and Clear removes")])
def test_a_light_map_uv_name_the_bake_cannot_take_is_an_error(blender, registered, tmp_path, name, reason):
    floor = _scene(blender)
    floor.pdic.uv_map = name
    _save(blender, tmp_path)
    with pytest.raises(RuntimeError, match=reason):
        blender.ops.pdic.bake()


def test_a_layout_without_area_is_refused_before_anything_changes(blender, registered, tmp_path):
    """Every corner of the floor's Light-Map UVs at one point: no map size can give it a texel density."""
    floor = _scene(blender)
    floor.data.uv_layers["Lightmap"].uv.foreach_set("vector", np.full(2 * len(floor.data.loops), 0.5, np.float32))
    _save(blender, tmp_path)
    before = snapshot(blender)
    with pytest.raises(RuntimeError, match="object 'Floor': its Light-Map UVs 'Lightmap' have no area"):
        blender.ops.pdic.bake()
    assert snapshot(blender) == before


def test_objects_of_one_mesh_naming_different_uvs_are_an_error(blender, registered, tmp_path):
    floor = _scene(blender)
    twin = blender.data.objects.new("Twin", floor.data)
    twin.location = (0, 0, -2)
    blender.context.scene.collection.objects.link(twin)
    _save(blender, tmp_path)
    with pytest.raises(RuntimeError, match="share mesh .* different Light-Map UVs"):
        blender.ops.pdic.bake()


def test_user_uvs_are_packed_into_an_atlas_as_islands(blender, registered, tmp_path):
    """With an atlas, the floor's own layout is an island placed in the atlas, scaled, not re-charted:
    laid out twice as wide as high (xatlas would chart the square floor square), it stays so."""
    floor = _scene(blender)
    uv = read_uv(floor.data, "UVMap")
    floor.data.uv_layers["Lightmap"].uv.foreach_set("vector", (0.1 + uv * [0.8, 0.4]).ravel())
    _save(blender, tmp_path)
    job_module.BakeJob(blender.context, _settings(blender), atlas_size=128).run()
    packed = read_uv(floor.data, LIGHTMAP_UV)
    width, height = np.ptp(packed, axis=0)
    assert max(width, height) / min(width, height) == pytest.approx(2.0, rel=0.02)
    doc = manifest.read_manifest(tmp_path / "pdic_lightmaps")
    entries = {e["name"]: e for e in doc["objects"]}
    assert entries["Floor"]["uv_source"] == "Lightmap" and "atlas_window" in entries["Floor"]


def _settings(bpy):
    from pdic.pdic_addon.properties import to_settings

    return to_settings(bpy.context.scene.pdic)
