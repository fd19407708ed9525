"""A floor texel at a wall's foot: its indirect light is the outside samples' mean times the share of
its footprint outside the wall (core/validity.py ``indirect_weights``), as Cycles' bake has it.

Core only, real rays. A 4 m floor (32^2 texels of 12.5 cm) continues under a closed box standing on
it (a wall on a slab, as modellers build them). The wall's face cuts one texel column a quarter of
a texel from its centre: of the centred half-texel footprint Cycles integrates (Blender 5.0-5.1),
3/4 or 1/4 lies outside. The texel's 2x2 samples split 1 outside / 1 inside in both cases, so
averaging the samples (inside ones at 0) gave 1/2 both times: the occluded building at 4 texels/m
had such texels at half of Cycles' light, or twice it.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core import pipeline
from pdic.core import texels as texel_stage
from pdic.core.executor import Executor, Progress
from pdic.core.rays import RayCaster
from pdic.core.scene import BakeTarget, Materials, PointLight, Scene, recentre
from pdic.core.settings import Deviations, preset
from pdic.core.validity import indirect_weights, texel_validity

from scenes import geometry, quad
from test_closed_box_leak import _box

RES = 32
TEXEL = 4.0 / RES
COLUMN = 20
"""The texel column the wall's face cuts; its centre is at x = -2 + (COLUMN + 1/2) TEXEL."""


def _scene(wall_x: float) -> Scene:
    """The floor (target "Floor", UVs = x, y) and a closed wall box on it for x > wall_x; a lamp on the open side."""
    tris = np.concatenate([quad([-2, -2, 0], [4, 0, 0], [0, 4, 0]), _box([wall_x, -2, 0], [2, 2, 1])])
    local, origin = recentre(tris)
    target = np.full(len(tris), -1, np.int32)
    target[:2] = 0
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    floor = BakeTarget("Floor", np.array([0, 1]), uv, RES, RES)
    light = PointLight("Lamp", np.array([-1.0, 0.0, 1.5]) - origin, np.full(3, 200.0))
    return Scene(geometry(local, target=target), Materials.default(1), lights=(light,), targets=(floor,),
                 origin_world=origin)


def _shares(wall_x: float) -> np.ndarray:
    """(RES,) the indirect-light shares of row RES/2's texels (their samples' weights summed)."""
    scene = _scene(wall_x)
    settings = preset("FINAL", threads=1, deviations=Deviations(photon_evidence=False))
    points, rasters = texel_stage.lift_texels(scene, settings.texel_samples)
    caster = RayCaster(scene.geometry.positions, scene.extent, Executor(1), scene.geometry.transmission)
    inside, _, _ = texel_validity(caster, points, [0, 1], Executor(1), Progress())
    weights, rays = indirect_weights(scene, caster, None, 0, points, inside, settings, 0.25, 7,
                                     centre_triangle=rasters[0].centre_triangle)
    assert rays > 0
    share = np.bincount(points.texel, weights=weights, minlength=RES * RES).reshape(RES, RES)
    return share[RES // 2]


@pytest.mark.parametrize("offset, outside", [(+0.125, 0.75), (-0.125, 0.25)])
def test_a_texel_at_a_walls_foot_takes_the_share_of_its_footprint_outside(offset, outside):
    centre = -2 + (COLUMN + 0.5) * TEXEL
    row = _shares(centre + offset * TEXEL)
    assert row[COLUMN] == pytest.approx(outside, abs=0.06)  # 36 jittered points vote
    assert np.allclose(row[:COLUMN], 1.0)  # the open floor: every sample counts in full
    assert np.allclose(row[COLUMN + 1:], 0.0)  # under the wall: no light


def test_the_floor_at_a_walls_foot_is_not_halved():
    """End to end (Preview): the texel three quarters outside keeps about 3/4 of its neighbour's light,
    not the half its samples' plain mean gave; the texels under the wall stay black."""
    centre = -2 + (COLUMN + 0.5) * TEXEL
    result = pipeline.bake(_scene(centre + 0.125 * TEXEL), preset("PREVIEW", photons=60_000, threads=1))
    row = result.indirect["Floor"][RES // 2].mean(axis=1)
    assert np.isfinite(row).all() and (row[COLUMN + 1:] == 0).all()
    assert 0.6 < row[COLUMN] / row[COLUMN - 1] < 0.95
