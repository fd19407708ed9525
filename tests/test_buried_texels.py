"""Texels a wall standing on the floor cuts or covers take their whole neighbours' light in the light
map (deviation: buried-texels).

Core only, real rays. The floor of tests/test_straddling_texels.py continues under a closed wall
box. Cycles' bake (and the bake's ``direct`` and ``indirect`` images, ``BakeResult.as_cycles``)
holds each texel's footprint mean with the part under the wall at 0: the texel the wall's face
cuts at 3/4 holds 3/4 of the floor's light, those under the wall 0. No camera sees those parts,
but a game engine's bilinear filter spreads a texel over the visible floor up to the wall: a
dark line along the wall's foot. The light map fills those (buried) texels from their whole
neighbours by dilation.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core import pipeline
from pdic.core.settings import Deviations, preset

from scenes import bake_samples
from test_straddling_texels import COLUMN, RES, TEXEL, _scene

ROW = RES // 2
RINGS = preset("PREVIEW").padding + 2
"""Dilation rings: buried texels this close to the open floor are filled, deeper ones stay empty."""


@pytest.fixture(scope="module")
def bakes():
    wall_x = -2 + (COLUMN + 0.5 + 0.125) * TEXEL  # the face a quarter texel past COLUMN's centre: 3/4 outside
    settings = dict(photons=60_000, threads=1)
    visible = pipeline.bake(_scene(wall_x), preset("PREVIEW", **settings))
    cycles = pipeline.bake(_scene(wall_x), preset("PREVIEW", **settings, deviations=Deviations(buried_texels=False)))
    return visible, cycles


def test_the_texels_the_wall_cuts_or_covers_are_buried(bakes):
    visible, _ = bakes
    buried = visible.buried["Floor"]
    assert buried[:, COLUMN:].all()  # the cut column (3/4 outside) and every texel under the wall
    assert not buried[:, :COLUMN].any()  # the open floor
    assert visible.stats["counters"]["texels_buried"] == int(buried.sum())


def test_the_light_map_holds_the_visible_floors_light(bakes):
    visible, cycles = bakes
    lit = visible.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    alpha = visible.lightmaps["Floor"][ROW, :, 3]
    as_cycles = visible.as_cycles("Floor")[ROW].mean(axis=1)
    # Cycles' convention: the cut texel holds about 3/4 of its open neighbour's light, those under the wall 0.
    assert 0.6 < as_cycles[COLUMN] / as_cycles[COLUMN - 1] < 0.95
    assert (as_cycles[COLUMN + 1:] == 0).all()
    # The light map: the cut texel and the buried ones next to it hold the open neighbour's light
    # (the mean of the whole texels among their 8 neighbours); deeper ones stay empty.
    assert lit[COLUMN] == pytest.approx(lit[COLUMN - 1], rel=0.05)
    assert lit[COLUMN + 1] == pytest.approx(lit[COLUMN], rel=0.05)
    assert (alpha[COLUMN:COLUMN + RINGS] == 1).all()
    assert (alpha[COLUMN + RINGS:] == 0).all() and (lit[COLUMN + RINGS:] == 0).all()
    # The open floor is the same with the switch off, which writes Cycles' convention: black under the wall.
    off = cycles.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    np.testing.assert_array_equal(off[:COLUMN], lit[:COLUMN])
    np.testing.assert_allclose(off, as_cycles, rtol=1e-6, atol=1e-7)
    assert (cycles.lightmaps["Floor"][ROW, COLUMN + 1:, 3] == 1).all()


def test_a_bake_without_indirect_light_buries_them_too():
    """Direct light alone (Passes: Indirect off): the texels the wall cuts or covers within the dilation's
    reach of the lit floor are buried, and the light map fills the wall's foot from the open floor;
    Cycles' convention (``as_cycles``) keeps the cut texel dim. Only unlit samples that near the lit
    floor are voted on."""
    wall_x = -2 + (COLUMN + 0.5 + 0.125) * TEXEL
    result = pipeline.bake(_scene(wall_x), preset("FINAL", indirect=False, threads=1))
    counters = result.stats["counters"]
    buried = result.buried["Floor"]
    # The last lit texels are COLUMN - 1's (the cut one holds its footprint's mean at every sample).
    assert buried[:, COLUMN:COLUMN - 1 + RINGS + 1].all() and not buried[:, :COLUMN].any()
    assert not buried[:, COLUMN - 1 + RINGS + 1:].any()  # past the reach: not voted
    assert counters["texels_buried"] == int(buried.sum())
    # The cut column's inside samples and the RINGS - 1 columns past it: 2 and 4 per texel, more where the
    # floor's diagonal crosses them (folded onto the centre triangle, docs/DEVIATIONS.md crease-folding).
    scene = _scene(wall_x)
    points = bake_samples(scene)
    floor = [t.name for t in scene.targets].index("Floor")
    column = points.texel % RES
    under = (points.target == floor) & (column >= COLUMN) & (column < COLUMN + RINGS)
    under &= points.p[:, 0] + scene.origin_world[0] > wall_x
    assert counters["texel_samples_inside_geometry"] == under.sum() >= 2 * RES + 4 * (RINGS - 1) * RES
    assert "photons_emitted" not in counters
    lit = result.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    as_cycles = result.as_cycles("Floor")[ROW].mean(axis=1)
    assert 0.6 < as_cycles[COLUMN] / as_cycles[COLUMN - 1] < 0.95
    assert (as_cycles[COLUMN + 1:] == 0).all()
    # The cut texel and the next one under the wall, which a bilinear filter reads at the wall's foot.
    assert lit[COLUMN] == pytest.approx(lit[COLUMN - 1], rel=0.05)
    assert lit[COLUMN + 1] == pytest.approx(lit[COLUMN], rel=0.05)
    # Switched off, the light map keeps Cycles' dark foot and casts no validity ray.
    off = pipeline.bake(_scene(wall_x), preset("FINAL", indirect=False, threads=1,
                                               deviations=Deviations(buried_texels=False)))
    assert not off.buried["Floor"].any() and "validity_rays" not in off.stats["counters"]
    dark = off.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    assert dark[COLUMN] / dark[COLUMN - 1] < 0.95
