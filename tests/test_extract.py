"""Scene extraction from real Blender scenes (bpy wheel, background mode)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdic.core.scene import AreaLight, PointLight, SceneError, SpotLight, SunLight
from pdic.pdic_addon import extract
from pdic.pdic_addon.extract_materials import srgb_to_linear

LM = "PDIC_Lightmap"

CUBE_VERTS = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
QUAD_VERTS = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
QUAD_FACES = [(0, 1, 2, 3)]


# --------------------------------------------------------------------------- scene building
def add_mesh(bpy, name, verts=CUBE_VERTS, faces=CUBE_FACES, location=(0, 0, 0), collection=None, material=None):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    mesh.uv_layers.new(name=LM)
    if material is not None:
        mesh.materials.append(material)
    ob = bpy.data.objects.new(name, mesh)
    ob.location = location
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def add_light(bpy, name, kind="POINT", location=(0, 0, 5), energy=100.0, rotation=(0, 0, 0), scale=(1, 1, 1)):
    light = bpy.data.lights.new(name, kind)
    light.energy = energy
    ob = bpy.data.objects.new(name, light)
    ob.location = location
    ob.rotation_euler = rotation
    ob.scale = scale
    bpy.context.scene.collection.objects.link(ob)
    return ob


def run(bpy, bake, resolution=(32, 32)):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return extract.extract_scene(depsgraph, bake, LM, {ob.name: resolution for ob in bake})


def world_positions(ex):
    return ex.scene.geometry.positions + ex.scene.origin_world


def principled(bpy, name):
    mat = bpy.data.materials.new(name)
    return mat, mat.node_tree.nodes["Principled BSDF"]


# --------------------------------------------------------------------------- geometry
def test_world_transform_applied_in_float64_and_recentred(blender):
    ob = add_mesh(blender, "Quad", QUAD_VERTS, QUAD_FACES, location=(1e5 + 10, 20, 30))
    ob.rotation_euler = (0, 0, math.pi / 2)
    ob.scale = (2, 3, 1)
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    M = np.array(ob.matrix_world, np.float64)
    expected = {tuple(np.round(M[:3, :3] @ np.array(v, float) + M[:3, 3], 6)) for v in QUAD_VERTS}
    got = {tuple(np.round(p, 6)) for p in world_positions(ex).reshape(-1, 3)}
    assert got == expected
    p = ex.scene.geometry.positions.reshape(-1, 3)
    np.testing.assert_allclose(p.min(0) + p.max(0), 0.0, atol=1e-9)  # bounding box centred on origin_world
    np.testing.assert_allclose(ex.scene.origin_world, [1e5 + 10, 20, 30], atol=1e-9)
    # the quad's normal +Z stays +Z under a rotation about Z; target covers both triangles
    np.testing.assert_allclose(ex.scene.geometry.normals.reshape(-1, 3), [[0, 0, 1]] * 6, atol=1e-6)
    assert ex.target_objects == ["Quad"]
    assert list(ex.scene.geometry.target) == [0, 0]
    assert ex.scene.targets[0].width == 32


def test_array_modifier_doubles_triangles(blender):
    ob = add_mesh(blender, "Cube")
    add_light(blender, "Lamp")
    assert run(blender, [ob]).scene.geometry.count == 12
    ob.modifiers.new("Array", "ARRAY").count = 2
    ex = run(blender, [ob])
    assert ex.scene.geometry.count == 24
    assert len(ex.scene.targets[0].triangles) == 24
    assert ex.scene.targets[0].lightmap_uv.shape == (24, 3, 2)


@pytest.mark.parametrize("scale", [(1, 1, 1), (-1, 1, 1), (-2, -1, -0.5)])
def test_negative_scale_keeps_normals_outward(blender, scale):
    ob = add_mesh(blender, "Cube", location=(3, 0, 0))
    ob.scale = scale
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    g = ex.scene.geometry
    centroid = g.positions.mean(axis=1)
    centre = g.positions.reshape(-1, 3).mean(0)
    face = g.face_normals()
    outward = np.einsum("ij,ij->i", face, centroid - centre)
    assert (outward > 0).all()  # winding normal points out of the cube
    shading_vs_face = np.einsum("ijk,ik->ij", g.normals.astype(np.float64), face)
    np.testing.assert_allclose(shading_vs_face, 1.0, atol=1e-5)  # corner normals agree and are unit


def test_collection_instance_is_an_occluder_not_a_target(blender):
    scene = blender.context.scene
    col = blender.data.collections.new("Props")
    scene.collection.children.link(col)
    quad = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES, collection=col)
    for offset in (5.0, 10.0):
        inst = blender.data.objects.new(f"Inst{offset}", None)
        inst.instance_type = "COLLECTION"
        inst.instance_collection = col
        inst.location = (offset, 0, 0)
        scene.collection.objects.link(inst)
    add_light(blender, "Lamp")
    ex = run(blender, [quad])
    g = ex.scene.geometry
    assert g.count == 6
    assert (g.target == 0).sum() == 2 and (g.target == -1).sum() == 4
    x = (g.positions + ex.scene.origin_world)[..., 0].mean(axis=1)
    np.testing.assert_allclose(np.sort(x[g.target == -1]), [5 - 1 / 3, 5 + 1 / 3, 10 - 1 / 3, 10 + 1 / 3], atol=1e-9)
    np.testing.assert_allclose(np.sort(x[g.target == 0]), [-1 / 3, 1 / 3], atol=1e-9)


def test_nested_collection_instances_are_placed_by_both_transforms(blender):
    inner, outer = blender.data.collections.new("Inner"), blender.data.collections.new("Outer")
    add_mesh(blender, "Rock", QUAD_VERTS, QUAD_FACES, collection=inner)
    for name, home, instanced, location in (("EInner", outer, inner, (0, 0, 5)),
                                            ("EOuter", blender.context.scene.collection, outer, (10, 0, 0))):
        empty = blender.data.objects.new(name, None)
        empty.instance_type, empty.instance_collection, empty.location = "COLLECTION", instanced, location
        home.objects.link(empty)
    floor = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    add_light(blender, "Lamp")
    ex = run(blender, [floor])
    rock = world_positions(ex)[ex.scene.geometry.target == -1]
    np.testing.assert_allclose(rock.reshape(-1, 3).mean(0), [10, 0, 5], atol=1e-9)


def test_geometry_node_instances_are_occluders(blender):
    floor = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    blender.ops.mesh.primitive_ico_sphere_add(subdivisions=1, location=(10, 0, 0))  # 12 points
    scatter = blender.context.object
    tree = blender.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    group_in, group_out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    on_points, cube = tree.nodes.new("GeometryNodeInstanceOnPoints"), tree.nodes.new("GeometryNodeMeshCube")
    cube.inputs["Size"].default_value = (0.1, 0.1, 0.1)
    tree.links.new(group_in.outputs[0], on_points.inputs["Points"])
    tree.links.new(cube.outputs[0], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs[0], group_out.inputs[0])
    scatter.modifiers.new("Scatter", "NODES").node_group = tree
    add_light(blender, "Lamp")
    ex = run(blender, [floor])
    g = ex.scene.geometry
    assert (g.target == -1).sum() == 12 * 12
    centres = world_positions(ex)[g.target == -1].reshape(12, 12 * 3, 3).mean(axis=1)
    np.testing.assert_allclose(np.linalg.norm(centres - [10, 0, 0], axis=1), 1.0, atol=1e-4)  # on the unit sphere


def test_objects_hidden_from_render_are_skipped(blender):
    target = add_mesh(blender, "Target", QUAD_VERTS, QUAD_FACES)
    add_mesh(blender, "HiddenRender", location=(5, 0, 0)).hide_render = True
    col = blender.data.collections.new("NoRender")
    col.hide_render = True
    blender.context.scene.collection.children.link(col)
    add_mesh(blender, "InHiddenCollection", location=(10, 0, 0), collection=col)
    excluded = blender.data.collections.new("Excluded")
    blender.context.scene.collection.children.link(excluded)
    blender.context.view_layer.layer_collection.children["Excluded"].exclude = True
    add_mesh(blender, "InExcluded", location=(15, 0, 0), collection=excluded)
    # hidden in the viewport only: Cycles renders these, so they are extracted
    eye = add_mesh(blender, "EyeHidden", location=(20, 0, 0))
    add_mesh(blender, "ViewportDisabled", location=(25, 0, 0)).hide_viewport = True
    add_light(blender, "Lamp")
    eye.hide_set(True)
    ex = run(blender, [target])
    x = world_positions(ex)[..., 0].mean(axis=1)
    assert ex.scene.geometry.count == 2 + 12 + 12
    assert set(np.round(x[ex.scene.geometry.target == -1] / 5) * 5) == {20.0, 25.0}
    assert any("ViewportDisabled" in w for w in ex.warnings)


def test_text_object_is_extracted_through_to_mesh(blender):
    target = add_mesh(blender, "Target", QUAD_VERTS, QUAD_FACES)
    text = blender.data.objects.new("Label", blender.data.curves.new("Label", "FONT"))
    text.location = (0, 0, 3)
    blender.context.scene.collection.objects.link(text)
    add_light(blender, "Lamp")
    ex = run(blender, [target])
    assert (ex.scene.geometry.target == -1).sum() > 10
    assert np.allclose(world_positions(ex)[ex.scene.geometry.target == -1][..., 2], 3.0)


def test_degenerate_triangles_are_kept_and_counted(blender):
    verts = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0)]
    ob = add_mesh(blender, "Sliver", verts, [(0, 1, 2), (0, 1, 3)])
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    assert ex.scene.geometry.count == 2
    assert ex.degenerate_triangles == {"Sliver": 1}
    assert any("Sliver" in w and "degenerate" in w for w in ex.warnings)


# --------------------------------------------------------------------------- materials
def test_base_colour_constant_and_default_grey(blender):
    mat, bsdf = principled(blender, "Paint")
    bsdf.inputs["Base Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    painted = add_mesh(blender, "Painted", QUAD_VERTS, QUAD_FACES, material=mat)
    bare = add_mesh(blender, "Bare", QUAD_VERTS, QUAD_FACES, location=(3, 0, 0))
    painted_again = add_mesh(blender, "Painted2", QUAD_VERTS, QUAD_FACES, location=(6, 0, 0), material=mat)
    add_light(blender, "Lamp")
    ex = run(blender, [painted, bare, painted_again])
    m, g = ex.scene.materials, ex.scene.geometry
    assert m.count == 2  # deduplicated by material
    for target, colour in zip(ex.scene.targets, [(0.2, 0.4, 0.6), (0.8, 0.8, 0.8), (0.2, 0.4, 0.6)]):
        np.testing.assert_allclose(m.base_color[g.material[target.triangles]], [colour] * 2, atol=1e-6)
    assert (m.texture == -1).all() and not ex.warnings


def _textured_material(bpy, name, image):
    mat, bsdf = principled(bpy, name)
    node = mat.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    node.interpolation = "Closest"
    mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    return mat


def test_srgb_function_matches_the_standard():
    np.testing.assert_allclose(srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0])), [0.0, 0.04045 / 12.92, 0.21404, 1.0], atol=2e-5)


@pytest.mark.parametrize("colorspace, decode", [("sRGB", True), ("Non-Color", False)])
def test_texture_pixels_decoded_by_colour_space(blender, colorspace, decode):
    image = blender.data.images.new("Checker", 4, 2)
    image.colorspace_settings.name = colorspace
    px = np.full((2, 4, 4), 0.5, np.float32)
    px[0, 0, :3] = (1.0, 0.0, 0.25)  # bottom-left texel
    image.pixels.foreach_set(px.ravel())
    ob = add_mesh(blender, "Textured", QUAD_VERTS, QUAD_FACES, material=_textured_material(blender, "Tex", image))
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    (tex,) = ex.scene.textures
    assert ex.scene.materials.texture.tolist() == [0]
    assert tex.pixels.shape == (2, 4, 3) and tex.interpolation == "Closest"
    stored = np.round(px[..., :3] * 255) / 255  # byte image: 0.5 is stored as 128/255
    expected = srgb_to_linear(stored) if decode else stored
    np.testing.assert_allclose(tex.pixels, expected, atol=1e-5)
    assert abs(float(tex.pixels[1, 1, 0]) - (0.2158 if decode else 0.50196)) < 1e-3


def test_uv_map_node_selects_the_texture_uv_layer(blender):
    # A UV Map node feeding the Image Texture names the layer to sample: read it, do not warn.
    image = blender.data.images.new("Tiles", 4, 4)
    mat = _textured_material(blender, "Tiled", image)
    uv_node = mat.node_tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "Tiling"
    mat.node_tree.links.new(uv_node.outputs["UV"], mat.node_tree.nodes["Image Texture"].inputs["Vector"])
    ob = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES, material=mat)
    tiling = ob.data.uv_layers.new(name="Tiling")
    tiling.data.foreach_set("uv", np.full(2 * len(ob.data.loops), 7.5, np.float32))
    for layer in ob.data.uv_layers:
        layer.active_render = layer.name == LM  # the render map is another one
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    np.testing.assert_allclose(ex.scene.geometry.uvs, 7.5)
    assert not any("Vector input" in w for w in ex.warnings), ex.warnings

    uv_node.uv_map = "Missing"
    ex = run(blender, [ob])
    assert any("'Floor'" in w and "'Missing'" in w and "'Tiled'" in w for w in ex.warnings), ex.warnings


def test_missing_image_warns_and_uses_socket_colour(blender):
    image = blender.data.images.new("Gone", 4, 4)
    image.source = "FILE"
    image.filepath = "/nonexistent/brick_albedo.png"
    ob = add_mesh(blender, "Wall", QUAD_VERTS, QUAD_FACES, material=_textured_material(blender, "Brick", image))
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    assert ex.scene.materials.texture.tolist() == [-1] and ex.scene.textures == ()
    np.testing.assert_allclose(ex.scene.materials.base_color[0], (0.1, 0.2, 0.3), atol=1e-6)
    assert any("brick_albedo.png" in w and "Brick" in w for w in ex.warnings)


def test_emission_colour_times_strength(blender):
    mat, bsdf = principled(blender, "Glow")
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 4.0
    shader = blender.data.materials.new("Neon")
    nodes = shader.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (0.0, 1.0, 0.0, 1.0)
    emission.inputs["Strength"].default_value = 2.5
    shader.node_tree.links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    a = add_mesh(blender, "A", QUAD_VERTS, QUAD_FACES, material=mat)
    add_mesh(blender, "B", QUAD_VERTS, QUAD_FACES, location=(3, 0, 0), material=shader)
    ex = run(blender, [a])  # no lamp: the emissive materials light the scene
    m = ex.scene.materials
    rows = {name: i for i, name in enumerate(m.names)}
    np.testing.assert_allclose(m.emission[rows["Glow"]], (4.0, 2.0, 1.0), atol=1e-6)
    np.testing.assert_allclose(m.emission[rows["Neon"]], (0.0, 2.5, 0.0), atol=1e-6)
    np.testing.assert_allclose(m.base_color[rows["Neon"]], 0.0)  # an Emission shader reflects nothing
    assert len(ex.scene.emissive_triangles) == 4


def test_diffuse_bsdf_and_unsupported_shader(blender):
    diffuse = blender.data.materials.new("Matte")
    glossy = blender.data.materials.new("Chrome")
    for mat, kind in ((diffuse, "ShaderNodeBsdfDiffuse"), (glossy, "ShaderNodeBsdfGlossy")):
        nodes = mat.node_tree.nodes
        nodes.remove(nodes["Principled BSDF"])
        node = nodes.new(kind)
        node.inputs["Color"].default_value = (0.3, 0.2, 0.1, 1.0)
        mat.node_tree.links.new(node.outputs[0], nodes["Material Output"].inputs["Surface"])
    a = add_mesh(blender, "A", QUAD_VERTS, QUAD_FACES, material=diffuse)
    add_mesh(blender, "B", QUAD_VERTS, QUAD_FACES, location=(3, 0, 0), material=glossy)
    add_light(blender, "Lamp")
    ex = run(blender, [a])
    m = ex.scene.materials
    rows = {name: i for i, name in enumerate(m.names)}
    np.testing.assert_allclose(m.base_color[rows["Matte"]], (0.3, 0.2, 0.1), atol=1e-6)
    np.testing.assert_allclose(m.base_color[rows["Chrome"]], (0.8, 0.8, 0.8), atol=1e-6)
    assert [w for w in ex.warnings if "Chrome" in w and "Glossy BSDF" in w]
    assert not [w for w in ex.warnings if "Matte" in w]


def test_linked_base_colour_from_other_node_warns(blender):
    mat, bsdf = principled(blender, "Noisy")
    noise = mat.node_tree.nodes.new("ShaderNodeTexNoise")
    mat.node_tree.links.new(noise.outputs["Color"], bsdf.inputs["Base Color"])
    ob = add_mesh(blender, "A", QUAD_VERTS, QUAD_FACES, material=mat)
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    assert any("Noisy" in w and "ShaderNodeTexNoise" in w for w in ex.warnings)
    np.testing.assert_allclose(ex.scene.materials.base_color[0], 0.8, atol=1e-6)  # Principled default constant


# --------------------------------------------------------------------------- lights and world
def test_light_unit_conversions(blender):
    ob = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES, location=(0, 0, -1))
    point = add_light(blender, "Point", "POINT", location=(1, 2, 3), energy=100.0)
    point.data.color = (1.0, 0.5, 0.25)
    point.data.exposure = 1.0
    point.data.shadow_soft_size = 0.3
    spot = add_light(blender, "Spot", "SPOT", location=(0, 0, 4), energy=50.0, rotation=(math.pi / 2, 0, 0))
    spot.data.spot_size = 1.0
    spot.data.spot_blend = 0.25
    sun = add_light(blender, "Sun", "SUN", energy=3.0, rotation=(0, math.pi / 2, 0))
    sun.data.angle = 0.1
    area = add_light(blender, "Area", "AREA", location=(0, 0, 2), energy=60.0, scale=(2, 3, 1))
    area.data.shape = "RECTANGLE"
    area.data.size, area.data.size_y = 2.0, 1.0
    disk = add_light(blender, "Disk", "AREA", location=(0, 0, 2), energy=10.0)
    disk.data.shape = "DISK"
    disk.data.size = 2.0
    warm = add_light(blender, "Warm", "POINT", energy=10.0)
    warm.data.use_temperature = True
    warm.data.temperature = 3000.0
    ex = run(blender, [ob])
    lights = {l.name: l for l in ex.scene.lights}
    origin = ex.scene.origin_world

    p = lights["Point"]
    assert isinstance(p, PointLight)
    np.testing.assert_allclose(p.power, [200.0, 100.0, 50.0], rtol=1e-6)  # energy * 2**exposure * colour
    np.testing.assert_allclose(p.position + origin, [1, 2, 3], atol=1e-9)
    assert p.radius == pytest.approx(0.3)

    s = lights["Spot"]
    assert isinstance(s, SpotLight)
    assert s.half_angle == pytest.approx(0.5) and s.blend == pytest.approx(0.25)
    np.testing.assert_allclose(s.direction, [0, 1, 0], atol=1e-6)  # -Z rotated +90 degrees about X

    sun_light = lights["Sun"]
    assert isinstance(sun_light, SunLight)
    np.testing.assert_allclose(sun_light.irradiance, [3.0, 3.0, 3.0], rtol=1e-6)
    np.testing.assert_allclose(sun_light.direction, [1, 0, 0], atol=1e-6)  # +Z rotated +90 degrees about Y
    assert sun_light.half_angle == pytest.approx(0.05)

    a = lights["Area"]
    assert isinstance(a, AreaLight)
    assert (a.size_u, a.size_v) == pytest.approx((4.0, 3.0))  # size x scale
    assert a.area == pytest.approx(12.0)
    np.testing.assert_allclose(a.radiance, 60.0 / (math.pi * 12.0), rtol=1e-6)
    np.testing.assert_allclose(a.normal, [0, 0, -1], atol=1e-9)
    np.testing.assert_allclose(a.axis_u, [1, 0, 0], atol=1e-9)

    d = lights["Disk"]
    assert d.area == pytest.approx(math.pi)
    np.testing.assert_allclose(d.radiance, 10.0 / (math.pi * math.pi), rtol=1e-6)

    w = lights["Warm"]
    np.testing.assert_allclose(w.power, 10.0 * np.array(warm.data.temperature_color[:3]), rtol=1e-6)
    assert w.power[0] > w.power[2]  # 3000 K is reddish


def test_light_portal_is_no_light_but_a_portal(blender):
    # A Cycles light portal (an area light with Portal on, set in a window of an interior) only guides
    # Cycles' sampling of the world; extracted as an area light of its 500 W it lit the floor 180x.
    floor = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    add_light(blender, "Lamp", "POINT", location=(3, 0, 2), energy=100.0)
    portal = add_light(blender, "Portal", "AREA", location=(0, 0, 1), energy=500.0)
    portal.data.cycles.is_portal = True
    portal.data.size = 1.0
    ex = run(blender, [floor])
    assert [light.name for light in ex.scene.lights] == ["Lamp"]
    (window,) = ex.scene.portals  # the sun's and the world's photons go through it (deviation portal-photons)
    np.testing.assert_allclose(window.position + ex.scene.origin_world, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(window.normal, [0, 0, -1], atol=1e-9)
    assert window.area == pytest.approx(1.0)
    assert not any("Portal" in w for w in ex.warnings)
    portal.data.cycles.is_portal = False  # no update_tag(): Blender keeps the evaluated copy's True
    assert [light.name for light in run(blender, [floor]).scene.lights] == ["Lamp", "Portal"]


PORTAL_IN_CYCLES = """
import json, sys
sys.path[:0] = [{root!r}, {tests!r}]
import pdic_bootstrap
pdic_bootstrap.load()
import bpy
import cycles_reference as cr
bpy.ops.wm.read_factory_settings(use_empty=True)
mesh = bpy.data.meshes.new("Floor")
mesh.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
uv = mesh.uv_layers.new(name="LM")
for i, (u, v) in enumerate([(0, 0), (1, 0), (1, 1), (0, 1)]):
    uv.data[i].uv = (u, v)
