"""Issue #11's acceptance on the generated cathedral: PDIC's direct light against Cycles', texel by texel.

One object, tests/cathedral.py at detail 0.3 (25k triangles: columns with capitals,
rosettes, arches, walls with an inside and an outside, mouldings, parapets,
tracery, an apse, stairs), two hard point lights in the nave, a black world.
PDIC bakes direct light only through ``BakeJob`` at 512^2; Cycles bakes Diffuse
Direct (no Color) into the same ``PDIC_Lightmap`` UVs (tests/test_direct_vs_cycles:
``bake_pdic``, ``bake_cycles``, masks ``baked`` and ``flat``).

"Away from shadow edges" is the ``flat`` mask: baked texels whose 3x3
neighbourhood is baked and whose Cycles luminance varies there by < 10 % of the
centre's (or is 0 throughout). Near edges PDIC's 2x2 sub-sample average and
Cycles' texel-centre sample legitimately differ: shadow and contact lines (floor
under walls and column bases, mouldings), and chart-border texels of column
shafts whose centre lies on a facet turned away from the lights while half the
texel covers the next facet, lit, which has no texel centre of its own.

Measured (bench/cathedral_direct.py, detail 0.3, 512^2, Cycles 16 spp; session 22, stairs
built as one flight): 92,469 baked texels, 45,230 flat; within 2 % on 99.51 % of the flat texels
(Cycles' own seed-to-seed agreement there: 99.73 %); lit in PDIC where Cycles is dark 0.90 % of
the baked texels (the issue measured 8.4 % before the UV overlap fix), the reverse 0.06 %; 10 flat
texels off by > 90 %.
"""
from __future__ import annotations

import numpy as np
import pytest

from cathedral import cathedral
from test_direct_vs_cycles import bake_cycles, bake_pdic, flat_mask

DETAIL, RES, CYCLES_SPP = 0.3, 512, 16
LIGHTS = ((10.0, 0.5, 8.0, 1500.0), (29.0, -1.0, 4.0, 800.0))  # x, y, z metres; watts
DARK = 1e-4
"""E/pi below which a texel counts as having no direct light (lit texels here: 0.01 to 10)."""
WITHIN = 0.02
ALBEDO = 0.8
"""The cathedral's one material: a Diffuse BSDF of this grey (build_cathedral_scene)."""


def build_cathedral_scene(bpy, detail: float = DETAIL):
    """The cathedral as one mesh object of one Diffuse BSDF material (grey ALBEDO) and two hard
    point lights in the nave, black world; returns the object.

    A Diffuse BSDF, not Blender's default surface: Cycles 4.x and 5.x shade an object without
    materials as a Principled BSDF (base 0.8, its specular layer on), whose diffuse interreflection
    a pure Lambertian surface does not model (PDIC extracts both as diffuse 0.8). Measured on this
    cathedral (64-spp bakes, the 1,024-spp pair's texels): the default surface's indirect light is
    that of a Diffuse BSDF of 0.790, 3.1 % below diffuse 0.8 (floor 3.6 %, tracery 4.6 %); a
    Principled BSDF with Specular IOR Level 0 equals diffuse 0.8 to the last digit."""
    world = bpy.data.worlds.new("World")
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    bpy.context.scene.world = world
    polygons = cathedral(detail)
    mesh = bpy.data.meshes.new("Cathedral")
    mesh.from_pydata(polygons.positions.tolist(), [], polygons.faces())
    mesh.validate()
    mesh.materials.append(_diffuse_material(bpy, "CathedralStone", ALBEDO))
    ob = bpy.data.objects.new("Cathedral", mesh)
    bpy.context.scene.collection.objects.link(ob)
    for k, (x, y, z, watts) in enumerate(LIGHTS):
        light = bpy.data.lights.new(f"Light{k}", "POINT")
        light.energy = watts
        light.shadow_soft_size = 0.0
        lob = bpy.data.objects.new(f"Light{k}", light)
        lob.location = (x, y, z)
        bpy.context.scene.collection.objects.link(lob)
    bpy.context.view_layer.update()  # objects linked from Python join the view layer on update
    return ob


def _diffuse_material(bpy, name: str, albedo):
    """A node material whose surface is one Diffuse BSDF of ``albedo``: a grey level or an RGB triple."""
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender 5.0 gives every material a tree and deprecates use_nodes
        material.use_nodes = True
    nodes = material.node_tree.nodes
    for node in [n for n in nodes if n.type != "OUTPUT_MATERIAL"]:
        nodes.remove(node)
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*np.broadcast_to(albedo, 3), 1.0)
    output = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    material.node_tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
    return material


def direct_comparison(P: np.ndarray, C: np.ndarray, baked: np.ndarray) -> dict:
    """Shares of texels: ``within`` (of ``flat``) and the lit/dark disagreements (of ``baked``).

    P, C : (H, W, 3) float32 E/pi of PDIC and Cycles; baked : (H, W) bool.
    """
    lp, lc = P.mean(axis=2), C.mean(axis=2)
    flat = flat_mask(C, baked)
    rel = np.abs(lp - lc) / np.maximum(lc, DARK)
    agree = (rel <= WITHIN) | ((lp <= DARK) & (lc <= DARK))
    n = baked.sum()
    return {"baked": int(n), "flat": int(flat.sum()), "flat_mask": flat,
            "within": float(agree[flat].mean()), "far_off": float((rel[flat] > 0.9).mean()),
            "pdic_only": float((baked & (lp > DARK) & (lc <= DARK)).sum() / n),
            "cycles_only": float((baked & (lc > DARK) & (lp <= DARK)).sum() / n)}


@pytest.mark.slow
def test_cathedral_direct_light_within_2_percent_of_cycles_away_from_shadow_edges(blender, registered, tmp_path):
    ob = build_cathedral_scene(blender)
    job, _ = bake_pdic(blender, tmp_path, direct_samples=1, resolution=RES)
    P = job.result.as_cycles(ob.name)  # Cycles' convention (the light map fills buried texels)
    assert P.shape[:2] == (RES, RES)
    reference = bake_cycles(blender, ob, CYCLES_SPP, resolution=RES)
    baked = reference.coverage[ob.name] & job.result.centre_inside[ob.name]
    m = direct_comparison(P, reference.images[ob.name], baked)
    print(f"\ncathedral {DETAIL}: {m['baked']} baked, {m['flat']} flat; within 2 % {m['within']:.4f}; "
          f"lit only in PDIC {m['pdic_only']:.4f}, only in Cycles {m['cycles_only']:.4f}; off > 90 % {m['far_off']:.5f}")
    assert m["baked"] >= 0.85 * job.result.centre_inside[ob.name].sum()
    assert m["flat"] >= 0.3 * m["baked"]  # the edge mask leaves most of the cathedral in
    assert m["within"] >= 0.99  # the acceptance
    assert m["far_off"] <= 0.001
    assert m["pdic_only"] <= 0.02  # 8.4 % before the light-map UVs stopped overlapping
    # lit only in Cycles: texels at chart borders next to lit ones (0.04 % with Cycles 5.0, 0.71 %
    # with Cycles 5.2 on the same UVs; not looked into yet)
    assert m["cycles_only"] <= 0.01
