"""bench/referee_competitors.py: which blocks it audits, what it traces there, and the error it reports."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.bench import path_referee, referee_competitors
from pdic.bench.competitors import block_means
from pdic.core.lights import PointLight
from scenes import quad, quad_scene


def test_worst_blocks_and_the_refereed_block_error_by_hand():
    """Four 8x8 blocks, a flat pair at 1: PDIC reads 2 in one block and 1.1 in another. The block off by 1
    is the worst; against the pair the block error is sqrt((1 + 0.01) / 4) / 1; with the truth traced
    at 2 there (no noise), only the 0.1 is left, over a mean reference of 1.25."""
    pair = (np.ones((16, 16, 3), np.float32), np.ones((16, 16, 3), np.float32))
    pdic = np.ones((16, 16, 3), np.float32)
    pdic[8:, :8] = 2.0
    pdic[:8, 8:] = 1.1
    mask = np.ones((16, 16), bool)
    blocks = referee_competitors.pair_blocks(pair, mask)
    test = block_means(pdic, mask)[0]
    chosen = referee_competitors.worst_blocks(test, blocks, 1)
    assert chosen.tolist() == [[1, 0]]
    before, after = referee_competitors.refereed_block_error(test, blocks, chosen, np.full((1, 3), 2.0), np.zeros(1))
    assert before == pytest.approx(np.sqrt(1.01 / 4), rel=1e-6)
    assert after == pytest.approx(np.sqrt(0.01 / 4) / 1.25, rel=1e-5)


def test_traced_blocks_of_a_lone_floor_hold_the_lamps_direct_light_over_cycles_footprints():
    """A lone 1 x 1 m floor under a point lamp: no surface to bounce from, so every path escapes and the
    traced block mean is the direct light alone, E / pi = P h / (4 pi d^3) / pi averaged per texel over
    the footprint points Blender 5.0 bakes (the same draws as the referee's), then over the block's
    texels; "indirect" gives 0."""
    power = 10.0
    scene = quad_scene([quad([0, 0, 0], [1, 0, 0], [0, 1, 0])], {"floor": (0, 16)},
                       (PointLight("lamp", np.array([0.5, 0.5, 1.0]), np.full(3, power)),))
    lamp = scene.lights[0].position  # the scene's local frame
    mask = np.ones((16, 16), bool)
    mask[0, 0] = False  # a texel left out of its block's mean
    chosen = np.array([[1, 0], [0, 0]])  # a lower block first: each block's mean lands in its own row
    traced, se, _ = referee_competitors.traced_blocks(scene, "all", mask, chosen, paths=2, per_axis=2, seed=5)
    y, x = np.nonzero(mask & (np.arange(16)[None, :] < 8))  # blocks (0, 0) and (1, 0): the left column
    texels = y * 16 + x
    texel, p, _ = path_referee.cycles_footprint(scene, 0, texels, 2, np.random.default_rng(5), False)
    d = np.linalg.norm(lamp - p, axis=1)
    exact = power * lamp[2] / (4 * np.pi * d ** 3) / np.pi
    slot = np.searchsorted(texels, texel)
    per_texel = np.bincount(slot, weights=exact) / np.bincount(slot)
    for row, upper in ((0, y >= 8), (1, y < 8)):
        assert traced[row] == pytest.approx(np.full(3, per_texel[upper].mean()), rel=1e-6)
    assert traced[0, 0] != pytest.approx(traced[1, 0], rel=1e-3)
    assert np.all(se == 0.0)
    dark, _, black = referee_competitors.traced_blocks(scene, "indirect", mask, chosen, paths=2, per_axis=2, seed=5)
    assert np.all(dark == 0.0)
    assert black.tolist() == [int((texel // 16 >= 8).sum()), int((texel // 16 < 8).sum())]  # every point black
