"""A light inside a closed box standing 1 cm above a floor leaves the floor under it black (issue 14 item 18).

Core only. Before the fix, records on the box's inside bottom (1 cm above the floor,
same normal) were accepted by floor texels, hole records on the floor gathered the
box's inside photons and the last-resort fallback took the nearest record, inside
the box: the floor under it reached E/pi 651 (Preview) / 33 (Final).
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core import pipeline
from pdic.core.scene import BakeTarget, Materials, PointLight, Scene, recentre
from pdic.core.settings import Deviations, preset

from scenes import closed_box, geometry, quad

RES = 32


def _box(lo, hi) -> np.ndarray:
    """(12, 3, 3) triangles of a closed box, normals outward."""
    return np.concatenate(closed_box(lo, hi))


def _scene() -> Scene:
    """A 4 m floor (target "Floor") and a 1 m box from z = 0.01 to 1.01 with a 100 W point light inside."""
    tris = np.concatenate([quad([-2, -2, 0], [4, 0, 0], [0, 4, 0]), _box([-0.5, -0.5, 0.01], [0.5, 0.5, 1.01])])
    local, origin = recentre(tris)
    target = np.full(len(tris), -1, np.int32)
    target[:2] = 0
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    floor = BakeTarget("Floor", np.array([0, 1]), uv, RES, RES)
    light = PointLight("Inside", np.array([0.0, 0.0, 0.5]) - origin, np.full(3, 100.0))
    return Scene(geometry(local, target=target), Materials.default(1), lights=(light,), targets=(floor,),
                 origin_world=origin)


@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_light_inside_a_closed_box_does_not_leak_onto_the_floor(quality):
    scene = _scene()
    result = pipeline.bake(scene, preset(quality, photons=40_000, default_resolution=RES, threads=1))
    floor = result.lightmaps["Floor"][..., :3]
    assert result.photons is not None and len(result.photons) > 10_000  # the box's inside is lit
    assert float(result.cache.E.max()) > 1.0
    assert float(floor.max()) == 0.0  # under the box and around it: no light reaches the floor


def test_without_record_visibility_the_box_leaks_onto_the_floor():
    """The switch is what stops the leak: off, the records inside the box light the floor (Preview)."""
    off = Deviations(record_visibility=False)
    leaky = pipeline.bake(_scene(), preset("PREVIEW", photons=40_000, default_resolution=RES, threads=1,
                                           deviations=off))
    assert float(leaky.lightmaps["Floor"][..., :3].max()) > 1.0


@pytest.mark.parametrize("visibility", [True, False])
def test_the_last_resort_fallback_takes_no_record_from_a_walls_other_side(visibility):
    """A wall face turned into a closed void (the cathedral's: E/pi 0.28 where Cycles and a path tracer
    find 0) has lit records on the same plane, facing the other way: coplanar, so no visibility ray
    parts them. The fallback skips them for the nearest record facing the sample's side, or gives 0."""
    from pdic.core.hole_records import nearest_record
    from pdic.core.irradiance_cache import IrradianceCache
    from pdic.core.rays import RayCaster

    wall = quad([-2, 0, 0], [4, 0, 0], [0, 0, 4])  # the plane y = 0
    caster = RayCaster(wall) if visibility else None
    p = np.array([[0.1, 0.0, 1.0], [1.5, 0.0, 1.0], [1.9, 0.0, 1.0]])  # lit side, lit side, the void's side
    n = np.array([[0.0, 1, 0], [0.0, 1, 0], [0.0, -1, 0]])
    m = len(p)
    records = IrradianceCache(p=p, n=n, E=np.array([[5.0] * 3, [6.0] * 3, [0.5] * 3]), R=np.full(m, 0.1),
                              grad_r=np.zeros((m, 3, 3)), grad_t=np.zeros((m, 3, 3)),
                              photons_used=np.zeros(m, np.int32), hole=np.zeros(m, bool), refined=np.zeros(m, bool))
    samples = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.4, 0.0, 1.0]])
    facing = np.array([[0.0, -1, 0], [0.0, 1, 0], [0.0, -1, 0]])
    E = nearest_record(records, samples, facing, caster)
    np.testing.assert_allclose(E[:, 0], [0.5, 5.0, 0.5])  # not 5 and 6: those records face the lit side
    lone = records.take(slice(0, 2))
    np.testing.assert_allclose(nearest_record(lone, samples[:1], facing[:1], caster), 0.0)
