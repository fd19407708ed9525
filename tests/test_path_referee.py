"""bench/path_referee.py, the third opinion between PDIC and Cycles, against an exact balance."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.bench import path_referee
from pdic.core.lights import PointLight
from pdic.core.rays import RayCaster
from scenes import box_faces, quad_scene


def test_path_traced_indirect_light_of_a_closed_box_balances_the_lamp_power():
    """Inside a closed box every reflected watt lands on a wall again, so the indirect flux onto
    the walls is rho / (1 - rho) times the lamp's P: the walls' area-mean indirect E / pi is
    rho / (1 - rho) P / (pi A) whatever the lamp's place. A bounce lost, or a path that stopped
    early without its Russian roulette weight, breaks it by rho^k."""
    rho, power = 0.6, 30.0
    scene = quad_scene(box_faces(), {}, (PointLight("lamp", np.array([0.3, 0.6, 0.7]), np.full(3, power)),),
                       albedo=rho)
    rng = np.random.default_rng(3)
    faces = rng.integers(0, 12, 3000)  # two equal triangles per unit face: uniform over the area
    tri = scene.geometry.positions[faces]
    s, t = rng.random((2, len(faces)))
    fold = s + t > 1
    s[fold], t[fold] = 1 - s[fold], 1 - t[fold]
    p = tri[:, 0] + s[:, None] * (tri[:, 1] - tri[:, 0]) + t[:, None] * (tri[:, 2] - tri[:, 0])
    n = scene.geometry.face_normals()[faces]
    mean, _ = path_referee.mean_indirect(scene, RayCaster(scene.geometry.positions), p, n, 40, rng)
    expected = rho / (1 - rho) * power / (np.pi * 6.0)
    assert mean.mean() == pytest.approx(expected, rel=0.03)
    assert np.allclose(mean.mean(axis=0), mean.mean(), rtol=1e-6)  # grey in, grey out
