"""Soft lamps share one budget of shadow rays per point (deviation: light-budget).

A soft lamp (an area light, a point or spot light with a radius) takes ``samples`` stratified shadow rays per
point for its soft shadow (``BakeSettings.direct_samples``, 16 at Final), so a room lit by 16 ceiling panels cast
256 rays per texel sample, and 64 lamps of Blender's default radius 1,024, each lamp's light known far better than
its share of the point's light needs. In a scene of BUDGET_LAMPS soft lamps or more, each point spends about
``samples`` rays over them together: a lamp gets the smallest power of two (up to ``samples``) not below
``samples`` times its share of what the lamps would give the point unoccluded
(:func:`~core.lamp_weights.lamp_probabilities`), and at least one. Every lamp a point may see keeps its own
stratified estimate, so E stays unbiased whatever the shares; a lamp giving the point a share s of its light
carries about s of its noise, so k lamps lighting it alike add up to the noise one lamp has with ``samples`` rays.
(Drawing the ``samples`` rays among the lamps instead, as the gathering hits do, deviation light-selection, left
lamps unsampled whose light a wall hides from part of the points: 2.7x the noise per point for 0.7x the rays on
lamps scattered over a floor with a wall across it.) Hard lamps keep their one exact ray each; suns, emissive
triangles and the world are sampled as before.
"""
from __future__ import annotations

import numpy as np

from .constants import BUDGET_LAMPS, BUDGET_SCALE
from .lamp_weights import lamp_probabilities
from .lights import AreaLight, PointLight, SpotLight


def soft_lamp(emitter) -> bool:
    """Whether ``emitter`` is a lamp whose shadow is soft: an area light, or a point or spot light with a radius."""
    if isinstance(emitter, AreaLight):
        return True
    return isinstance(emitter, (PointLight, SpotLight)) and float(emitter.radius) > 0.0


def budgeted_lamps(emitters: tuple, samples: int) -> tuple[tuple, tuple]:
    """(soft lamps that share the budget, the other emitters): the soft lamps that emit when there are
    BUDGET_LAMPS or more and a point takes more than one sample; else ((), ``emitters``)."""
    lamps = tuple(e for e in emitters if soft_lamp(e) and e.emits())
    if samples <= 1 or len(lamps) < BUDGET_LAMPS:
        return (), tuple(emitters)
    shared = {id(lamp) for lamp in lamps}
    return lamps, tuple(e for e in emitters if id(e) not in shared)


def sample_counts(lamps: tuple, p: np.ndarray, n: np.ndarray, samples: int) -> np.ndarray:
    """(K, m) int64: each of K lamps' shadow rays at points p (m, 3) facing unit n (m, 3): the smallest power of
    two not below BUDGET_SCALE x ``samples`` x its share there, at least 1 and at most ``samples``."""
    levels = _levels(samples)
    want = BUDGET_SCALE * samples * lamp_probabilities(lamps, p, n)
    return levels[np.minimum(np.searchsorted(levels, want, side="left"), len(levels) - 1)]


def _levels(samples: int) -> np.ndarray:
    """The counts a lamp may get: 1, 2, 4, ... below ``samples``, and ``samples``."""
    powers = 1 << np.arange(max(int(samples).bit_length(), 1), dtype=np.int64)
    return np.unique(np.append(powers[powers < samples], samples))
