"""A record on the lower tier of a step is not interpolated onto the upper tier it cannot see.

Core only. Ward's test accepts a record behind a texel sample's tangent plane (a curved surface's
own records lie there); on Sponza's column bases a record 2 cm down a step, lit 2.6x brighter than
the upper tier by its corner, was read there (PDIC 3.35 against the path referee's 1.66 and
Cycles' 1.75). Records farther behind the plane than RECORD_STEP_BEHIND a R_k must see the sample.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.constants import RECORD_STEP_BEHIND
from pdic.core.interpolation import CacheLookup
from pdic.core.irradiance_cache import IrradianceCache
from pdic.core.rays import RayCaster

from scenes import quad

A = 0.4
UP = np.array([[0.0, 0.0, 1.0]])


def _cache(p) -> IrradianceCache:
    """One refined record at p facing up, R = 1 (zone 0.4), E = 5 W/m^2 in every channel."""
    return IrradianceCache(p=np.array([p], float), n=UP.copy(), E=np.full((1, 3), 5.0), R=np.ones(1),
                           grad_r=np.zeros((1, 3, 3)), grad_t=np.zeros((1, 3, 3)),
                           photons_used=np.zeros(1, np.int32), hole=np.zeros(1, bool), refined=np.ones(1, bool))


def _step(upper: bool = True) -> RayCaster:
    """A floor z = 0 over x in [1, 2], and (``upper``) an upper tier z = 0.1 over x in [0, 1] with
    the step's riser at x = 1 between them."""
    faces = [quad([1, 0, 0], [1, 0, 0], [0, 1, 0])]
    if upper:
        faces += [quad([0, 0, 0.1], [1, 0, 0], [0, 1, 0]), quad([1, 0, 0], [0, 1, 0], [0, 0, 0.1])]
    return RayCaster(np.concatenate(faces))


def _weight(caster, record, sample) -> float:
    lookup = CacheLookup(_cache(record), A, True, caster=caster)
    return float(lookup.irradiance(np.array([sample], float), UP)[1][0])


def test_a_record_down_a_step_is_hidden_from_the_upper_tier():
    record, sample = (1.05, 0.5, 0.0), (0.95, 0.5, 0.1)  # 0.1 behind the sample's plane, > 0.1 a R
    assert 0.1 > RECORD_STEP_BEHIND * A
    assert _weight(None, record, sample) > 0  # Ward's test alone accepts it
    assert _weight(_step(), record, sample) == 0.0
    # A ray decides, not the distance: with nothing between (the tier and riser gone), it counts.
    assert _weight(_step(upper=False), record, sample) > 0


def test_a_record_slightly_behind_the_plane_casts_no_ray():
    """Within RECORD_STEP_BEHIND a R_k of the plane (a curved surface's own records) no ray decides:
    the record counts even where the riser would block the segment."""
    caster = _step()
    record, sample = (1.05, 0.5, 0.0), (0.95, 0.5, 0.5 * RECORD_STEP_BEHIND * A)
    assert _weight(caster, record, sample) > 0
    assert caster.rays_cast == 0


def test_a_widened_zone_holds_the_gradient_at_its_own_edge():
    """Gap-fill widens zones by a margin; past a record's own zone a R_k its translational gradient
    is not extrapolated: the estimate there is E_k at the zone's edge (on the occluded building a
    riser's texel 63 cm from its only record read 3.77 against the referee's 2.56 before)."""
    cache = _cache((0.0, 0.5, 0.0))
    cache.grad_t = np.zeros((1, 3, 3))
    cache.grad_t[0, :, 0] = 5.0  # +5 W/m^2 per metre along x: 7 W/m^2 at the zone's edge x = 0.4
    caster = _step(upper=False)
    inside = CacheLookup(cache, A, True, caster=caster).irradiance(np.array([[0.3, 0.5, 0.0]]), UP)[0]
    assert inside[0] == pytest.approx(5.0 + 5.0 * 0.3)  # within the zone the gradient applies
    widened = CacheLookup(cache, A, True, caster=caster, margin=0.3)
    E, w = widened.irradiance(np.array([[0.6, 0.5, 0.0]]), UP)
    assert w[0] > 0
    assert E[0] == pytest.approx(np.full(3, 5.0 + 5.0 * A))  # not 5 + 5 x 0.6
