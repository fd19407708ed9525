"""Direct light at gathering hits with one shadow ray among the scene's lamps (deviation: light-selection).

A gathering hit's direct light is one sample among the hundreds a record averages, so it need not be exact:
among a scene's point, spot and area lights each hit casts one shadow ray, toward a lamp drawn with probability
proportional to what that lamp would give it unoccluded, and divides by that probability (an unbiased
estimate of the sum over lamps), as Cycles' light tree draws one light per sample. A scene with 64 lamps would
otherwise cast 64 shadow rays per gathering hit (the occluded building with 64 lamps spread through it: 211 M of
the bake's 353 M rays, 8 M with the draw). Only scenes of SELECTION_LAMPS lamps or more draw: with fewer, the
rays cost about what the draw's own arithmetic does. The texels' own direct light, and the hit grid's cells
(read by many records, so their noise would not average), keep every lamp (core/direct.py).

The weight of a lamp of radius 0 is its exact unoccluded irradiance at the hit (P cos / (4 pi d^2), times
the spot mask), so no lamp that lights the hit is left out. A lamp with a radius, and an area light (weighed
as a small one seen from its centre: L A cos cos_l / d^2, d^2 at least A), lights points its centre's weight
calls dark (the cone widened by its angular size, the horizon it rises above): a share SELECTION_DEFENSIVE of
each draw is spread evenly over such lamps, so each keeps a probability > 0. Suns, emissive triangles and the
world are sampled as before, every one.
"""
from __future__ import annotations

import numpy as np

from .constants import SELECTION_DEFENSIVE, SELECTION_LAMPS
from .direct import DirectResult, direct_irradiance
from .lights import AreaLight, PointLight, SpotLight, spot_attenuation
from .vectors import dots

SELECTION_CHUNK = 1 << 22
"""Lamp weights held at once (lamps x points): a chunk of points is drawn for at a time."""


def selectable_lamps(scene) -> tuple[tuple, tuple]:
    """(lamps drawn among, the other emitters): the point, spot and area lights that emit, when there are
    SELECTION_LAMPS or more; else nothing is drawn among, ((), every emitter)."""
    emitters = scene.emitters()
    lamps = tuple(e for e in emitters if isinstance(e, (PointLight, SpotLight, AreaLight)) and e.emits())
    if len(lamps) < SELECTION_LAMPS:
        return (), emitters
    drawn = {id(lamp) for lamp in lamps}
    return lamps, tuple(e for e in emitters if id(e) not in drawn)


def gathering_direct(scene, caster, p: np.ndarray, n: np.ndarray, rng: np.random.Generator, select: bool
                     ) -> DirectResult:
    """Direct irradiance at gathering hits p (h, 3) facing n (h, 3), one shadow sample per emitter, or with
    ``select`` one shadow ray among the lamps (:func:`selectable_lamps`): E and the rays cast."""
    lamps, others = selectable_lamps(scene) if select else ((), None)
    if not lamps:
        return direct_irradiance(scene, caster, p, n, n, 1, rng)
    out = direct_irradiance(scene, caster, p, n, n, 1, rng, emitters=others)
    step = max(1, SELECTION_CHUNK // len(lamps))
    for start in range(0, len(p), step):
        rows = slice(start, start + step)
        _add_selected(out.E[rows], out.shadow_rays, scene, caster, p[rows], n[rows], lamps, rng)
    return out


def _add_selected(E: np.ndarray, shadow_rays: dict, scene, caster, p, n, lamps, rng) -> None:
    """Draw one lamp per point p (m, 3), trace it, add its light over its probability to E (m, 3) (a view of the
    caller's) and its rays to ``shadow_rays``."""
    pdf = lamp_probabilities(lamps, p, n)
    cdf = np.cumsum(pdf, axis=0)
    u = rng.random(len(p)) * cdf[-1]
    # The first lamp whose cumulative probability passes u; points no lamp can light (cdf 0) draw none.
    pick = np.minimum((cdf <= u).sum(axis=0), len(lamps) - 1)
    pick[cdf[-1] <= 0] = -1
    for i, lamp in enumerate(lamps):
        mine = np.flatnonzero(pick == i)
        if len(mine) == 0:
            continue
        one = direct_irradiance(scene, caster, p[mine], n[mine], n[mine], 1, rng, emitters=(lamp,))
        E[mine] += one.E / pdf[i, mine][:, None]
        for kind, count in one.shadow_rays.items():
            shadow_rays[kind] += count


def lamp_probabilities(lamps, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K, m) the probability of drawing each of K lamps at points p (m, 3) facing unit n (m, 3); each column
    sums to 1, or is 0 where no lamp can light the point."""
    weight = np.stack([_unoccluded(lamp, p, n) for lamp in lamps])
    soft = np.array([isinstance(lamp, AreaLight) or float(lamp.radius) > 0 for lamp in lamps])
    total = weight.sum(axis=0)
    pdf = np.divide(weight, total, out=np.zeros_like(weight), where=total > 0)
    if soft.any():
        even = soft[:, None] / soft.sum()
        pdf = np.where(total > 0, (1.0 - SELECTION_DEFENSIVE) * pdf + SELECTION_DEFENSIVE * even, even)
    return pdf


def _unoccluded(lamp, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(m,) a lamp's unoccluded irradiance at p facing n, luminance-like (its channels' mean), from its centre:
    exact for radius 0, the draw's guide for a lamp with a radius or an area light."""
    delta = np.asarray(lamp.position, np.float64) - p
    d2 = dots(delta, delta)
    d = np.sqrt(d2)
    cos = np.divide(dots(n, delta), d, out=np.zeros_like(d), where=d > 0)
    if isinstance(lamp, AreaLight):  # one-sided: nothing behind its plane
        area = lamp.area
        if not (area > 0 and np.isfinite(area)):
            return np.zeros_like(d)
        normal = np.asarray(lamp.normal, np.float64)
        cos_l = np.divide(-dots(delta, np.broadcast_to(normal, delta.shape)), d * np.linalg.norm(normal),
                          out=np.zeros_like(d), where=d > 0)
        falloff = np.clip(cos, 0.0, None) * np.clip(cos_l, 0.0, None) / np.maximum(d2, area)
        return falloff * area * float(np.mean(lamp.radiance))
    weight = np.divide(np.clip(cos, 0.0, None), 4.0 * np.pi * d2, out=np.zeros_like(d), where=d2 > 0)
    if isinstance(lamp, SpotLight):
        w = np.divide(-delta, d[:, None], out=np.zeros_like(delta), where=d[:, None] > 0)
        weight *= spot_attenuation(lamp)(w)
    return weight * float(np.mean(lamp.power))
