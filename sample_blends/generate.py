"""Write the PDIC sample scenes from published dimensions (needs the bpy wheel or Blender).

Usage::

    .venv/bin/python sample_blends/generate.py [OUT_DIR]          # default: this folder
    blender -b --python sample_blends/generate.py -- [OUT_DIR]

Writes ``cornell_point.blend``, ``cornell_area.blend``, ``textured_room.blend`` and
``floor_tiles.png`` (also packed into ``textured_room.blend``). Every file is
rebuilt from the numbers in this script: nothing is copied from elsewhere. See
README.md beside this file for what each scene holds.

Conventions: Blender Z-up, metres. Walls face the room interior; box faces face
outwards. Every mesh has a ``LightMap`` UV layer (non-overlapping, in [0, 1]);
the textured room's meshes also have a ``UVMap`` layer (first, active for
rendering) that the floor texture uses.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import bpy
import numpy as np
from mathutils import Vector

HERE = Path(__file__).resolve().parent

# --------------------------------------------------------------------------- Cornell data
# The Cornell Program of Computer Graphics box measurements (millimetres, Y up,
# the open side at z = 0 facing the camera at z = -800). Quads, corner order as published.
CORNELL_MM = {
    "Floor": [(552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2)],
    "Ceiling": [(556.0, 548.8, 0.0), (556.0, 548.8, 559.2), (0.0, 548.8, 559.2), (0.0, 548.8, 0.0)],
    "BackWall": [(549.6, 0.0, 559.2), (0.0, 0.0, 559.2), (0.0, 548.8, 559.2), (556.0, 548.8, 559.2)],
    "RightWall": [(0.0, 0.0, 559.2), (0.0, 0.0, 0.0), (0.0, 548.8, 0.0), (0.0, 548.8, 559.2)],
    "LeftWall": [(552.8, 0.0, 0.0), (549.6, 0.0, 559.2), (556.0, 548.8, 559.2), (556.0, 548.8, 0.0)],
}
CORNELL_LIGHT_MM = [(343.0, 548.8, 227.0), (343.0, 548.8, 332.0), (213.0, 548.8, 332.0), (213.0, 548.8, 227.0)]
# Blocks: top and the four sides (the bottom rests on the floor and is never seen).
CORNELL_SHORT_BLOCK_MM = [
    [(130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0)],
    [(290.0, 0.0, 114.0), (290.0, 165.0, 114.0), (240.0, 165.0, 272.0), (240.0, 0.0, 272.0)],
    [(130.0, 0.0, 65.0), (130.0, 165.0, 65.0), (290.0, 165.0, 114.0), (290.0, 0.0, 114.0)],
    [(82.0, 0.0, 225.0), (82.0, 165.0, 225.0), (130.0, 165.0, 65.0), (130.0, 0.0, 65.0)],
    [(240.0, 0.0, 272.0), (240.0, 165.0, 272.0), (82.0, 165.0, 225.0), (82.0, 0.0, 225.0)],
]
CORNELL_TALL_BLOCK_MM = [
    [(423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0)],
    [(423.0, 0.0, 247.0), (423.0, 330.0, 247.0), (472.0, 330.0, 406.0), (472.0, 0.0, 406.0)],
    [(472.0, 0.0, 406.0), (472.0, 330.0, 406.0), (314.0, 330.0, 456.0), (314.0, 0.0, 456.0)],
    [(314.0, 0.0, 456.0), (314.0, 330.0, 456.0), (265.0, 330.0, 296.0), (265.0, 0.0, 296.0)],
    [(265.0, 0.0, 296.0), (265.0, 330.0, 296.0), (423.0, 330.0, 247.0), (423.0, 0.0, 247.0)],
]
CORNELL_CAMERA_MM = (278.0, 273.0, -800.0)  # looking along +z, focal length 35 mm, film 25 x 25 mm
CORNELL_CEILING_MM = 548.8
# The light fixture quad sits this far below the ceiling so it is not coplanar with it.
LIGHT_PANEL_DROP_M = 0.0005
AREA_LIGHT_DROP_M = 0.001

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_PANEL_WHITE = (0.78, 0.78, 0.78)  # the light fixture's diffuse colour in the classic data sets

POINT_LIGHT_HEIGHT_M = 0.5
"""Point light: 0.5 m above the floor, 4.88 cm below the ceiling, over the floor centre."""
POINT_LIGHT_POWER_W = 10.0
"""Point light power: floor below gets E = 10 / (4 pi 0.5^2) = 3.18 W/m^2, a baked texel 10/pi^2 = 1.013."""
AREA_LIGHT_RADIANCE = (17.0, 12.0, 4.0)
"""Radiance of the classic light (Ke 17 12 4): Blender power P = 17 pi A with colour (1, 12/17, 4/17)."""


def cornell_to_blender(p_mm) -> Vector:
    """Map a Cornell point (mm, Y up, camera at -z) to Blender metres (Z up, camera at -Y).

    (x, y, z) -> (-(x - 278), z - 279.6, y) / 1000: a proper rotation (no mirror,
    so windings keep their sense), the box centred on X = Y = 0 with its floor at Z = 0;
    the red wall ends up at -X (the camera's left), the green one at +X.
    """
    x, y, z = p_mm
    return Vector((-(x - 278.0), z - 279.6, y)) / 1000.0


# --------------------------------------------------------------------------- helpers
def _reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for block in (bpy.data.meshes, bpy.data.materials, bpy.data.images, bpy.data.lights, bpy.data.cameras, bpy.data.worlds):
        for item in list(block):
            block.remove(item)


def _material(name: str, base_color, image=None, uv_map: str = "UVMap"):
    """A Principled BSDF material (roughness 1, no specular) with a constant colour or an image."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*base_color, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    if "Specular IOR Level" in bsdf.inputs:
        bsdf.inputs["Specular IOR Level"].default_value = 0.0
    mat.diffuse_color = (*base_color, 1.0)
    if image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.name = tex.label = "Base Color Texture"
        tex.image = image
        tex.interpolation = "Linear"
        tex.location = (-400, 300)
        uv = nt.nodes.new("ShaderNodeUVMap")
        uv.name = "Texture UV"
        uv.uv_map = uv_map
        uv.location = (-650, 300)
        nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _orient(quad: list[Vector], inside: Vector, outward: bool) -> list[Vector]:
    """Return ``quad`` wound so its normal points away from (``outward``) or towards ``inside``."""
    n = (quad[1] - quad[0]).cross(quad[2] - quad[0]) + (quad[2] - quad[0]).cross(quad[3] - quad[0])
    centre = sum(quad, Vector()) / len(quad)
    facing_inside = n.dot(inside - centre) > 0
    return quad if facing_inside != outward else list(reversed(quad))


def _lightmap_uvs(faces: list[list[Vector]], padding: float = 0.02) -> list[list[tuple]]:
    """Non-overlapping light-map UVs in [0, 1]: coplanar faces form one chart, charts on a grid.

    Each chart is projected onto its plane (u along its first edge), all charts
    with one scale so texel density is uniform within the object. Returns the
    per-corner (u, v) of every face, in face order.
    """
    # group faces by plane (normal, offset), rounded
    charts: dict[tuple, list[int]] = {}
    normals = []
    for i, f in enumerate(faces):
        n = (f[1] - f[0]).cross(f[2] - f[0]) + (f[2] - f[0]).cross(f[3 % len(f)] - f[0])
        n.normalize()
        normals.append(n)
        key = (round(n.x, 3), round(n.y, 3), round(n.z, 3), round(n.dot(f[0]), 3))
        charts.setdefault(key, []).append(i)
    projected = {}
    extents = []
    for key, members in charts.items():
        f0 = faces[members[0]]
        n = normals[members[0]]
        u_axis = (f0[1] - f0[0]).normalized()
        v_axis = n.cross(u_axis)
        pts = {i: [(p.dot(u_axis), p.dot(v_axis)) for p in faces[i]] for i in members}
        allp = np.array([q for i in members for q in pts[i]])
        lo, hi = allp.min(0), allp.max(0)
        projected[key] = (pts, lo)
        extents.append(hi - lo)
    count = len(charts)
    cols = math.ceil(math.sqrt(count))
    rows = math.ceil(count / cols)
    cell = 1.0 / max(cols, rows)
    scale = cell * (1.0 - 2.0 * padding) / max(float(np.max(extents)), 1e-9)
    uvs: list[list[tuple]] = [[] for _ in faces]
    for c, (key, (pts, lo)) in enumerate(projected.items()):
        col, row = c % cols, c // cols
        origin = np.array([col * cell + cell * padding, row * cell + cell * padding])
        for i, corners in pts.items():
            uvs[i] = [tuple(origin + (np.array(q) - lo) * scale) for q in corners]
    return uvs


def _mesh_object(name: str, faces: list[list[Vector]], material, texture_uv_scale: float | None = None):
    """Link a mesh object built from polygons (world coordinates, object at the origin).

    ``texture_uv_scale`` adds a first ``UVMap`` layer = world (x, y) / scale, used
    by the floor texture; every mesh gets a ``LightMap`` layer.
    """
    verts, polys = [], []
    for f in faces:
        polys.append(list(range(len(verts), len(verts) + len(f))))
        verts.extend(tuple(p) for p in f)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], polys)
    mesh.validate()
    mesh.materials.append(material)
    lightmap = _lightmap_uvs(faces)
    if texture_uv_scale is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", [c / texture_uv_scale for f in faces for p in f for c in (p.x, p.y)])
    layer = mesh.uv_layers.new(name="LightMap")
    layer.data.foreach_set("uv", [c for f in lightmap for q in f for c in q])
    mesh.uv_layers[0].active_render = True
    mesh.uv_layers.active = mesh.uv_layers["LightMap"]
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _camera(name: str, location, rotation, lens: float, sensor: float):
    cam = bpy.data.cameras.new(name)
    cam.lens = lens
    cam.sensor_width = sensor
    cam.sensor_height = sensor
    cam.sensor_fit = "AUTO"
    obj = bpy.data.objects.new(name, cam)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.scene.camera = obj
    return obj


