"""Fuzz: 200 seeded random small scenes bake without a crash, give finite maps or a clear refusal,
and Clear restores each file exactly (issue 14, acceptance).

Each scene draws 1-4 meshes (primitives, some sharing a mesh) with random modifiers, materials
(Principled, emissive, Emission-only, Diffuse, none, two slots), 0-3 lights of every type with
powers over seven decades, one scale for the whole scene in 1e-3..1e4, and names with unicode and
cleaned-name collisions. 20k photons, 32^2 maps. Failures are collected over all scenes and
reported together with their seeds.
"""
from __future__ import annotations

import math
import os
import re

import numpy as np
from snapshot import snapshot

from pdic.pdic_addon import job as job_module
from pdic.pdic_addon import writeback
from pdic.pdic_addon.properties import to_settings

SCENES = int(os.environ.get("PDIC_FUZZ_SCENES", 200))
"""Scenes per run (PDIC_FUZZ_SCENES overrides, e.g. for a quick local look)."""
NAMES = ("Wall.001", "Wall_001", "Wall 1", "Wall_1", "M\u00e8sa", "M\u00e9sa", "\u540d\u524d", "Caf\u00e9 \u2615",
         "Floor", "floor", "x" * 60, "Cube")
PRIMITIVES = ("cube", "plane", "sphere", "cylinder", "cone", "ico", "torus")
MODIFIERS = ("SUBSURF", "ARRAY", "MIRROR", "SOLIDIFY", "BEVEL", "TRIANGULATE")
LIGHTS = ("POINT", "SUN", "SPOT", "AREA")
SETTING_WORDS = ("Photons", "Texel Density", "Resolution", "light", "output folder")


def _primitive(bpy, kind, rng):
    ops = bpy.ops.mesh
    if kind == "cube":
        ops.primitive_cube_add(size=1)
    elif kind == "plane":
        ops.primitive_plane_add(size=2)
    elif kind == "sphere":
        ops.primitive_uv_sphere_add(radius=0.5, segments=int(rng.integers(6, 12)), ring_count=4)
    elif kind == "cylinder":
        ops.primitive_cylinder_add(vertices=int(rng.integers(5, 10)), radius=0.4, depth=1)
    elif kind == "cone":
        ops.primitive_cone_add(vertices=int(rng.integers(4, 9)), radius1=0.5, depth=1)
    elif kind == "ico":
        ops.primitive_ico_sphere_add(subdivisions=1, radius=0.5)
    else:
        ops.primitive_torus_add(major_segments=8, minor_segments=4, major_radius=0.5, minor_radius=0.15)
    return bpy.context.object