floor = bpy.data.objects.new("Floor", mesh)
bpy.context.scene.collection.objects.link(floor)
lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
lamp.data.energy, lamp.location = 100.0, (3, 0, 2)
bpy.context.scene.collection.objects.link(lamp)
portal = bpy.data.objects.new("Portal", bpy.data.lights.new("Portal", "AREA"))
portal.data.energy, portal.data.size, portal.data.cycles.is_portal, portal.location = 500.0, 1.0, True, (0, 0, 1)
bpy.context.scene.collection.objects.link(portal)
with_portal = cr.cycles_bake([floor], "LM", 8, 8, {{"DIRECT"}}, 16)["Floor"]
bpy.data.objects.remove(portal)
without = cr.cycles_bake([floor], "LM", 8, 8, {{"DIRECT"}}, 16)["Floor"]
print(json.dumps([with_portal.tolist(), without.tolist()]))
"""


def test_a_light_portal_adds_nothing_in_cycles():
    # What is_portal relies on: Cycles' Diffuse Direct bake with a 500 W portal over a floor equals the bake
    # without it. In a process of its own: Cycles 5.2.3 crashes (SIGSEGV inside its bake) on the portal's
    # scene after an earlier test's Cycles bake in the same process, and alone too, now and then: 13 of 20
    # runs two at a time on a 2-core machine, none of 10 one at a time (the suite runs one at a time). Its crash
    # is not what this asks, so a run that dies by a signal is run again, five times at most.
    import json
    import subprocess
    import sys
    from pathlib import Path

    tests = Path(__file__).resolve().parent
    code = PORTAL_IN_CYCLES.format(root=str(tests.parent), tests=str(tests))
    for _ in range(5):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        if done.returncode >= 0:
            break
    assert done.returncode == 0, f"exit {done.returncode}: {done.stderr[-2000:]}"
    with_portal, without = (np.array(x) for x in json.loads(done.stdout.strip().splitlines()[-1]))
    assert without.mean() > 0.05
    np.testing.assert_allclose(with_portal, without, rtol=1e-5)


def test_instanced_light_is_extracted(blender):
    scene = blender.context.scene
    col = blender.data.collections.new("Lamps")  # only instanced, not in the scene itself
    lamp = blender.data.objects.new("Bulb", blender.data.lights.new("Bulb", "POINT"))
    col.objects.link(lamp)
    inst = blender.data.objects.new("LampInst", None)
    inst.instance_type, inst.instance_collection, inst.location = "COLLECTION", col, (0, 0, 7)
    scene.collection.objects.link(inst)
    ob = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    ex = run(blender, [ob])
    (light,) = ex.scene.lights
    np.testing.assert_allclose(light.position + ex.scene.origin_world, [0, 0, 7], atol=1e-9)


def test_world_colour_times_strength(blender):
    world = blender.data.worlds.new("Sky")
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.2, 0.4, 0.8, 1.0)
    background.inputs["Strength"].default_value = 2.0
    blender.context.scene.world = world
    ob = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    ex = run(blender, [ob])
    np.testing.assert_allclose(ex.scene.world.radiance, [0.4, 0.8, 1.6], rtol=1e-6)
    assert not ex.warnings


def test_world_environment_texture_warns_and_uses_constant(blender):
    world = blender.data.worlds.new("HDRI")
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    env = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    world.node_tree.links.new(env.outputs["Color"], background.inputs["Color"])
    blender.context.scene.world = world
    ob = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    ex = run(blender, [ob])
    np.testing.assert_allclose(ex.scene.world.radiance, [0.5, 0.5, 0.5], rtol=1e-6)
    assert any("HDRI" in w and "ShaderNodeTexEnvironment" in w for w in ex.warnings)


# --------------------------------------------------------------------------- errors
def test_nan_vertex_is_an_error_naming_the_object(blender):
    ob = add_mesh(blender, "Broken", [(0, 0, 0), (1, 0, 0), (float("nan"), 1, 0)], [(0, 1, 2)])
    add_light(blender, "Lamp")
    with pytest.raises(SceneError, match="Broken"):
        run(blender, [ob])


def test_no_bakeable_mesh_is_an_error(blender):
    lamp = add_light(blender, "Lamp")
    hidden = add_mesh(blender, "Hidden")
    hidden.hide_render = True
    with pytest.raises(SceneError, match="no bakeable mesh"):
        run(blender, [lamp, hidden])
    with pytest.raises(SceneError, match="no bakeable mesh"):
        run(blender, [])


def test_nothing_emitting_is_an_error(blender):
    ob = add_mesh(blender, "Dark")
    add_light(blender, "Off", energy=0.0)
    with pytest.raises(SceneError, match="nothing emits light"):
        run(blender, [ob])


def test_target_that_lost_its_lightmap_uv_is_an_error(blender):
    ob = add_mesh(blender, "Remeshed")
    ob.modifiers.new("Remesh", "REMESH").mode = "VOXEL"  # voxel remesh drops UV maps
    add_light(blender, "Lamp")
    with pytest.raises(SceneError, match=f"Remeshed.*{LM}"):
        run(blender, [ob])


# --------------------------------------------------------------------------- copies, curves, shadows (issue 14)
def _unique_lightmap_uv(mesh):
    """Give every face of ``mesh`` its own cell of a 4x4 grid in the light-map UV map (an unwrap's layout)."""
    layer = mesh.uv_layers[LM]
    for i, poly in enumerate(mesh.polygons):
        cell = np.array([i % 4, i // 4], float) / 4
        square = [(0.02, 0.02), (0.23, 0.02), (0.23, 0.23), (0.02, 0.23)]
        for corner, loop in zip(square, poly.loop_indices):
            layer.uv[loop].vector = tuple(cell + corner)


@pytest.mark.parametrize("kind", ["ARRAY", "MIRROR"])
def test_modifier_copies_sharing_lightmap_texels_are_refused_naming_the_modifier(blender, kind):
    shifted = [(x + 2, y, z) for x, y, z in CUBE_VERTS]  # off the mirror plane: the copy is a second box
    ob = add_mesh(blender, "Pillar", shifted)
    _unique_lightmap_uv(ob.data)
    other = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES, location=(0, 0, -2))
    add_light(blender, "Lamp")
    assert run(blender, [ob, other]).target_objects == ["Pillar", "Floor"]  # unmodified: baked
    ob.modifiers.new("Copies", kind)
    ex = run(blender, [ob, other])
    assert ex.target_objects == ["Floor"]
    assert any("Pillar" in w and "'Copies' (" + kind + ")" in w and "Apply" in w for w in ex.warnings)
    assert (ex.scene.geometry.target == -1).sum() == 24  # both copies still cast shadows
    with pytest.raises(SceneError, match="Pillar.*Copies"):
        run(blender, [ob])


def test_subdivided_copy_of_an_overlapping_uv_layout_is_not_refused(blender):
    ob = add_mesh(blender, "Smooth")  # every face on the whole UV square: overlapping before any modifier
    ob.modifiers.new("Subdivision", "SUBSURF").levels = 1
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    assert ex.target_objects == ["Smooth"] and len(ex.scene.targets[0].triangles) == 48


@pytest.mark.parametrize("kind", ["CURVE", "FONT"])
def test_curve_and_text_objects_are_extracted_once(blender, kind):
    target = add_mesh(blender, "Target", QUAD_VERTS, QUAD_FACES)
    data = blender.data.curves.new("Shape", kind)
    if kind == "CURVE":
        data.bevel_depth = 0.1
        spline = data.splines.new("POLY")
        spline.points.add(1)
        spline.points[1].co = (1, 0, 0, 1)
    else:
        data.body = "Hi"
        data.extrude = 0.05
    shape = blender.data.objects.new("Shape", data)
    blender.context.scene.collection.objects.link(shape)
    add_light(blender, "Lamp")
    mesh = shape.evaluated_get(blender.context.evaluated_depsgraph_get()).to_mesh()
    expected = len(mesh.loop_triangles)
    shape.evaluated_get(blender.context.evaluated_depsgraph_get()).to_mesh_clear()
    ex = run(blender, [target])
    assert expected > 10
    assert (ex.scene.geometry.target == -1).sum() == expected  # once, not the object and its mesh instance


def test_alpha_and_transmission_let_light_through_and_scale_reflection(blender):
    glass, glass_bsdf = principled(blender, "Glass")
    glass_bsdf.inputs["Transmission Weight"].default_value = 1.0
    veil, veil_bsdf = principled(blender, "Veil")
    veil_bsdf.inputs["Alpha"].default_value = 0.25
    veil_bsdf.inputs["Base Color"].default_value = (0.8, 0.4, 0.2, 1.0)
    veil_bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    veil_bsdf.inputs["Emission Strength"].default_value = 2.0
    a = add_mesh(blender, "A", QUAD_VERTS, QUAD_FACES, material=glass)
    add_mesh(blender, "B", QUAD_VERTS, QUAD_FACES, location=(3, 0, 0), material=veil)
    add_mesh(blender, "C", QUAD_VERTS, QUAD_FACES, location=(6, 0, 0))
    ex = run(blender, [a])
    g, m = ex.scene.geometry, ex.scene.materials
    rows = {name: i for i, name in enumerate(m.names)}
    tau = {name: g.transmission[g.material == row] for name, row in rows.items()}
    np.testing.assert_allclose(tau["Glass"], 1.0)
    np.testing.assert_allclose(tau["Veil"], 0.75)
    np.testing.assert_allclose(tau["default"], 0.0)
    np.testing.assert_allclose(m.base_color[rows["Glass"]], 0.0)  # no diffuse lobe left
    np.testing.assert_allclose(m.base_color[rows["Veil"]], [0.2, 0.1, 0.05], atol=1e-6)
    np.testing.assert_allclose(m.emission[rows["Veil"]], 0.5, atol=1e-6)  # alpha mixes emission too


def test_shadow_visibility_off_makes_an_object_fully_transmissive(blender):
    floor = add_mesh(blender, "Floor", QUAD_VERTS, QUAD_FACES)
    blocker = add_mesh(blender, "Blocker", location=(0, 0, 2))
    blocker.visible_shadow = False
    add_light(blender, "Lamp")
    g = run(blender, [floor]).scene.geometry
    np.testing.assert_allclose(g.transmission[g.target == -1], 1.0)
    np.testing.assert_allclose(g.transmission[g.target == 0], 0.0)


def test_negative_emission_warns_naming_the_material(blender):
    mat, bsdf = principled(blender, "AntiGlow")
    bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = -3.0
    ob = add_mesh(blender, "A", QUAD_VERTS, QUAD_FACES, material=mat)
    add_light(blender, "Lamp")
    ex = run(blender, [ob])
    assert any("AntiGlow" in w and "negative emission" in w for w in ex.warnings)
    np.testing.assert_allclose(ex.scene.materials.emission, 0.0)
