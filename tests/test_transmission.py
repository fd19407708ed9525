"""Transmissive triangles (Geometry.transmission): shadow rays and photons pass them as Cycles' transparent shadows.

Core only (no bpy): a 2 m sheet between a light and a floor, with closed-form answers.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.photons import trace_photons
from pdic.core.rays import TRANSPARENT_MAX_LAYERS, RayCaster
from pdic.core.scene import Geometry, Materials, SceneError, SunLight, Scene

from scenes import geometry, quad


def _floor_and_sheet(tau: float, layers: int = 1) -> np.ndarray:
    """Floor (10 m at z=0) and ``layers`` 2 m sheets at z = 1, 1.1, ...; returns (triangles, transmission)."""
    tris = [quad([-5, -5, 0], [10, 0, 0], [0, 10, 0])]
    tris += [quad([-1, -1, 1 + 0.1 * k], [2, 0, 0], [0, 2, 0]) for k in range(layers)]
    tris = np.concatenate(tris)
    transmission = np.r_[np.zeros(2), np.full(2 * layers, tau)].astype(np.float32)
    return tris, transmission


def _shadow_rays(n: int = 4000, seed: int = 0):
    """n rays from floor points under the sheet toward a point 3 m up (different directions)."""
    rng = np.random.default_rng(seed)
    points = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), np.zeros(n)]
    light = np.array([0.0, 0.0, 3.0]) + np.c_[rng.uniform(-0.2, 0.2, (n, 2)), np.zeros(n)]
    return points, np.tile([0.0, 0.0, 1.0], (n, 1)), light


@pytest.mark.parametrize("tau, visible", [(0.0, 0.0), (1.0, 1.0), (0.5, 0.5), (0.25, 0.25)])
def test_shadow_rays_pass_a_sheet_with_its_transmission_probability(tau, visible):
    tris, transmission = _floor_and_sheet(tau)
    caster = RayCaster(tris, transmission=transmission)
    points, normals, light = _shadow_rays()
    fraction = caster.visible_between(points, normals, light).mean()
    assert fraction == pytest.approx(visible, abs=0.03)


def test_layers_multiply_and_stop_at_the_transparent_limit():
    tris, transmission = _floor_and_sheet(0.5, layers=2)
    caster = RayCaster(tris, transmission=transmission)
    points, normals, light = _shadow_rays()
    assert caster.visible_between(points, normals, light).mean() == pytest.approx(0.25, abs=0.03)
    tris, transmission = _floor_and_sheet(1.0, layers=TRANSPARENT_MAX_LAYERS + 1)
    blocked = RayCaster(tris, transmission=transmission).visible_between(points, normals, light)
    assert not blocked.any()  # one layer more than Cycles' transparent bounce limit: opaque


def test_transparent_answers_do_not_depend_on_threads_or_batches():
    from pdic.core.executor import Executor

    tris, transmission = _floor_and_sheet(0.5)
    points, normals, light = _shadow_rays(n=70_000)
    serial = RayCaster(tris, transmission=transmission).visible_between(points, normals, light)
    threaded = RayCaster(tris, transmission=transmission, executor=Executor(2)).visible_between(points, normals, light)
    half = RayCaster(tris, transmission=transmission).visible_between(points[:35_000], normals[:35_000], light[:35_000])
    assert np.array_equal(serial, threaded) and np.array_equal(serial[:35_000], half)


def test_transmission_outside_zero_one_is_refused():
    tris, transmission = _floor_and_sheet(0.5)
    g = geometry(tris)
    with pytest.raises(SceneError, match="transmission"):
        Geometry(g.positions, g.normals, g.uvs, g.material, g.target, transmission=transmission + 0.6)


def _sun_scene(tau: float) -> Scene:
    tris, transmission = _floor_and_sheet(tau)
    g = geometry(tris)
    g = Geometry(g.positions, g.normals, g.uvs, g.material, g.target, transmission=transmission)
    mats = Materials(("grey",), np.full((1, 3), 0.0), np.array([-1]), np.zeros((1, 3)))
    return Scene(g, mats, lights=(SunLight("sun", np.array([0, 0, 1.0]), np.array([2.0, 2, 2])),))


@pytest.mark.parametrize("tau", [0.0, 0.5, 1.0])
def test_photons_reach_the_floor_under_a_sheet_in_proportion_to_its_transmission(tau):
    scene = _sun_scene(tau)
    caster = RayCaster(scene.geometry.positions, transmission=scene.geometry.transmission)
    pm, _ = trace_photons(scene, caster, 100_000, 2, seed=4)
    floor = pm.triangle < 2
    under = floor & (np.abs(pm.p[:, 0]) < 0.8) & (np.abs(pm.p[:, 1]) < 0.8)
    E = pm.power[under, 0].sum() / 1.6 ** 2
    assert E == pytest.approx(2.0 * tau, abs=0.1)
    assert np.all(pm.bounce[under] == 0)  # passing a layer is no bounce
    if tau > 0:  # d_prev spans the layer: back to the emission plane, as beside the sheet
        np.testing.assert_allclose(pm.d_prev[under].min(), pm.d_prev[floor & ~under].min(), rtol=1e-5)
    sheet = pm.triangle >= 2
    assert sheet.sum() > 0 and np.all(pm.bounce[sheet] == 0)  # the sheet still receives its photons
