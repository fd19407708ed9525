"""Gathering hits draw one lamp among many (deviation: light-selection, core/light_selection.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.constants import SELECTION_LAMPS
from pdic.core.direct import direct_irradiance
from pdic.core.light_selection import gathering_direct, lamp_probabilities, selectable_lamps
from pdic.core.lights import AreaLight, PointLight, SpotLight
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import Deviations, preset

from scenes import box_faces, lit, quad, quad_scene

X, Y, Z = np.eye(3)


def _lamps(count: int, radius: float = 0.0, area: bool = False) -> list:
    """``count`` lamps of 1 to 3 W scattered 0.3-2.5 m over the floor of :func:`_room`, every fourth a spot
    aimed down; with ``radius``, every other one a sphere light; with ``area``, every third a 0.4 x 0.3 m
    area light facing down."""
    rng = np.random.default_rng(7)
    out = []
    for i in range(count):
        position = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0.3, 2.5)])
        power = np.full(3, 1.0 + 2.0 * rng.random()) * [1.0, 0.8, 0.6]
        if area and i % 3 == 2:
            out.append(AreaLight(f"area{i}", position, -Z, X, Y, 0.4, 0.3, "RECTANGLE", power / (np.pi * 0.12)))
        elif i % 4 == 3:
            out.append(SpotLight(f"spot{i}", position, -Z, power, np.radians(40.0), 0.2))
        else:
            out.append(PointLight(f"lamp{i}", position, power, radius if i % 2 else 0.0))
    return out


def _room(lamps: list):
    """A 6 x 6 m floor with a 2 m wall across it (so some lamps are hidden from some points), lit by
    ``lamps``; scene-local, unrecentred."""
    tris = np.concatenate([quad([-3, -3, 0], 6 * X, 6 * Y), quad([-3, 0.5, 0], 2 * Z, 6 * X),
                           quad([-3, 0.5, 0], 6 * X, 2 * Z)])
    return lit(tris, *lamps)


def _floor_points(m: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.uniform(-2.8, 2.8, m), rng.uniform(-2.8, 2.8, m), np.zeros(m)])
    return p, np.tile(Z, (m, 1))


def test_below_the_lamp_count_every_lamp_keeps_its_ray_to_the_bit():
    scene = _room(_lamps(SELECTION_LAMPS - 1, radius=0.1))
    assert selectable_lamps(scene)[0] == ()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    p, n = _floor_points(500)
    drawn = gathering_direct(scene, caster, p, n, np.random.default_rng(1), True)
    every = direct_irradiance(scene, caster, p, n, n, 1, np.random.default_rng(1))
    assert np.array_equal(drawn.E, every.E)
    assert drawn.shadow_rays == every.shadow_rays


def test_probabilities_sum_to_one_and_vanish_where_no_lamp_can_light():
    lamps = tuple(_lamps(SELECTION_LAMPS))
    p, n = _floor_points(300)
    pdf = lamp_probabilities(lamps, p, n)
    assert pdf.shape == (len(lamps), 300) and (pdf >= 0).all()
    np.testing.assert_allclose(pdf.sum(axis=0), 1.0, rtol=1e-12)
    assert (lamp_probabilities(lamps, p, -n) == 0).all()  # facing the ground: no hard lamp lights it
    soft = tuple(_lamps(SELECTION_LAMPS, radius=0.2))
    below = lamp_probabilities(soft, p, -n)  # a sphere light may light what its centre cannot: it keeps a share
    radius = np.array([float(lamp.radius) > 0 for lamp in soft])
    assert (below[radius] > 0).all() and (below[~radius] == 0).all()


@pytest.mark.parametrize("radius, area", [(0.0, False), (0.15, False), (0.0, True)])
def test_the_drawn_lamp_over_its_probability_is_every_lamps_light_on_average(radius, area):
    """Many draws at each point average to every lamp's light (hard lamps exact; sphere and area lights
    sampled alike)."""
    scene = _room(_lamps(2 * SELECTION_LAMPS, radius, area))
    lamps, others = selectable_lamps(scene)
    assert len(lamps) == 2 * SELECTION_LAMPS and others == ()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    p, n = _floor_points(40)
    draws = 3000
    P, N = np.repeat(p, draws, axis=0), np.repeat(n, draws, axis=0)
    drawn = gathering_direct(scene, caster, P, N, np.random.default_rng(2), True)
    assert sum(drawn.shadow_rays.values()) <= len(P)  # one ray a point, none where nothing lights it
    mean = drawn.E.reshape(40, draws, 3).mean(axis=1)
    exact = direct_irradiance(scene, caster, P, N, N, 1, np.random.default_rng(5)).E.reshape(40, draws, 3).mean(1)
    assert np.isfinite(mean).all()
    lum = np.array([0.2126, 0.7152, 0.0722])
    np.testing.assert_allclose(mean @ lum, exact @ lum, rtol=0.06, atol=0.02 * float((exact @ lum).mean()))
    assert abs(mean.sum() / exact.sum() - 1.0) < 0.01


def test_a_bake_with_many_lamps_draws_and_matches_every_lamps_bake_within_its_noise():
    lamps = [PointLight(f"lamp{i}", np.array([0.15 + 0.7 * (i % 4) / 3, 0.15 + 0.7 * (i // 4 % 4) / 3, 0.8]),
                        np.full(3, 100.0 / SELECTION_LAMPS)) for i in range(SELECTION_LAMPS)]
    scene = quad_scene(box_faces(), {"floor": (0, 16), "back": (1, 16)}, lamps)
    settings = preset("FINAL", photons=20_000, threads=1, hemisphere_theta=6, hemisphere_phi=12, direct=False)
    drawn = bake(scene, settings)
    every = bake(scene, replace(settings, deviations=Deviations(light_selection=False)))
    counters = [r.stats["counters"] for r in (drawn, every)]
    shadow = [c["refine_shadow_rays"] + c["holes_refine_shadow_rays"] for c in counters]
    assert shadow[0] * 4 < shadow[1]  # one ray among 16 lamps, not 16 (the records' visibility rays besides)
    for name in drawn.lightmaps:
        a, b = drawn.lightmaps[name][..., :3], every.lightmaps[name][..., :3]
        assert np.isfinite(a).all()
        assert abs(a.mean() / b.mean() - 1.0) < 0.02, name
        assert np.sqrt(np.mean((a - b) ** 2)) / b.mean() < 0.05, name
