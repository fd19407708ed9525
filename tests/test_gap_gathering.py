"""Gathering hits in a gap before their record's surface (deviation: gap-gathering, docs/DEVIATIONS.md).

A plate 1 cm before the unit box's back wall, lit on its back by the lamp: its front, the bake
target, faces the wall. Its records gather mostly from the wall patch right behind them, and the
records around that patch, out on the open wall, do not see the plate covering it. A gathering
hit that faces its record from nearby gathers its own indirect light instead, by a walk that
bounces between the plate and the wall until it leaves the gap (records inside the gap spread the
light of its mouth, 10x the centre's, over their zones). At 4x4 texels over the 30 x 40 cm plate
(R_min 17 cm, wider than the plate's light varies) the front's mean is 1.45x a path tracer's with
the deviation (1.36x with gradients limited to half of E_k across a zone, 1.50x to a fifth) and
about 2.1x without (one ray per gap hit and near hits only, before session 23: 1.6x);
at 16x16 1.21x and 1.51x. The records on the plate match the path tracer at their own positions
(the darkest, mid-plate: 0.12 against 0.12, 0.15 against 0.21 E/pi); what is left is the 4x4
texels' interpolation of a light that falls tenfold from the plate's edges to its middle.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.bench import path_referee
from pdic.core.lights import PointLight
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import Deviations, preset

from scenes import BOX_LAMP, box_faces, closed_box, quad, quad_points, quad_scene

GAP = 0.01
CORNER, EDGE_U, EDGE_V = np.array([0.35, 1 - GAP, 0.3]), np.array([0.0, 0.0, 0.4]), np.array([0.3, 0.0, 0.0])


def _scene():
    plate = quad(CORNER, EDGE_U, EDGE_V)  # its front faces +y, the back wall at y = 1
    return quad_scene(box_faces() + [plate], {"plate": (6, 4)}, [BOX_LAMP])


@pytest.fixture(scope="module")
def referee():
    """The path tracer's mean indirect E / pi over the plate's front (16 x 16 points, 400 paths each)."""
    scene = _scene()
    p = quad_points(CORNER, EDGE_U, EDGE_V, 16) - scene.origin_world
    n = np.tile([0.0, 1.0, 0.0], (len(p), 1))
    mean, _ = path_referee.mean_indirect(scene, RayCaster(scene.geometry.positions), p, n, 400,
                                         np.random.default_rng(1))
    return float(mean.mean())


def _plate(gap_gathering: bool):
    # The plate's texel samples stand in a crevice, where they would gather records of their own
    # (crevice-records, tests/test_crevice_records.py): off, they read the cache whose records the gap shades.
    settings = preset("FINAL", photons=100_000, threads=1,
                      deviations=Deviations(gap_gathering=gap_gathering, crevice_records=False))
    result = bake(_scene(), settings)
    return float(result.indirect["plate"][result.centre_inside["plate"]].mean()), result.stats["counters"]


def test_hits_in_the_gap_gather_their_own_light_and_the_plate_darkens_toward_the_path_tracer(referee):
    on, counters = _plate(True)
    off, counters_off = _plate(False)
    assert counters["refine_gap_hits"] > 1000 and counters_off["refine_gap_hits"] == 0
    assert np.isfinite(on) and on > 0
    assert off / referee > 1.9  # the open wall's records lit the patch behind the plate
    assert on / referee < 1.5  # 1.6 with one ray per gap hit
    assert on < 0.85 * off


# A ledge 20 cm deep and 3 m wide on the back wall of a 10 m room, 6 m up, lit by a lamp 1 m above the
# floor: the ledge shades the wall above it, and the wall's indirect light falls toward the corner over
# tens of centimetres, under pass 2's records and photons, which stay flat there (the cathedral's
# mouldings: the records on their tops gathered 1.3-1.5x a path tracer's).
ROOM, LEDGE_LO, LEDGE_HI = 10.0, np.array([3.5, 9.8, 5.95]), np.array([6.5, 10.0, 6.0])


def _ledge_scene():
    room = [ROOM * face for face in box_faces()]
    lamp = PointLight("lamp", np.array([5.0, 5.0, 1.0]), np.full(3, 100.0))
    return quad_scene(room + closed_box(LEDGE_LO, LEDGE_HI), {"top": (len(room) + 1, 4)}, [lamp])


def test_hits_at_the_foot_of_the_wall_above_a_ledge_walk_and_the_ledge_top_matches_the_path_tracer():
    scene = _ledge_scene()
    size = LEDGE_HI - LEDGE_LO
    p = quad_points(LEDGE_LO + [0.0, 0.0, size[2]], [size[0], 0.0, 0.0], [0.0, size[1], 0.0], 16) - scene.origin_world
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    mean, _ = path_referee.mean_indirect(scene, RayCaster(scene.geometry.positions), p, n, 400,
                                         np.random.default_rng(1))
    referee = float(mean.mean())
    ratios = []
    for seed in (0, 1):
        # Crevice-records off: the ledge's samples nearest the wall would gather records of their own,
        # which hides part of what the cache's records read (with it on: 1.016 / 1.011; 1.048 / 1.046 before).
        settings = preset("FINAL", photons=100_000, threads=2, seed=seed,
                          deviations=Deviations(crevice_records=False))
        result = bake(scene, settings)
        ratios.append(float(result.indirect["top"][result.centre_inside["top"]].mean()) / referee)
    # 1.057 and 1.055 with corner-gathering's walks only within a R_min and a quarter of it high.
    assert abs(np.mean(ratios) - 1) < 0.04, ratios