def _material(bpy, rng, i):
    kind = rng.choice(["principled", "emissive", "emission_only", "diffuse", "none"], p=[.5, .1, .1, .15, .15])
    if kind == "none":
        return None
    mat = bpy.data.materials.new(f"Mat{i}.{kind}")
    tree = mat.node_tree
    color = (*rng.uniform(0, 1, 3), 1.0)
    if kind in ("principled", "emissive"):
        bsdf = tree.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = color
        if kind == "emissive":
            bsdf.inputs["Emission Color"].default_value = color
            bsdf.inputs["Emission Strength"].default_value = float(10 ** rng.uniform(-1, 2))
        return mat
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    node = tree.nodes.new("ShaderNodeEmission" if kind == "emission_only" else "ShaderNodeBsdfDiffuse")
    node.inputs["Color"].default_value = color
    if kind == "emission_only":
        node.inputs["Strength"].default_value = float(10 ** rng.uniform(-1, 2))
    tree.links.new(node.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    return mat


def _modifier(obj, rng):
    kind = str(rng.choice(MODIFIERS))
    mod = obj.modifiers.new(kind.title(), kind)
    if kind == "SUBSURF":
        mod.levels = 1
    elif kind == "ARRAY":
        mod.count = 2
    elif kind == "SOLIDIFY":
        mod.thickness = 0.05
    elif kind == "BEVEL":
        mod.width = 0.05


def build_random_scene(bpy, rng) -> float:
    """A random scene (see the module docstring) in the empty factory file; returns its scale."""
    scale = float(10 ** rng.uniform(-3, 4))
    meshes = []
    for i in range(int(rng.integers(1, 5))):
        if meshes and rng.random() < 0.15:  # a linked duplicate
            obj = bpy.data.objects.new("Twin", meshes[-1].data)
            bpy.context.scene.collection.objects.link(obj)
        else:
            obj = _primitive(bpy, str(rng.choice(PRIMITIVES)), rng)
            for _ in range(int(rng.integers(0, 3))):
                mat = _material(bpy, rng, i)
                obj.data.materials.append(mat)
            if rng.random() < 0.4:
                _modifier(obj, rng)
        obj.name = str(rng.choice(NAMES))
        obj.location = tuple(rng.uniform(-2, 2, 3) * scale)
        obj.rotation_euler = tuple(rng.uniform(0, math.pi, 3))
        obj.scale = tuple(np.full(3, scale) * rng.uniform(0.5, 2, 3))
        meshes.append(obj)
    for _ in range(int(rng.integers(0, 4))):
        kind = str(rng.choice(LIGHTS))
        bpy.ops.object.light_add(type=kind, location=tuple(rng.uniform(-2, 2, 3) * scale + [0, 0, 3 * scale]))
        light = bpy.context.object.data
        light.energy = float(10 ** rng.uniform(-2, 5)) * (1 if kind == "SUN" else scale ** 2)
        light.name = str(rng.choice(NAMES))
    props = bpy.context.scene.pdic
    props.quality, props.photons, props.max_bounces = "CUSTOM", 20000, 2
    props.hemisphere_theta, props.hemisphere_phi = 2, 4
    props.default_resolution = 32
    return scale


def _refusal_is_clear(message: str, bpy) -> bool:
    names = [o.name for o in bpy.data.objects] + [m.name for m in bpy.data.meshes]
    return bool(message) and "internal" not in message.lower() and (
        any(repr(n) in message or n in message for n in names) or any(w in message for w in SETTING_WORDS))


def _check_one(bpy, tmp_path, seed: int, outcomes: dict) -> str | None:
    """Bake scene ``seed``; None if all is well, else what went wrong. Counts outcomes by kind."""
    rng = np.random.default_rng(seed)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scale = build_random_scene(bpy, rng)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / f"fuzz{seed}.blend"))
    before = snapshot(bpy)
    where = f"scene {seed} (scale {scale:.3g})"
    try:
        report = job_module.BakeJob(bpy.context, to_settings(bpy.context.scene.pdic)).run()
    except job_module.BakeError as e:
        outcomes.setdefault(re.sub(r"'[^']*'|\d+", "_", str(e))[:60], []).append(seed)
        if snapshot(bpy) != before:
            return f"{where}: refused ({e}) but the file changed"
        return None if _refusal_is_clear(str(e), bpy) else f"{where}: unclear refusal: {e}"
    except Exception as e:  # noqa: BLE001 - any other exception is the finding
        return f"{where}: crashed: {type(e).__name__}: {e}"
    for entry in report.objects:
        image = writeback.owned_images(entry["name"])[0]
        px = np.empty(len(image.pixels), np.float32)
        image.pixels.foreach_get(px)
        if not np.isfinite(px).all():
            return f"{where}: non-finite texels in {entry['name']!r}"
    writeback.clear(None)
    if snapshot(bpy) != before:
        return f"{where}: Clear did not restore the file"
    outcomes.setdefault("baked", []).append(seed)
    return None


def test_random_scenes_bake_or_refuse_clearly_and_clear_restores_them(blender, registered, tmp_path):
    outcomes: dict = {}
    problems = [p for p in (_check_one(blender, tmp_path, seed, outcomes) for seed in range(SCENES)) if p]
    print({k: len(v) for k, v in outcomes.items()})
    assert not problems, "\n".join(problems)
    assert len(outcomes.get("baked", [])) >= SCENES // 2  # most scenes bake: the checks above are not vacuous


def test_refusal_check_needs_a_name_or_a_setting(blender):
    blender.ops.mesh.primitive_cube_add()
    assert _refusal_is_clear("nothing to bake: 'Cube' has no faces", blender)
    assert not _refusal_is_clear("internal error: ZeroDivisionError", blender)
    assert not re.search("Cube", "") and not _refusal_is_clear("", blender)
