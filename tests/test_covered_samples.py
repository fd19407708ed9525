"""Texel samples under a sheet a fraction of a texel above them count as inside geometry (texel validity).

A floor with a slab resting 1 mm above part of it: no light reaches the gap's floor but past the
slab's edges and no camera sees it, while Ward's weights carry the open floor's records in (Sponza
at 16 texels/m: such texels at 0.15 E/pi where Cycles has 0.007). A corner's other face, which a
lamp may light, does not cover a sample however near it is.
"""
import numpy as np

from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import PointLight
from pdic.core.settings import preset
from pdic.core.validity import inside_geometry

from scenes import quad, quad_scene

COVER = 0.005
"""The cover distance these tests ask for (5 mm)."""


def _face_normals(tris):
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_a_sheet_1_mm_above_covers_the_floor_under_it_and_a_tilted_roof_does_not():
    floor = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])                  # facing +z
    sheet = quad([0.2, -1, 0.001], [0, 2, 0], [0.6, 0, 0])           # facing -z, down at the floor
    tilt = np.tan(np.radians(25))                                    # a roof 25 degrees off the floor's plane
    roof = quad([-0.5, -1, 0.0005], [-1.0, 0, tilt], [0, 2, 0])      # facing down, toward -x
    tris = np.concatenate([floor, sheet, roof])
    caster = RayCaster(tris)
    rng = np.random.default_rng(4)
    m = 600
    y = rng.uniform(-0.8, 0.8, m)
    under_sheet = np.column_stack([rng.uniform(0.3, 0.7, m), y, np.zeros(m)])
    open_floor = np.column_stack([rng.uniform(1.0, 1.8, m), y, np.zeros(m)])
    under_roof = np.column_stack([rng.uniform(-0.5005, -0.5001, m), y, np.zeros(m)])
    n = np.tile([0.0, 0, 1], (m, 1))
    # Under the sheet a ray at more than 78 degrees from the normal travels past 5 mm before it meets
    # the sheet: 4 % of the rays, so about 15 % of the samples stay uncovered.
    for points, low, high in ((under_sheet, 0.75, 0.95), (open_floor, 0.0, 0.0), (under_roof, 0.0, 0.0)):
        inside, covered, _ = inside_geometry(caster, _face_normals(tris), points, n, np.random.default_rng(5),
                                             cover=COVER)
        assert low <= covered.mean() <= high
        assert not inside.any()  # they see front faces: the back-face vote alone lets them be
    # Without a cover distance nothing is covered.
    assert not inside_geometry(caster, _face_normals(tris), under_sheet, n, np.random.default_rng(5))[1].any()


def test_the_floor_under_a_slab_bakes_dark_as_cycles_and_takes_its_neighbours_light_in_the_map():
    lamp = PointLight("lamp", np.array([0.0, 0.0, 1.5]), np.full(3, 200.0))
    floor = quad([-1, -1, 0], [2, 0, 0], [0, 2, 0])
    slab_bottom = quad([0.0, -0.5, 0.001], [0, 1.0, 0], [0.5, 0, 0])   # facing the floor, 1 mm above it
    slab_top = quad([0.0, -0.5, 0.05], [0.5, 0, 0], [0, 1.0, 0])       # facing the lamp
    scene = quad_scene([floor, slab_bottom, slab_top], {"floor": (0, 16)}, [lamp])
    result = bake(scene, preset("FINAL", photons=20_000, threads=1, hemisphere_theta=6, hemisphere_phi=12))
    assert result.stats["counters"]["texel_samples_covered"] > 0
    # Texels wholly under the slab (x in (0, 0.5), y in (-0.5, 0.5) of the 2 m floor, 8 texels per metre).
    rows, cols = np.mgrid[0:16, 0:16]
    cx, cy = (cols + 0.5) / 8 - 1, (rows + 0.5) / 8 - 1
    under = (cx > 0.07) & (cx < 0.43) & (np.abs(cy) < 0.43)  # symmetric in y: image rows may run either way
    assert under.sum() >= 8
    assert result.indirect["floor"][under].max() == 0.0
    assert result.buried["floor"][under].all()
    open_floor = result.coverage["floor"] & ~result.buried["floor"]
    assert result.lightmaps["floor"][under, :3].mean() > 0.1 * result.as_cycles("floor")[open_floor].mean()
