"""Texel samples in crevices gather their own record (deviation: crevice-records, core/crevice_records.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.bench.path_referee import mean_indirect
from pdic.core import texels as texel_stage
from pdic.core.texels import splat
from pdic.core.crevice_records import CREVICE_RAYS, in_crevice, local_distance
from pdic.core.lights import PointLight
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import Deviations, preset
from scenes import box_faces, closed_box, quad, quad_scene

GAP = 0.02
"""The plate's back stands this far before the wall, as the cathedral's window tracery does."""


def _planes(h: float) -> RayCaster:
    """A plane at z = h facing down, 20 000 h wide, over the point (0, 0, 0); rays leave their surface the
    offset of a scene h across, not of the plane's width."""
    w = 1e4 * abs(h)
    return RayCaster(quad([-w, -w, h], [0, 2 * w, 0], [2 * w, 0, 0]), extent=abs(h))


def test_the_local_distance_under_a_plane_is_five_thirds_of_its_height_at_any_scale():
    """One ray along the normal meets a plane h above at h, four 60 degrees off it at 2 h: 5 / (1/h + 4/(2h))
    = 5/3 h, the same pattern at every scale; with nothing above every ray escapes (inf)."""
    p, n = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    for h in (1e-4, 0.01, 0.3, 1e3):
        assert local_distance(_planes(h), p, n)[0] == pytest.approx(5 / 3 * h, rel=1e-4)  # less the ray offset
    assert local_distance(_planes(-1.0), p, n)[0] == np.inf


def test_the_crevice_verdict_from_short_rays_is_the_full_length_verdict():
    """in_crevice casts its rays only CREVICE_RAYS x ``nearer`` far and bounds the rest: inside a closed box
    with a shelf, at random points and thresholds, it gives exactly the verdict of the full-length harmonic
    distance, casting rays again in full where the bounds straddle a threshold."""
    rng = np.random.default_rng(7)
    caster = RayCaster(np.concatenate([*closed_box([0, 0, 0], [2.0, 1.0, 1.5]),
                                       quad([0.2, 0.1, 0.3], [1.2, 0, 0], [0, 0.8, 0])]), extent=2.0)
    m = 4000
    p = rng.uniform([0.0, 0.0, 0.0], [2.0, 1.0, 0.0], (m, 3))  # on the floor, under the shelf 0.3 m up or beside it
    n = np.tile([0.0, 0.0, 1.0], (m, 1))
    H = local_distance(caster, p, n)
    recast = 0
    for nearer in (0.1, 0.35, 0.6, 2.0):
        farther = 0.05 * nearer
        verdict, rays = in_crevice(caster, p, n, nearer, farther)
        np.testing.assert_array_equal(verdict, (H < nearer) & (H >= farther))
        assert 0 < verdict.sum() < m
        recast += rays - CREVICE_RAYS * m
    assert recast > 0


def _plate_before_a_wall():
    """A 2 m room lit by a lamp, and a 40 cm x 1 m plate, 4 cm thick, standing GAP before its back wall: the
    plate's back (facing the wall, 4 x 4 texels) and the wall (8 x 8: 25 cm texels, zones 14 cm) baked."""
    s = 2.0
    room = [face * s for face in box_faces()]  # its back wall (face 1) at y = s
    plate = closed_box([0.8, s - GAP - 0.04, 0.5], [1.2, s - GAP, 1.5])  # its back (+y) is face 6 + 3
    return quad_scene(room + plate, {"wall": (1, 8), "plate_back": (9, 4)},
                      [PointLight("lamp", np.array([1.0, 0.6, 1.6]), np.full(3, 200.0))])


