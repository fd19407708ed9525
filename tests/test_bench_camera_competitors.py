"""The camera comparison's light-map lookup (bench/camera_competitors.py): pixels read the map at
the light-map UV of the point they see, front faces only. No Cycles."""
from __future__ import annotations

import numpy as np

from pdic.bench import camera_competitors, competitors
from pdic.core.camera_render import Camera
from pdic.core.rays import RayCaster

from scenes import quad, quad_scene

W = H = 64
SIDE = 16


def _floor():
    """A 2 m floor facing up, its light map a ramp in u: texel (r, c) holds (c + 0.5) / SIDE in red."""
    scene = quad_scene([quad([0, 0, 0], [2, 0, 0], [0, 2, 0])], {"floor": (0, SIDE)}, [])
    ramp = np.zeros((SIDE, SIDE, 4), np.float32)
    ramp[..., 0] = (np.arange(SIDE) + 0.5) / SIDE
    return scene, ramp


def test_pixels_read_the_map_at_the_uv_of_the_point_they_see():
    scene, ramp = _floor()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    above = Camera(np.array([0.0, 0.0, 1.5]), np.eye(3), 0.5, 0.5)  # looks down -z at the floor's middle
    uv, pixel = camera_competitors.lightmap_view(scene, caster, above, W, H)
    assert len(pixel) == W * H  # the floor fills the view
    image = camera_competitors.seen(ramp, (uv, pixel), (H, W))
    origins, directions = above.rays(W, H)
    x = origins[:, 0] + directions[:, 0] * (-origins[:, 2] / directions[:, 2])  # scene-local hit on z = 0
    u = (x + 1.0) / 2.0  # the floor spans x in [-1, 1] once recentred
    inside = (u > 0.5 / SIDE) & (u < 1 - 0.5 / SIDE)  # a linear ramp is read exactly between texel centres
    assert inside.sum() > 0.9 * W * H
    assert np.abs(image[..., 0].ravel()[inside] - u[inside]).max() < 1e-4
    assert np.all(image[..., 1:] == 0.0)


def test_back_faces_are_left_out():
    scene, ramp = _floor()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    flip = np.diag([1.0, -1.0, -1.0])  # looks up +z: it sees the floor's back
    below = Camera(np.array([0.0, 0.0, -1.5]), flip, 0.5, 0.5)
    uv, pixel = camera_competitors.lightmap_view(scene, caster, below, W, H)
    assert len(pixel) == 0
    assert np.all(camera_competitors.seen(ramp, (uv, pixel), (H, W)) == 0.0)


def test_errors_on_4x4_blocks_are_noise_corrected():
    """A 4 % bright image against a noisy reference pair: 4 % per pixel and on the camera's 4x4 blocks."""
    rng = np.random.default_rng(2)
    truth = np.full((32, 48, 3), 0.5, np.float32) * (1 + 0.2 * np.sin(np.arange(48) / 5.0))[None, :, None]
    pair = tuple(truth * (1 + 0.2 * rng.standard_normal(truth.shape)).astype(np.float32) for _ in range(2))
    mask = np.ones(truth.shape[:2], bool)
    err = competitors.errors(truth * 1.04, pair, mask, block=camera_competitors.BLOCK)
    expected = np.sqrt(np.mean((0.04 * truth) ** 2)) / truth.mean()
    assert abs(err["texel"] - expected) < 0.25 * expected
    assert abs(err["block"] - expected) < 0.25 * expected
    assert abs(err["mean_ratio"] - 1.04) < 0.01
