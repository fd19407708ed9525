"""Texels under a wall take their neighbours' light in the light map (deviation: buried-texels).

Core only, real rays. The floor of tests/test_straddling_texels.py continues under a closed wall
box. The floor's texels under the wall are covered (their centres lie on the floor's triangles)
but no camera sees them; Cycles bakes them black. A game engine's bilinear filter reads them for
the visible floor's last half texel, so black there draws a dark line along the wall's foot. The
light map fills them from their neighbours (dilation), the indirect image keeps them black, and
``BakeResult.buried`` names them so comparisons with Cycles leave them out.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core import pipeline
from pdic.core.settings import Deviations, preset

from test_straddling_texels import COLUMN, RES, TEXEL, _scene

ROW = RES // 2
RINGS = preset("PREVIEW").padding + 2
"""Dilation rings: buried texels this close to the open floor are filled, deeper ones stay empty."""


@pytest.fixture(scope="module")
def bakes():
    wall_x = -2 + (COLUMN + 0.5 + 0.125) * TEXEL  # the wall's face a quarter texel past COLUMN's centre
    settings = preset("PREVIEW", photons=60_000, threads=1)
    filled = pipeline.bake(_scene(wall_x), settings)
    black = pipeline.bake(_scene(wall_x), preset("PREVIEW", photons=60_000, threads=1,
                                                  deviations=Deviations(buried_texels=False)))
    return filled, black


def test_the_texels_under_the_wall_are_buried(bakes):
    filled, _ = bakes
    buried = filled.buried["Floor"]
    assert buried[:, COLUMN + 1:].all()  # every texel past the straddling column lies under the wall
    assert not buried[:, :COLUMN + 1].any()  # the open floor and the straddling texel are not
    assert filled.stats["counters"]["texels_buried"] == int(buried.sum())


def test_buried_texels_next_to_the_open_floor_hold_its_light(bakes):
    filled, black = bakes
    lit = filled.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    alpha = filled.lightmaps["Floor"][ROW, :, 3]
    edge = lit[COLUMN]  # the straddling texel: the last one a camera sees (3/4 of it outside)
    assert edge > 0
    # The first buried texel holds its covered neighbours' mean (the straddling column), so a bilinear
    # read between the two texels' centres gives the edge's light, not half of it.
    assert lit[COLUMN + 1] == pytest.approx(edge, rel=0.05)
    assert (alpha[COLUMN + 1:COLUMN + 1 + RINGS] == 1).all()
    assert (alpha[COLUMN + 1 + RINGS:] == 0).all() and (lit[COLUMN + 1 + RINGS:] == 0).all()
    # The indirect image is the bake's own value: black under the wall, as in Cycles.
    assert (filled.indirect["Floor"][ROW, COLUMN + 1:] == 0).all()
    # The open floor is bit for bit the same with the switch off; under the wall it stays black.
    off = black.lightmaps["Floor"][ROW, :, :3].mean(axis=1)
    np.testing.assert_array_equal(off[:COLUMN + 1], lit[:COLUMN + 1])
    assert (off[COLUMN + 1:] == 0).all() and (black.lightmaps["Floor"][ROW, COLUMN + 1:, 3] == 1).all()
