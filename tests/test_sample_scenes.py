"""sample_blends/generate.py: the three sample scenes, their triangle counts, lights, normals and packed texture."""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from conftest import ROOT

WALLS = {
    "cornell": ("Floor", "Ceiling", "BackWall", "LeftWall", "RightWall", "LightPanel"),
    "textured_room": ("Floor", "Ceiling", "WallWest", "WallEast", "WallSouth", "WallNorth"),
}
BOXES = {
    "cornell": ("ShortBlock", "TallBlock"),
    "textured_room": ("Table", "Cabinet", "Sofa"),
}


def _load_generator():
    spec = importlib.util.spec_from_file_location("pdic_sample_generate", ROOT / "sample_blends" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """Run the generator once into a temporary folder; {file name: path}."""
    import bpy

    out = tmp_path_factory.mktemp("sample_blends")
    paths = _load_generator().generate(out)
    yield paths
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _open(bpy, path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    return bpy


def _triangles(ob):
    """(t, 3, 3) float64 world-space corners and (t, 3) unit face normals of an object's loop triangles."""
    mesh = ob.data
    mesh.calc_loop_triangles()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    tri = np.empty(len(mesh.loop_triangles) * 3, np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri)
    matrix = np.array(ob.matrix_world)
    p = co[tri.reshape(-1, 3)] @ matrix[:3, :3].T + matrix[:3, 3]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


def _room_bounds(bpy):
    corners = np.concatenate([_triangles(bpy.data.objects[name])[0].reshape(-1, 3) for name in ("Floor", "Ceiling")])
    return corners.min(0), corners.max(0)


def test_generator_writes_the_three_files(generated):
    assert set(generated) == {"cornell_point.blend", "cornell_area.blend", "textured_room.blend"}
    for path in generated.values():
        assert path.is_file() and 10_000 < path.stat().st_size < 1_000_000
    assert (next(iter(generated.values())).parent / "floor_tiles.png").is_file()


def test_cornell_point_has_32_triangles_and_one_point_light(blender, generated):
    bpy = _open(blender, generated["cornell_point.blend"])
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH"]
    assert sum(len(_triangles(ob)[0]) for ob in meshes) == 32
    lights = [ob for ob in bpy.data.objects if ob.type == "LIGHT"]
    assert [(ob.data.type, ob.data.energy) for ob in lights] == [("POINT", 10.0)]
    # just below the ceiling centre, 0.5 m above the floor
    lo, hi = _room_bounds(bpy)
    p = np.array(lights[0].matrix_world.translation)
    assert abs(p[2] - 0.5) < 1e-6 and hi[2] - 0.06 < p[2] < hi[2]
    np.testing.assert_allclose(p[:2], 0.5 * (lo + hi)[:2], atol=2e-3)
    world = bpy.context.scene.world
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    assert tuple(bg.inputs["Color"].default_value)[:3] == (0.0, 0.0, 0.0)


def test_cornell_area_light_has_classic_radiance(blender, generated):
    bpy = _open(blender, generated["cornell_area.blend"])
    assert sum(len(_triangles(ob)[0]) for ob in bpy.data.objects if ob.type == "MESH") == 32
    lights = [ob for ob in bpy.data.objects if ob.type == "LIGHT"]
    assert len(lights) == 1
    light = lights[0].data
    assert light.type == "AREA" and light.shape == "RECTANGLE"
    assert light.size == pytest.approx(0.13) and light.size_y == pytest.approx(0.105)
    # radiance L = c P / (pi A) (DEVELOPERS.md) is the classic Ke = (17, 12, 4)
    radiance = np.array(light.color) * light.energy / (math.pi * light.size * light.size_y)
    np.testing.assert_allclose(radiance, (17.0, 12.0, 4.0), rtol=1e-5)
    down = np.array(lights[0].matrix_world.to_3x3()) @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(down, (0.0, 0.0, -1.0), atol=1e-9)


@pytest.mark.parametrize("file, kind", [("cornell_point.blend", "cornell"), ("cornell_area.blend", "cornell"),
                                         ("textured_room.blend", "textured_room")])
def test_walls_face_the_room_and_boxes_face_out(blender, generated, file, kind):
    bpy = _open(blender, generated[file])
    lo, hi = _room_bounds(bpy)
    centre = 0.5 * (lo + hi)
    for name in WALLS[kind]:
        p, n = _triangles(bpy.data.objects[name])
        towards_centre = np.einsum("ij,ij->i", n, centre - p.mean(1))
        assert (towards_centre > 0).all(), f"{name}: a face points out of the room"
    for name in BOXES[kind]:
        p, n = _triangles(bpy.data.objects[name])
        box_centre = p.reshape(-1, 3).mean(0)
        outwards = np.einsum("ij,ij->i", n, p.mean(1) - box_centre)
        assert (outwards > 0).all(), f"{name}: a face points into the box"


@pytest.mark.parametrize("file", ["cornell_point.blend", "textured_room.blend"])
def test_every_mesh_has_a_lightmap_uv_in_the_unit_square(blender, generated, file):
    bpy = _open(blender, generated[file])
    for ob in bpy.data.objects:
        if ob.type != "MESH":
            continue
        layer = ob.data.uv_layers["LightMap"]
        uv = np.empty(len(layer.data) * 2)
        layer.data.foreach_get("uv", uv)
        assert uv.min() >= 0.0 and uv.max() <= 1.0, ob.name


def test_textured_room_floor_image_is_packed_and_decodes(blender, generated):
    bpy = _open(blender, generated["textured_room.blend"])
    image = bpy.data.images["floor_tiles"]
    assert image.packed_file is not None and image.packed_file.size > 0
    assert tuple(image.size) == (256, 256)
    pixels = np.empty(256 * 256 * 4, np.float32)
    image.pixels.foreach_get(pixels)
    rgb = pixels.reshape(256, 256, 4)[..., :3]
    assert np.isfinite(rgb).all() and rgb.std() > 0.05  # a pattern, not a flat or missing image
    # the floor's Principled Base Color comes from that image
    floor_material = bpy.data.objects["Floor"].material_slots[0].material
    bsdf = next(n for n in floor_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    link = bsdf.inputs["Base Color"].links[0]
    assert link.from_node.type == "TEX_IMAGE" and link.from_node.image == image


def test_textured_room_sun_shines_through_the_window(blender, generated):
    bpy = _open(blender, generated["textured_room.blend"])
    sun = next(ob for ob in bpy.data.objects if ob.type == "LIGHT")
    assert sun.data.type == "SUN" and sun.data.energy == pytest.approx(3.0)
    assert math.degrees(sun.data.angle) == pytest.approx(0.5, abs=1e-4)
    # the ray from the floor-patch centre towards the sun leaves through the window opening
    to_sun = np.array(sun.matrix_world.to_3x3()) @ np.array([0.0, 0.0, 1.0])
    lo, hi = _room_bounds(bpy)
    window_centre = np.array([hi[0], 0.0, 1.5])
    t = window_centre[2] / to_sun[2]
    patch_centre = window_centre - t * to_sun
    assert lo[0] < patch_centre[0] < hi[0] and lo[1] < patch_centre[1] < hi[1]
    assert to_sun[0] > 0 and to_sun[2] > 0
    # and the window centre is an opening: no triangle of the east wall covers it (Y-Z barycentrics)
    p, _ = _triangles(bpy.data.objects["WallEast"])
    assert np.allclose(p[..., 0], hi[0])
    a, b, c = p[:, 0, 1:], p[:, 1, 1:], p[:, 2, 1:]
    q = window_centre[1:]
    def cross(u, v):
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    d1, d2, d3 = cross(b - a, q - a), cross(c - b, q - b), cross(a - c, q - c)
    inside = ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))
    assert not inside.any()


def test_cornell_point_floor_below_the_light_bakes_ten_over_pi_squared(blender, generated):
    """P = 10 W at d = 0.5 m: E = P / (4 pi d^2), a texel holds E / pi = 10 / pi^2 = 1.013."""
    from cycles_reference import cycles_bake

    bpy = _open(blender, generated["cornell_point.blend"])
    floor = cycles_bake([bpy.data.objects["Floor"]], "LightMap", 32, 32, {"DIRECT"}, samples=16)["Floor"]
    # brightest texel: its centre is within ~1.2 cm of the point below the light (cos^3 factor > 0.999)
    assert float(floor[..., 0].max()) == pytest.approx(10.0 / math.pi**2, rel=0.01)
    np.testing.assert_allclose(floor.reshape(-1, 3).max(0), floor[..., 0].max(), rtol=1e-4)  # white light