def _world(color, strength: float):
    world = bpy.data.worlds.new("World")
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    world.color = color
    bpy.context.scene.world = world
    return world


def _render_settings(resolution: tuple[int, int]):
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 128
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0


def _save(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, check_existing=False)


# --------------------------------------------------------------------------- Cornell
def _cornell_geometry():
    """Objects of the 32-triangle Cornell box; returns {name: object}."""
    inside = cornell_to_blender((278.0, 274.4, 279.6))
    materials = {
        "White": _material("White", WHITE),
        "Red": _material("Red", RED),
        "Green": _material("Green", GREEN),
        "LightPanel": _material("LightPanel", LIGHT_PANEL_WHITE),
    }
    wall_material = {"Floor": "White", "Ceiling": "White", "BackWall": "White", "LeftWall": "Red", "RightWall": "Green"}
    objects = {}
    for name, quad_mm in CORNELL_MM.items():
        quad = _orient([cornell_to_blender(p) for p in quad_mm], inside, outward=False)
        objects[name] = _mesh_object(name, [quad], materials[wall_material[name]])
    panel = [cornell_to_blender(p) - Vector((0, 0, LIGHT_PANEL_DROP_M)) for p in CORNELL_LIGHT_MM]
    objects["LightPanel"] = _mesh_object("LightPanel", [_orient(panel, inside, outward=False)], materials["LightPanel"])
    for name, quads_mm in (("ShortBlock", CORNELL_SHORT_BLOCK_MM), ("TallBlock", CORNELL_TALL_BLOCK_MM)):
        quads = [[cornell_to_blender(p) for p in q] for q in quads_mm]
        centre = sum((p for q in quads for p in q), Vector()) / sum(len(q) for q in quads)
        objects[name] = _mesh_object(name, [_orient(q, centre, outward=True) for q in quads], materials["White"])
    cam = cornell_to_blender(CORNELL_CAMERA_MM)
    _camera("Camera", cam, (math.pi / 2, 0.0, 0.0), lens=35.0, sensor=25.0)
    _world((0.0, 0.0, 0.0), 1.0)
    _render_settings((512, 512))
    return objects


