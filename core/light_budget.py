"""Soft lamps share one budget of shadow rays per point (deviation: light-budget).

A soft lamp (an area light, a point or spot light with a radius) takes ``samples`` stratified shadow rays per
point for its soft shadow (``BakeSettings.direct_samples``, 16 at Final), so a room lit by 16 ceiling panels cast
256 rays per texel sample, and 64 lamps of Blender's default radius 1,024, each lamp's light known far better than
its share of the point's light needs. In a scene of BUDGET_LAMPS soft lamps or more, each point spends about
BUDGET_SCALE x ``samples`` rays over them together: a lamp gets the smallest power of two not below BUDGET_SCALE x
``samples`` times its share of what the lamps would give the point unoccluded
(:func:`~core.lamp_weights.lamp_probabilities`), at least one and at most ``samples`` (a lamp giving a
1 / BUDGET_SCALE share or more keeps all its rays). Every lamp a point may see keeps its own stratified estimate,
so E stays unbiased whatever the shares; a lamp giving the point a share s of its light carries about s of its
noise, so k lamps lighting it alike add up to the noise one lamp has with BUDGET_SCALE x ``samples`` rays.
(Drawing the ``samples`` rays among the lamps instead, as the gathering hits do, deviation light-selection, left
lamps unsampled whose light a wall hides from part of the points: 2.7x the noise per point for 0.7x the rays on
lamps scattered over a floor with a wall across it.) Where a point takes one ray per lamp (the points of an edge
texel's footprint, :mod:`core.direct_footprint`), lamps giving it DRAWN_SHARE of the light or more keep their ray
and the others share one, drawn among them (:func:`drawn_lamps`), the texel's points drawing by evenly spaced
numbers (:func:`group_draws`). Hard lamps keep their one exact ray each; suns, emissive triangles and the world
are sampled as before.
"""
from __future__ import annotations

import numpy as np

from .constants import BUDGET_LAMPS, BUDGET_SCALE, DRAWN_SHARE
from .lamp_weights import lamp_probabilities, soft_lamp, split_lamps


def budgeted_lamps(emitters: tuple, samples: int, drawn: bool = False) -> tuple[tuple, tuple]:
    """(soft lamps that share the budget, the other emitters): the soft lamps that emit when there are
    BUDGET_LAMPS or more and a point takes more than one sample, or one drawn among them (``drawn``,
    :func:`group_draws`); else ((), ``emitters``)."""
    if samples <= 1 and not drawn:
        return (), tuple(emitters)
    return split_lamps(emitters, soft_lamp, BUDGET_LAMPS)


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


def group_draws(group: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n,) numbers in [0, 1) by which points of the same group (n,) int (a texel's footprint points) each draw
    one soft lamp: a group of k points takes k evenly spaced draws, (r + jitter) / k with one jitter per group,
    handed to its points in a random order. Each point's number is uniform, so its draw is unbiased; a group's
    draws follow the lamps' shares to within one draw, so a lamp with share s among k points is sampled at
    about s k of them, spread over the footprint, and a texel its edge crosses integrates it as one lamp alone
    would with that many points."""
    n = len(group)
    order = np.lexsort((rng.random(n), group))  # by group, in a random order within each
    sorted_group = group[order]
    start = np.flatnonzero(np.r_[True, sorted_group[1:] != sorted_group[:-1]])
    size = np.diff(np.r_[start, n])
    first = np.repeat(start, size)
    rank = np.arange(n) - first
    jitter = np.repeat(rng.random(len(start)), size)
    u = np.empty(n)
    u[order] = (rank + jitter) / np.repeat(size, size)
    return u


def drawn_lamps(lamps: tuple, p: np.ndarray, n: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(K, m) weights: each of K soft lamps' factor at points p (m, 3) facing unit n (m, 3), 0 where it casts no
    ray. A lamp giving a point a share of DRAWN_SHARE or more of the lamps' light casts its ray there, factor 1;
    the others share one ray, toward the lamp the point's number u (m,) in [0, 1) draws among them by their
    shares, factor 1 / its probability among them."""
    pdf = lamp_probabilities(lamps, p, n)
    big = pdf >= DRAWN_SHARE
    small = np.where(big, 0.0, pdf)
    cdf = np.cumsum(small, axis=0)
    total = cdf[-1]
    pick = np.minimum((cdf <= u * total).sum(axis=0), len(lamps) - 1)
    weights = big.astype(np.float64)
    drawn = np.flatnonzero(total > 0)
    weights[pick[drawn], drawn] = total[drawn] / small[pick[drawn], drawn]
    return weights
