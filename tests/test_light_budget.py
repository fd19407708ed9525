"""Soft lamps share one budget of shadow rays per point (deviation: light-budget, core/light_budget.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.constants import BUDGET_LAMPS, BUDGET_SCALE
from pdic.core.direct import direct_irradiance
from pdic.core.lamp_weights import lamp_probabilities, soft_lamp
from pdic.core.light_budget import budgeted_lamps, group_draws, sample_counts
from pdic.core.lights import AreaLight, PointLight
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import Deviations, preset

from scenes import box_faces, quad_scene
from test_light_selection import _floor_points, _lamps, _room

X, Y, Z = np.eye(3)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def test_below_the_lamp_count_the_budget_changes_nothing_to_the_bit():
    """One soft lamp among hard ones and spots: every lamp keeps its samples, the maps their bits."""
    lamps = [lamp for lamp in _lamps(8, radius=0.1) if not (isinstance(lamp, PointLight) and lamp.radius > 0)]
    lamps.append(PointLight("sphere", np.array([0.5, -1.0, 1.5]), np.full(3, 2.0), 0.2))
    scene = _room(lamps)
    assert BUDGET_LAMPS > 1 and budgeted_lamps(scene.emitters(), 16)[0] == ()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    p, n = _floor_points(400)
    run = [direct_irradiance(scene, caster, p, n, n, 16, np.random.default_rng(1), np.random.default_rng(2),
                             budget=budget) for budget in (False, True)]
    for field in ("E", "edge_lit", "edge_open"):
        assert np.array_equal(getattr(run[0], field), getattr(run[1], field)), field
    assert run[0].shadow_rays == run[1].shadow_rays and run[0].skipped == run[1].skipped


def test_one_sample_per_point_shares_nothing():
    scene = _room(_lamps(8, area=True))
    assert budgeted_lamps(scene.emitters(), 1) == ((), tuple(scene.emitters()))


def test_counts_are_powers_of_two_up_to_the_samples_at_least_one_and_follow_the_shares():
    lamps = tuple(_lamps(24, radius=0.1, area=True))
    soft, _ = budgeted_lamps(lamps, 16)
    assert len(soft) >= BUDGET_LAMPS
    p, n = _floor_points(300)
    counts = sample_counts(soft, p, n, 16)
    assert counts.shape == (len(soft), 300)
    assert set(np.unique(counts)) <= {1, 2, 4, 8, 16} and counts.min() == 1
    # each lamp gets its share of the budget rounded up to a power of two (at most double), and in all far
    # fewer rays than every lamp's 16
    share = np.minimum(BUDGET_SCALE * 16 * lamp_probabilities(soft, p, n), 16)
    assert (counts >= share - 1e-9).all() and (counts < 2 * share + 1).all()
    assert counts.sum() < 0.5 * 16 * counts.size
    near = PointLight("over", np.array([0.0, 0.0, 0.3]), np.full(3, 5.0), 0.05)  # right over the point
    dim = tuple(PointLight(f"far{i}", np.array([40.0, i, 2.0]), np.full(3, 1.0), 0.05) for i in range(9))
    for samples in (16, 12):  # the lamp over the point keeps every sample it would take alone; far ones, one
        assert sample_counts((near, *dim), np.zeros((1, 3)), Z[None], samples)[:, 0].tolist() == [samples] + [1] * 9


@pytest.mark.parametrize("radius, area", [(0.15, False), (0.1, True)])
def test_shared_rays_average_to_every_lamps_light_with_fewer_rays(radius, area):
    """Sphere and area lights behind a wall from some points: 400 estimates at each of 60 points average to the
    every-lamp estimate's mean, per point within 3 % and over all within 0.5 %, for under 3/4 of the rays."""
    scene = _room(_lamps(24, radius, area))
    lamps, _ = budgeted_lamps(scene.emitters(), 16)
    assert len(lamps) >= 6
    caster = RayCaster(scene.geometry.positions, scene.extent)
    p, n = _floor_points(60)
    runs = 400
    P, N = np.repeat(p, runs, axis=0), np.repeat(n, runs, axis=0)
    shared = direct_irradiance(scene, caster, P, N, N, 16, np.random.default_rng(3), budget=True)
    every = direct_irradiance(scene, caster, P, N, N, 16, np.random.default_rng(4))
    assert np.isfinite(shared.E).all()
    assert 4 * sum(shared.shadow_rays.values()) < 3 * sum(every.shadow_rays.values())
    assert shared.skipped.keys() == every.skipped.keys()
    a, b = (r.E.reshape(60, runs, 3).mean(axis=1) @ LUMINANCE for r in (shared, every))
    lit = b > 0.02 * b.max()
    np.testing.assert_allclose(a[lit], b[lit], rtol=0.03)
    assert abs(a.sum() / b.sum() - 1.0) < 0.005