def ceiling_light_quad_m() -> tuple[Vector, float, float]:
    """Centre (Blender metres, at ceiling height) and X, Y sizes of the classic light quad."""
    corners = [cornell_to_blender(p) for p in CORNELL_LIGHT_MM]
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    return (lo + hi) / 2, hi.x - lo.x, hi.y - lo.y


def build_cornell_point():
    """The 32-triangle Cornell box lit by one point light under the ceiling centre."""
    _reset()
    _cornell_geometry()
    light = bpy.data.lights.new("PointLight", "POINT")
    light.energy = POINT_LIGHT_POWER_W
    light.color = (1.0, 1.0, 1.0)
    light.shadow_soft_size = 0.0
    obj = bpy.data.objects.new("PointLight", light)
    obj.location = (0.0, 0.0, POINT_LIGHT_HEIGHT_M)
    bpy.context.scene.collection.objects.link(obj)


def build_cornell_area():
    """The same box lit by a rectangle area light at the classic light quad (radiance 17 12 4)."""
    _reset()
    _cornell_geometry()
    centre, size_x, size_y = ceiling_light_quad_m()
    light = bpy.data.lights.new("AreaLight", "AREA")
    light.shape = "RECTANGLE"
    light.size = size_x
    light.size_y = size_y
    peak = max(AREA_LIGHT_RADIANCE)
    light.color = tuple(c / peak for c in AREA_LIGHT_RADIANCE)
    light.energy = peak * math.pi * size_x * size_y  # P = L pi A (DEVELOPERS.md)
    obj = bpy.data.objects.new("AreaLight", light)
    obj.location = centre - Vector((0.0, 0.0, AREA_LIGHT_DROP_M))  # local -Z = down: emits into the box
    bpy.context.scene.collection.objects.link(obj)


