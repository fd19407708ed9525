"""bench.cycles_reference: Cycles bakes E/pi in the PDIC unit and leaves the file as it was."""
from __future__ import annotations

import math

import numpy as np
import pytest

import cycles_reference as cr


def _plane(bpy, name="Plane", size=2.0, location=(0.0, 0.0, 0.0), material=True):
    """A +Z-facing square plane with UV layer 'UVMap' covering [0, 1]^2."""
    bpy.ops.mesh.primitive_plane_add(size=size, location=location)
    ob = bpy.context.active_object
    ob.name = name
    if material:
        ob.data.materials.append(bpy.data.materials.new(f"{name}Mat"))
    return ob


def _sun(bpy, strength):
    light = bpy.data.lights.new("Sun", "SUN")
    light.energy = strength
    light.angle = 0.0
    ob = bpy.data.objects.new("Sun", light)  # no rotation: shines along -Z onto a +Z plane
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _world(bpy, strength):
    world = bpy.data.worlds.new("World")
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bg.inputs["Strength"].default_value = strength
    bpy.context.scene.world = world


def _black_world(bpy):
    _world(bpy, 0.0)


def _snapshot(bpy, objects):
    """Everything cycles_bake must leave as it found it."""
    scene = bpy.context.scene
    view_layer = bpy.context.view_layer
    trees = {}
    for mat in bpy.data.materials:
        nt = mat.node_tree
        trees[mat.name] = (
            sorted(n.name for n in nt.nodes),
            sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier) for l in nt.links),
            nt.nodes.active.name if nt.nodes.active else None,
        )
    return {
        "trees": trees,
        "images": sorted(i.name for i in bpy.data.images),
        "materials": sorted(m.name for m in bpy.data.materials),
        "slots": {ob.name: [s.material.name if s.material else None for s in ob.material_slots] for ob in objects},
        "mesh_materials": {ob.name: [m.name if m else None for m in ob.data.materials] for ob in objects},
        "vertices": {ob.name: [tuple(v.co) for v in ob.data.vertices] for ob in objects},
        "uv_active": {ob.name: ob.data.uv_layers.active.name for ob in objects},
        "selected": sorted(ob.name for ob in view_layer.objects if ob.select_get()),
        "active": view_layer.objects.active.name if view_layer.objects.active else None,
        "render": (scene.render.engine, scene.cycles.samples, scene.cycles.use_adaptive_sampling, scene.cycles.seed,
                   scene.cycles.device, scene.cycles.sample_clamp_indirect, scene.cycles.diffuse_bounces,
                   scene.render.bake.margin, scene.render.bake.use_clear, scene.render.bake.target,
                   scene.cycles.bake_type),
    }


def test_sun_facing_plane_bakes_strength_over_pi(blender):
    strength = 3.0
    plane = _plane(blender)
    _sun(blender, strength)
    _black_world(blender)
    images = cr.cycles_bake([plane], "UVMap", 16, 16, {"DIRECT"}, samples=16)
    texels = images["Plane"]
    assert texels.shape == (16, 16, 3) and texels.dtype == np.float32
    np.testing.assert_allclose(texels, strength / math.pi, rtol=0.01)


def test_uniform_world_of_strength_one_bakes_one(blender):
    plane = _plane(blender)
    _world(blender, 1.0)
    images = cr.cycles_bake([plane], "UVMap", 16, 16, {"DIRECT", "INDIRECT"}, samples=64)
    assert abs(float(images["Plane"].mean()) - 1.0) < 0.03  # E = pi for an unoccluded surface


def test_only_texels_whose_centre_is_in_a_triangle_are_covered(blender):
    plane = _plane(blender)
    _sun(blender, 1.0)
    _black_world(blender)
    uv = plane.data.uv_layers["UVMap"].data
    for loop in uv:  # square [0.13, 0.63]^2: centres (i + 0.5) / 16 inside for i = 2..9
        loop.uv = loop.uv * 0.5 + type(loop.uv)((0.13, 0.13))
    result = cr.cycles_bake_full([plane], "UVMap", 16, 16, {"DIRECT"}, samples=4)
    expected = np.zeros((16, 16), bool)
    expected[2:10, 2:10] = True
    np.testing.assert_array_equal(result.coverage["Plane"], expected)
    assert np.all(result.images["Plane"][~expected] == 0.0)
    np.testing.assert_allclose(result.images["Plane"][expected], 1.0 / math.pi, rtol=0.01)


