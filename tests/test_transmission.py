"""Transmissive triangles (Geometry.transmission): shadow rays and photons pass them as Cycles' transparent shadows.

Core only (no bpy): a 2 m sheet between a light and a floor, with closed-form answers.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.photons import trace_photons
from pdic.core.pipeline import bake
from pdic.core.constants import TRANSPARENT_MAX_LAYERS
from pdic.core.rays import RayCaster
from pdic.core.scene import Geometry, Materials, SceneError, SunLight, Scene
from pdic.core.settings import Deviations, preset

from scenes import geometry, plane_target, quad


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


@pytest.mark.parametrize("tau", [0.0, 0.25, 0.5, 1.0])
def test_shadow_rays_through_a_sheet_carry_its_transmission(tau):
    tris, transmission = _floor_and_sheet(tau)
    caster = RayCaster(tris, transmission=transmission)
    points, normals, light = _shadow_rays()
    np.testing.assert_allclose(caster.transmittance_between(points, normals, light), tau)
    assert np.array_equal(caster.visible_between(points, normals, light), np.full(len(points), tau >= 0.5))
    up = light - points  # rays to infinity: the same sheet
    np.testing.assert_allclose(caster.transmittance(points, up, np.inf, normals), tau)


def test_layers_multiply_and_stop_at_the_transparent_limit():
    points, normals, light = _shadow_rays()
    tris, transmission = _floor_and_sheet(0.5, layers=2)
    caster = RayCaster(tris, transmission=transmission)
    np.testing.assert_allclose(caster.transmittance_between(points, normals, light), 0.25)
    tris, transmission = _floor_and_sheet(1.0, layers=TRANSPARENT_MAX_LAYERS)
    passes = RayCaster(tris, transmission=transmission).transmittance_between(points, normals, light)
    np.testing.assert_allclose(passes, 1.0)
    tris, transmission = _floor_and_sheet(1.0, layers=TRANSPARENT_MAX_LAYERS + 1)
    blocked = RayCaster(tris, transmission=transmission).transmittance_between(points, normals, light)
    np.testing.assert_allclose(blocked, 0.0)  # one layer more than Cycles' transparent bounce limit: opaque


def test_a_target_beyond_reach_of_the_sheet_is_not_dimmed_by_it():
    tris, transmission = _floor_and_sheet(0.5)
    caster = RayCaster(tris, transmission=transmission)
    points, normals, light = _shadow_rays()
    below = light.copy()
    below[:, 2] = 0.9  # the target sits under the sheet
    np.testing.assert_allclose(caster.transmittance_between(points, normals, below), 1.0)


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


def _sheet_over_a_floor_target(tau: float) -> Scene:
    """_sun_scene with the floor as a 16^2 bake target, lit by the sun straight down (irradiance 2)."""
    scene = _sun_scene(tau)
    return replace(scene, targets=(plane_target("Floor", 0, 16),))


@pytest.mark.parametrize("switch, expected", [(True, 2.0 / np.pi), (False, 0.0)])
def test_transparent_shadows_switch_decides_whether_a_clear_sheet_shadows_the_floor(switch, expected):
    settings = preset("PREVIEW", indirect=False, threads=1, deviations=Deviations(transparent_shadows=switch))
    floor = bake(_sheet_over_a_floor_target(1.0), settings).direct["Floor"]
    under = floor[7:9, 7:9]  # texels at the floor's centre, under the 2 m sheet
    np.testing.assert_allclose(under, expected, atol=1e-6)


def _room_lit_through_a_pane(tau: float | None) -> Scene:
    """A closed unit box with a 0.2 m window in its front wall; outside, a lamp behind a shield lights a
    2 m reflector facing the window, so the box's floor gets only indirect light, all of it through the
    window. tau: a black pane (albedo 0) in the window passing tau of the light; None: no pane."""
    from scenes import quad_scene
    from pdic.core.scene import PointLight

    X, Y, Z = np.eye(3)
    faces = [quad(np.zeros(3), X, Y), quad(Y, X, Z), quad(Z, Y, X), quad(np.zeros(3), Y, Z), quad(X, Z, Y),
             quad(np.zeros(3), 0.4 * Z, X), quad(0.6 * Z, 0.4 * Z, X),
             quad(0.4 * Z, 0.2 * Z, 0.4 * X), quad(0.6 * X + 0.4 * Z, 0.2 * Z, 0.4 * X),
             quad(np.array([-0.5, -1.0, -0.5]), 2 * Z, 2 * X), quad(np.array([0.2, -0.8, 0.2]), 0.6 * X, 0.6 * Z)]
    if tau is not None:
        faces.append(quad(0.4 * X + 0.4 * Z, 0.2 * Z, 0.2 * X))
    material = np.zeros(2 * len(faces), np.int32)
    if tau is not None:
        material[-2:] = 1
    lamp = PointLight("lamp", np.array([0.5, -0.85, 0.5]), np.full(3, 50.0))
    scene = quad_scene(faces, {"floor": (0, 32)}, [lamp], materials=material)
    if tau is None:
        return scene
    base = np.array([[0.7] * 3, [0.0] * 3], np.float32)
    transmission = np.zeros(scene.geometry.count, np.float32)
    transmission[-2:] = tau
    return replace(scene, materials=replace(scene.materials, base_color=base),
                   geometry=replace(scene.geometry, transmission=transmission))


def test_final_gathering_sees_through_glass():
    """Pass 3's gathering rays pass a transmissive layer as shadow rays and photons do: what lies past
    the pane adds tau of its radiance. A fully clear pane is then no pane (before, the rays stopped at it
    and read its black surface: the floor's indirect light 24 % dark), and a pane passing 0.6 passes 0.6
    of the light that came in through the window (measured 0.60)."""
    final = preset("FINAL", threads=2)
    indirect = {}
    for tau in (None, 1.0, 0.6):
        result = bake(_room_lit_through_a_pane(tau), final)
        mask = result.centre_inside["floor"]
        assert result.direct["floor"][mask].max() == 0.0  # the shield keeps the lamp out
        indirect[tau] = result.indirect["floor"][mask].mean()
    assert indirect[None] > 0
    assert abs(indirect[1.0] / indirect[None] - 1.0) < 0.06
    assert abs(indirect[0.6] / indirect[1.0] - 0.6) < 0.05
