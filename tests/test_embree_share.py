"""The stats report how much of each ray-casting stage ran inside Embree (issue 12: passes bound by rays).

No timing asserts: the shares are checked as fractions of the stage's own time, and the clock
as a sum its views share.
"""
import numpy as np
import pytest

from pdic.core.bake_cache import BakeCache
from pdic.core.executor import Executor
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import preset

from scenes import lamp_box

RAY_STAGES = ("direct", "photons", "cache", "refine", "interpolate")
"""Stages that cast rays at Final's defaults (photon_direct only with photon-path reuse)."""


def _box():
    return lamp_box(12)


@pytest.mark.parametrize("threads", [1, 2])
def test_stats_report_embree_share_of_every_ray_casting_stage_between_0_and_1(threads):
    settings = preset("FINAL", photons=4000, max_bounces=3, threads=threads, hemisphere_theta=6, hemisphere_phi=12)
    stats = bake(_box(), settings).stats
    c, seconds = stats["counters"], stats["seconds"]
    for stage in RAY_STAGES:
        share = c[f"embree_share_{stage}"]
        assert 0.0 < share <= 1.0, (stage, share)
        assert 0.0 < c[f"embree_seconds_{stage}"] <= seconds[stage] * threads + 1e-3
    assert "embree_share_rasterise" not in c  # rasterising casts no ray
    assert "embree_share_photon_direct" not in c  # only virtual rays read the photons' direct light


def test_a_bake_that_casts_no_ray_reports_no_embree_time():
    settings = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    store = BakeCache()
    bake(_box(), settings, cache=store)
    again = bake(_box(), settings, cache=store).stats["counters"]
    assert again["rays_cast"] == 0
    assert not [key for key in again if key.startswith("embree_")]


def test_serial_views_add_their_embree_time_to_the_casters_clock():
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float64)
    with Executor(2) as pool:
        caster = RayCaster(tris, executor=pool)
        view = caster.serial()
        o = np.tile([0.2, 0.2, 1.0], (100, 1))
        d = np.tile([0.0, 0.0, -1.0], (100, 1))
        assert caster.intersect(o, d).hit.all()
        calls = caster.clock.calls
        assert view.occluded(o, d, 2.0).all()
        assert view.clock is caster.clock and caster.clock.calls == calls + 1
        assert caster.clock.seconds > 0.0