def test_a_bake_with_many_area_lights_shares_their_rays_and_matches_every_lamps_bake():
    lamps = [AreaLight(f"panel{i}", np.array([0.14 + 0.24 * (i % 4), 0.14 + 0.24 * (i // 4), 0.95]), -Z, X, Y, 0.1,
                       0.1, "SQUARE", np.full(3, 6.0 / (np.pi * 0.01))) for i in range(16)]
    scene = quad_scene(box_faces(), {"floor": (0, 16), "back": (1, 16)}, lamps)
    settings = preset("PREVIEW", photons=20_000, threads=1)
    shared = bake(scene, settings)
    every = bake(scene, replace(settings, deviations=Deviations(light_budget=False)))
    rays = [r.stats["counters"]["shadow_rays_area"] for r in (shared, every)]
    assert 2 * rays[0] < rays[1]
    for name in shared.lightmaps:
        a, b = shared.lightmaps[name][..., :3], every.lightmaps[name][..., :3]
        assert np.isfinite(a).all()
        assert abs(a.mean() / b.mean() - 1.0) < 0.01, name
        assert np.sqrt(np.mean((a - b) ** 2)) / b.mean() < 0.03, name


def test_a_groups_draws_are_one_per_stratum_in_a_random_order():
    group = np.repeat([3, 0, 7, 5], [64, 1, 10, 3])
    u = group_draws(group, np.random.default_rng(4))
    assert ((u >= 0) & (u < 1)).all()
    for g in np.unique(group):
        k = int(np.sum(group == g))
        strata = np.floor(u[group == g] * k).astype(int)
        assert sorted(strata.tolist()) == list(range(k))
    assert not np.array_equal(np.floor(u[:64] * 64), np.arange(64))  # handed out in a random order


@pytest.mark.parametrize("radius, area", [(0.15, False), (0.1, True)])
def test_drawn_lamps_at_a_footprints_points_average_to_every_lamps_light(radius, area):
    """One ray per point toward each lamp with a large share and one drawn among the rest, 64 points a group as
    a texel's footprint, among 48-64 soft lamps: 20 groups at each of 40 points average to one ray per lamp at
    every point, within 4 % per point and 0.5 % over all, for under half the rays."""
    scene = _room([lamp for lamp in _lamps(192, radius, area) if soft_lamp(lamp)])
    caster = RayCaster(scene.geometry.positions, scene.extent)
    p, n = _floor_points(40)
    points = 64 * 20
    P, N = np.repeat(p, points, axis=0), np.repeat(n, points, axis=0)
    u = group_draws(np.repeat(np.arange(40 * 20), 64), np.random.default_rng(5))
    drawn = direct_irradiance(scene, caster, P, N, N, 1, np.random.default_rng(6), budget=True, draws=u)
    every = direct_irradiance(scene, caster, P, N, N, 1, np.random.default_rng(7))
    assert np.isfinite(drawn.E).all()
    assert 2 * sum(drawn.shadow_rays.values()) < sum(every.shadow_rays.values())
    a, b = (r.E.reshape(40, points, 3).mean(axis=1) @ LUMINANCE for r in (drawn, every))
    lit = b > 0.02 * b.max()
    np.testing.assert_allclose(a[lit], b[lit], rtol=0.04)
    assert abs(a.sum() / b.sum() - 1.0) < 0.005