def test_row_zero_is_the_image_bottom(blender):
    plane = _plane(blender)
    _sun(blender, 1.0)
    _black_world(blender)
    for loop in plane.data.uv_layers["UVMap"].data:  # squeeze into the bottom quarter (v < 0.25)
        loop.uv = type(loop.uv)((loop.uv[0], loop.uv[1] * 0.25))
    coverage = cr.cycles_bake_full([plane], "UVMap", 16, 16, {"DIRECT"}, samples=4).coverage["Plane"]
    assert coverage[:4].all() and not coverage[4:].any()


def test_blender_state_is_restored_after_bake(blender):
    # a material shared by two planes (separate bakes), one plane without material, an unrelated active node
    shared = blender.data.materials.new("Shared")
    nt = shared.node_tree
    extra = nt.nodes.new("ShaderNodeRGB")
    extra.name = "Tint"
    nt.nodes.active = extra
    a = _plane(blender, "A", location=(-3, 0, 0), material=False)
    a.data.materials.append(shared)
    b = _plane(blender, "B", location=(3, 0, 0), material=False)
    b.data.materials.append(shared)
    bare = _plane(blender, "Bare", location=(0, 3, 0), material=False)
    other = _plane(blender, "Other", location=(0, -3, 0))
    _sun(blender, 2.0)
    _black_world(blender)
    scene = blender.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.cycles.samples = 7
    scene.cycles.use_adaptive_sampling = True
    scene.render.bake.margin = 5
    for ob in blender.context.view_layer.objects:
        ob.select_set(False)
    other.select_set(True)
    blender.context.view_layer.objects.active = other
    objects = [a, b, bare, other]
    before = _snapshot(blender, objects)

    result = cr.cycles_bake_full(objects, "UVMap", 16, 16, {"DIRECT"}, samples=4)

    assert _snapshot(blender, objects) == before
    assert not [i for i in blender.data.images if i.name.startswith("PDIC_ref_")]
    # A and B share a material, so they were baked in different calls, each into its own image
    group_of = {name: i for i, g in enumerate(result.groups) for name in g}
    assert group_of["A"] != group_of["B"]
    for name in ("A", "B", "Bare", "Other"):
        np.testing.assert_allclose(result.images[name], 2.0 / math.pi, rtol=0.01)


def test_missing_uv_layer_names_the_object(blender):
    plane = _plane(blender, "NoLightMap")
    with pytest.raises(cr.CyclesBakeError, match="NoLightMap.*LightMap"):
        cr.cycles_bake([plane], "LightMap", 16, 16, {"DIRECT"}, samples=4)


def test_unknown_pass_is_rejected(blender):
    plane = _plane(blender)
    with pytest.raises(cr.CyclesBakeError, match="COLOR"):
        cr.cycles_bake([plane], "UVMap", 16, 16, {"DIRECT", "COLOR"}, samples=4)


def test_light_map_that_renders_textures_is_refused(blender):
    """Textures without a UV Map node sample the active render map: baking into it would change albedos."""
    plane = _plane(blender)
    plane.data.uv_layers.new(name="LightMap")
    plane.data.uv_layers["LightMap"].active_render = True
    tree = plane.data.materials[0].node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = blender.data.images.new("Albedo", 4, 4)
    tree.links.new(tex.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    with pytest.raises(cr.CyclesBakeError, match="Plane: UV map 'LightMap' is the active render map.*'UVMap'"):
        cr.cycles_bake([plane], "LightMap", 8, 8, {"INDIRECT"}, samples=1)
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "UVMap"
    tree.links.new(uv_node.outputs["UV"], tex.inputs["Vector"])
    assert cr.cycles_bake([plane], "LightMap", 8, 8, {"INDIRECT"}, samples=1)["Plane"].shape == (8, 8, 3)


def test_bake_reports_the_bounce_limits_it_ran_with(blender):
    plane = _plane(blender)
    _black_world(blender)
    scene_default = blender.context.scene.cycles.diffuse_bounces
    kept = cr.cycles_bake_full([plane], "UVMap", 4, 4, {"INDIRECT"}, 1)
    raised = cr.cycles_bake_full([plane], "UVMap", 4, 4, {"INDIRECT"}, 1, diffuse_bounces=20)
    assert kept.diffuse_bounces == scene_default
    assert (raised.diffuse_bounces, raised.max_bounces) == (20, 20)
    assert blender.context.scene.cycles.diffuse_bounces == scene_default