# --------------------------------------------------------------------------- textured room
ROOM_X, ROOM_Y, ROOM_Z = 4.0, 5.0, 3.0  # width (X), depth (Y), height (Z), metres
WINDOW_Y = (-0.8, 0.8)  # window opening in the +X wall: 1.6 m wide
WINDOW_Z = (0.9, 2.1)  # sill at 0.9 m, 1.2 m tall
SUN_STRENGTH = 3.0
SUN_ANGLE_DEG = 0.5
SUN_ELEVATION_DEG = 35.0
SUN_AZIMUTH_DEG = 15.0  # from +X towards +Y
SKY_COLOR = (0.45, 0.62, 0.9)
SKY_STRENGTH = 1.0
FLOOR_TILE_IMAGE = "floor_tiles.png"
FLOOR_IMAGE_METRES = 2.0  # the image covers 2 x 2 m of floor (4 x 4 tiles of 0.5 m), repeated


def floor_tile_pixels(size: int = 256, tiles: int = 4, seed: int = 7) -> np.ndarray:
    """A checker of ``tiles`` x ``tiles`` tiles, each shade varied, with grout lines.

    Returns (size, size, 4) float32 sRGB values in [0, 1], row 0 = image bottom.
    Flat colours per tile keep the PNG small.
    """
    rng = np.random.default_rng(seed)
    i = np.arange(size)
    row, col = i[:, None] * tiles // size, i[None, :] * tiles // size
    checker = (row + col) % 2
    light = np.array([0.82, 0.74, 0.60])
    dark = np.array([0.56, 0.42, 0.30])
    shade = 1.0 + 0.08 * rng.uniform(-1.0, 1.0, (tiles, tiles))  # per-tile variation
    rgb = np.where(checker[..., None] == 0, light, dark) * shade[row, col][..., None]
    pitch = size // tiles
    grout_width = max(size // 128, 1)
    grout = ((i % pitch) < grout_width)[:, None] | ((i % pitch) < grout_width)[None, :]
    rgb[grout] = (0.3, 0.3, 0.3)
    rgba = np.concatenate([np.clip(rgb, 0.0, 1.0), np.ones((size, size, 1))], axis=2)
    return rgba.astype(np.float32)


def _box_faces(x0, x1, y0, y1, z0, z1) -> list[list[Vector]]:
    """Top and four sides of an axis-aligned box (bottom omitted), wound outwards."""
    c = [Vector(v) for v in ((x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
                             (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1))]
    return [[c[4], c[5], c[6], c[7]], [c[0], c[1], c[5], c[4]], [c[1], c[2], c[6], c[5]],
            [c[2], c[3], c[7], c[6]], [c[3], c[0], c[4], c[7]]]


def build_textured_room(out_dir: Path):
    """A 4 x 5 x 3 m room, window in the +X wall, sun through it, sky world, textured floor."""
    _reset()
    hx, hy, h = ROOM_X / 2, ROOM_Y / 2, ROOM_Z
    inside = Vector((0.0, 0.0, h / 2))
    V = Vector
    wy0, wy1 = WINDOW_Y
    wz0, wz1 = WINDOW_Z
    rooms = {
        "Floor": [[V((-hx, -hy, 0)), V((hx, -hy, 0)), V((hx, hy, 0)), V((-hx, hy, 0))]],
        "Ceiling": [[V((-hx, -hy, h)), V((hx, -hy, h)), V((hx, hy, h)), V((-hx, hy, h))]],
        "WallWest": [[V((-hx, -hy, 0)), V((-hx, hy, 0)), V((-hx, hy, h)), V((-hx, -hy, h))]],
        "WallSouth": [[V((-hx, -hy, 0)), V((hx, -hy, 0)), V((hx, -hy, h)), V((-hx, -hy, h))]],
        "WallNorth": [[V((-hx, hy, 0)), V((hx, hy, 0)), V((hx, hy, h)), V((-hx, hy, h))]],
        # +X wall around the window opening: below, above, either side
        "WallEast": [
            [V((hx, -hy, 0)), V((hx, hy, 0)), V((hx, hy, wz0)), V((hx, -hy, wz0))],
            [V((hx, -hy, wz1)), V((hx, hy, wz1)), V((hx, hy, h)), V((hx, -hy, h))],
            [V((hx, -hy, wz0)), V((hx, wy0, wz0)), V((hx, wy0, wz1)), V((hx, -hy, wz1))],
            [V((hx, wy1, wz0)), V((hx, hy, wz0)), V((hx, hy, wz1)), V((hx, wy1, wz1))],
        ],
    }
    # floor texture: generated, saved beside the .blend and packed into it
    size = 256
    image = bpy.data.images.new("floor_tiles", size, size, alpha=False)
    image.pixels.foreach_set(floor_tile_pixels(size).ravel())
    png = out_dir / FLOOR_TILE_IMAGE
    out_dir.mkdir(parents=True, exist_ok=True)
    image.filepath_raw = str(png)
    image.file_format = "PNG"
    image.save()
    image.pack()  # reads the PNG just written: the packed bytes are the PNG file
    image.filepath = "//" + FLOOR_TILE_IMAGE  # relative to the .blend saved in the same folder
    image.colorspace_settings.name = "sRGB"

    mats = {
        "Floor": _material("FloorTiles", (0.8, 0.8, 0.8), image=image),
        "Wall": _material("WallPaint", (0.8, 0.78, 0.74)),
        "Ceiling": _material("CeilingPaint", (0.85, 0.85, 0.85)),
        "Wood": _material("Wood", (0.45, 0.28, 0.15)),
        "Fabric": _material("Fabric", (0.2, 0.3, 0.5)),
        "Cabinet": _material("Cabinet", (0.6, 0.62, 0.6)),
    }
    for name, faces in rooms.items():
        material = mats["Floor"] if name == "Floor" else mats["Ceiling"] if name == "Ceiling" else mats["Wall"]
        faces = [_orient(f, inside, outward=False) for f in faces]
        _mesh_object(name, faces, material, texture_uv_scale=FLOOR_IMAGE_METRES)
    furniture = {
        "Table": (_box_faces(-0.9, 0.3, 0.2, 1.0, 0.0, 0.75), mats["Wood"]),
        "Cabinet": (_box_faces(-hx, -hx + 0.6, -1.9, -0.3, 0.0, 1.8), mats["Cabinet"]),
        "Sofa": (_box_faces(-1.2, 0.8, hy - 0.9, hy, 0.0, 0.45), mats["Fabric"]),
    }
    for name, (faces, material) in furniture.items():
        _mesh_object(name, faces, material, texture_uv_scale=FLOOR_IMAGE_METRES)

    # sun through the window: direction towards the sun, light travels along -to_sun
    el, az = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_AZIMUTH_DEG)
    to_sun = Vector((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)))
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy = SUN_STRENGTH
    sun.angle = math.radians(SUN_ANGLE_DEG)
    sun_obj = bpy.data.objects.new("Sun", sun)
    sun_obj.location = (hx + 3.0, 0.0, 4.0)
    sun_obj.rotation_euler = to_sun.to_track_quat("Z", "Y").to_euler()  # local +Z towards the sun
    bpy.context.scene.collection.objects.link(sun_obj)
    _world(SKY_COLOR, SKY_STRENGTH)
    eye, target = Vector((-1.0, -2.35, 1.6)), Vector((0.6, 0.6, 0.4))
    look = (target - eye).to_track_quat("-Z", "Y").to_euler()  # camera looks along its local -Z
    _camera("Camera", eye, look, lens=16.0, sensor=36.0)
    _render_settings((640, 480))


# --------------------------------------------------------------------------- entry point
SCENES = ("cornell_point.blend", "cornell_area.blend", "textured_room.blend")


def generate(out_dir: Path | str = HERE) -> dict[str, Path]:
    """Build and save the three sample scenes into ``out_dir``; returns {file name: path}.

    Leaves Blender holding the last scene written (textured_room).
    """
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {}
    build_cornell_point()
    _save(paths.setdefault("cornell_point.blend", out_dir / "cornell_point.blend"))
    build_cornell_area()
    _save(paths.setdefault("cornell_area.blend", out_dir / "cornell_area.blend"))
    build_textured_room(out_dir)
    _save(paths.setdefault("textured_room.blend", out_dir / "textured_room.blend"))
    return paths


def main(argv: list[str]) -> None:
    args = argv[argv.index("--") + 1:] if "--" in argv else argv[1:]
    out = Path(args[0]) if args else HERE
    for name, path in generate(out).items():
        print(f"wrote {path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main(sys.argv)
