"""bench/small_blocks.py: a Cycles bake restricted to some polygons gives their texels the full bake's values."""
from __future__ import annotations

import numpy as np

import cycles_reference as cr
from pdic.bench import small_blocks
from pdic.pdic_addon.uvmaps import read_uv


def _lit_floor_with_a_box(bpy):
    """An 8 x 8-quad floor (2 x 2 m, UV layer 'UVMap' over [0, 1]^2), a box standing on it, a lamp above."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=8, y_subdivisions=8, size=2.0)
    floor = bpy.context.active_object
    floor.name = "Floor"
    floor.data.materials.append(bpy.data.materials.new("FloorMat"))
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.2, 0.1, 0.3))
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy, lamp.data.shadow_soft_size, lamp.location = 200.0, 0.0, (-0.4, -0.3, 1.5)
    bpy.context.scene.collection.objects.link(lamp)
    world = bpy.data.worlds.new("World")
    next(n for n in world.node_tree.nodes if n.type == "BACKGROUND").inputs["Strength"].default_value = 0.0
    bpy.context.scene.world = world
    return floor


def test_seed_spread_is_the_relative_deviation_of_each_blocks_mean_over_the_masked_texels():
    """Two seeds' 16 x 8 maps, blocks (0, 0) and (0, 1): the left block's masked texels read 1 and 3 (spread
    std / mean = sqrt(2) / 2), the right block's 2 and 2 whatever its unmasked texels read (spread 0)."""
    mask = np.zeros((8, 16), bool)
    mask[2:4, 1:3] = True
    mask[5, 12] = True
    a, b = np.full((8, 16, 3), 2.0, np.float32), np.full((8, 16, 3), 2.0, np.float32)
    a[:, :8], b[:, :8] = 1.0, 3.0
    b[0, 8:] = 50.0  # outside the mask
    spread = small_blocks.seed_spread([a, b], mask)
    np.testing.assert_allclose(spread[0], [np.sqrt(2.0) / 2.0, 0.0], rtol=1e-6)


def test_polygons_touching_blocks_are_those_whose_uv_box_reaches_them():
    """Two unit-square quads in a 32^2 map: (1-3, 1-3) texels reaches block (0, 0) only, (20-22, 9-11)
    texels block (1, 2); a box one texel wider, (20-22, 7-9) texels, reaches row 0 of blocks too."""
    quad = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    uv = np.concatenate([(quad * 2 + 1) / 32, (quad * 2 + [20, 9]) / 32, (quad * 2 + [20, 7]) / 32])
    blocks = np.zeros((4, 4), bool)
    blocks[1, 2] = True
    keep = small_blocks.polygons_touching(uv, np.array([4, 4, 4]), 32, 32, blocks)
    np.testing.assert_array_equal(keep, [False, True, True])
    blocks[:] = False
    blocks[0, 2] = True
    np.testing.assert_array_equal(small_blocks.polygons_touching(uv, np.array([4, 4, 4]), 32, 32, blocks),
                                  [False, False, True])


def test_a_bake_restricted_to_some_polygons_gives_their_texels_the_full_bakes_values(blender):
    """Cycles draws each texel's samples from the texel and the seed: with the other polygons collapsed
    onto one point of the UV layer copy, the kept polygons' texels bake to the full bake's values, in the
    same light (the floor's other quads still reflect it), and nothing else is baked but that point."""
    floor = _lit_floor_with_a_box(blender)
    full = cr.cycles_bake_full([floor], "UVMap", 32, 32, {"DIRECT", "INDIRECT"}, 16, seed=1, diffuse_bounces=8)
    loop_total = np.full(len(floor.data.polygons), 4)
    blocks = np.zeros((4, 4), bool)
    blocks[1, 2] = True
    keep = small_blocks.polygons_touching(read_uv(floor.data, "UVMap"), loop_total, 32, 32, blocks)
    assert 0 < keep.sum() < len(keep) // 2
    small_blocks.restricted_layer(floor.data, "UVMap", keep, 32, 32)
    part = cr.cycles_bake_full([floor], small_blocks.RESTRICT_UV, 32, 32, {"DIRECT", "INDIRECT"}, 16, seed=1,
                               diffuse_bounces=8)
    covered, baked = full.coverage["Floor"], part.coverage["Floor"]
    assert baked[8:16, 16:24].all()  # block (1, 2), every texel
    assert covered.sum() == 32 * 32 and 64 <= baked.sum() <= 0.4 * covered.sum()
    lit = baked.copy()
    lit[0, 0] = False  # the collapsed polygons' point
    np.testing.assert_allclose(part.images["Floor"][lit], full.images["Floor"][lit], rtol=1e-5, atol=1e-6)
    assert full.images["Floor"][lit].mean() > 0.05