@pytest.fixture(scope="module")
def plate():
    scene = _plate_before_a_wall()
    # thin-coverage off: Algorithm 1 places its hole records over the other samples, which the crevice
    # samples join or leave, so the open wall's records would differ for a reason of their own
    settings = preset("FINAL", photons=300_000, threads=1, deviations=Deviations(thin_coverage=False))
    on = bake(scene, settings)
    off = bake(scene, replace(settings, deviations=replace(settings.deviations, crevice_records=False)))
    # A path tracer at the plate's texel samples (4,000 paths each), as PDIC defines a texel: their mean.
    target = [t.name for t in scene.targets].index("plate_back")
    points, rasters = texel_stage.lift_texels(replace(scene, targets=(scene.targets[target],)), 2)
    E, _ = mean_indirect(scene, RayCaster(scene.geometry.positions), points.p, points.n_shading, 4000,
                         np.random.default_rng(3))
    total = splat(np.ones((len(points), 1)), points, rasters[0])
    return on, off, splat(E, points, rasters[0]) / np.maximum(total, 1e-30)


def _error(result, reference) -> tuple[float, float]:
    P = result.indirect["plate_back"]
    return float(np.sqrt(np.mean((P - reference) ** 2)) / reference.mean()), float(P.mean() / reference.mean())


def test_the_back_of_a_plate_before_a_wall_gathers_its_own_light(plate):
    """Light reaches the 2 cm gap only past the plate's edges: bright rows at its top and bottom, a dark middle
    (a path tracer: 0.13-0.16 E / pi there, about 1 at the edges). Equation 3 over records a zone apart
    carried the mouth's light inward (measured: 90 % off per texel, the mean 67 % bright); the samples' own
    records follow the path tracer within their gathering noise (seeds 0-3: 8-13 %, the mean 0.97-1.05)."""
    on, off, reference = plate
    assert on.stats["counters"]["crevice_samples"] >= 64  # every sample of the plate's back, some of the wall's
    error, ratio = _error(on, reference)
    assert error < 0.2 and abs(ratio - 1) < 0.1
    error_off, ratio_off = _error(off, reference)
    assert error_off > 2 * error and ratio_off > 1.2
    assert off.stats["counters"]["crevice_samples"] == 0


def test_crevice_records_leave_the_open_wall_to_the_cache(plate):
    """Only samples near other surfaces gather: of the wall, the texels behind the plate (x 0.8-1.2 m, z 0.5-1.5 m:
    columns 3-4, rows 2-5); the rest, out to the room's corners, are the same bits either way."""
    on, off, _ = plate
    behind = np.zeros((8, 8), bool)
    behind[2:6, 3:5] = True
    np.testing.assert_array_equal(on.indirect["wall"][~behind], off.indirect["wall"][~behind])
    assert (on.indirect["wall"] != off.indirect["wall"]).any(axis=2)[behind].all()


def test_crevice_records_gathered_beside_the_holes_are_those_gathered_in_line():
    """With two workers the crevice samples' records gather on a thread of their own while the other samples'
    holes are filled (core/hole_records.py): the maps and the rays counted are one worker's, bit for bit."""
    import threading

    from pdic.core.executor import Cancelled, Progress

    scene = _plate_before_a_wall()
    seen = set()

    def watch(stage, fraction, eta):
        if stage.endswith("Interpolating the cache at texels"):
            seen.update(t.name for t in threading.enumerate())

    one = bake(scene, preset("FINAL", photons=100_000, threads=1))
    two = bake(scene, preset("FINAL", photons=100_000, threads=2), Progress(watch))
    assert "pdic-beside" in seen
    for name in one.indirect:
        assert np.array_equal(one.indirect[name], two.indirect[name]), name
    a, b = one.stats["counters"], two.stats["counters"]
    assert a["crevice_samples"] == b["crevice_samples"] >= 64
    assert a["crevice_refine_rays_cast"] == b["crevice_refine_rays_cast"] > 0 and a["rays_cast"] == b["rays_cast"]

    progress = Progress(lambda stage, f, eta: progress.cancel() if "Interpolating" in stage else None)
    with pytest.raises(Cancelled):
        bake(scene, preset("FINAL", photons=100_000, threads=2), progress)
    assert not [t for t in threading.enumerate() if t.name == "pdic-beside"]
