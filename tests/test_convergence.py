"""No darkening: indirect light converges at the default settings (Russian roulette, no biting bounce cap)."""
import numpy as np
import pytest

from pdic.core.pipeline import bake
from pdic.core.settings import preset

from scenes import box_faces, quad_scene


def _glowing_box(albedo: float, radiance: float):
    """The inside of the unit box, every wall emitting ``radiance`` and reflecting ``albedo``; the floor baked."""
    faces = box_faces()
    return quad_scene(faces, {"floor": (0, 8)}, (), albedo=albedo, emission=np.full((1, 3), radiance))


@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_white_furnace_box_indirect_light_converges_at_defaults(quality):
    # Radiosity B = L + rho B in a closed box of uniform emitters: indirect E / pi = L rho / (1 - rho).
    # A cap of 6 bounces would give (1 - rho^6) of it: 26 % dark at rho 0.8.
    rho, L = 0.8, 1.0
    result = bake(_glowing_box(rho, L), preset(quality, direct=False))
    indirect = result.indirect["floor"][result.centre_inside["floor"]]
    assert np.all(np.isfinite(indirect))
    assert indirect.mean() == pytest.approx(L * rho / (1 - rho), rel=0.02)
