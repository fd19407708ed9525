"""What each lamp would give a point unoccluded: the guide by which lamps are drawn or share shadow rays.

Read by the gathering hits' lamp draw (deviation: light-selection, :mod:`core.light_selection`) and by the
texels' shadow-ray budget among soft lamps (deviation: light-budget, :mod:`core.light_budget`).
"""
from __future__ import annotations

import numpy as np

from .constants import SELECTION_DEFENSIVE
from .lights import AreaLight, PointLight, SpotLight, spot_attenuation
from .vectors import dots

WEIGHT_CHUNK = 1 << 22
"""Lamp weights held at once (lamps x points): a chunk of points is weighed at a time."""


def weight_chunks(points: int, lamps: int):
    """Slices of ``points`` points whose weights toward ``lamps`` lamps stay within WEIGHT_CHUNK values."""
    step = max(1, WEIGHT_CHUNK // max(lamps, 1))
    for start in range(0, points, step):
        yield slice(start, min(start + step, points))


def split_lamps(emitters, is_lamp, minimum: int) -> tuple[tuple, tuple]:
    """(the emitting lamps ``is_lamp`` picks, the other emitters) when there are ``minimum`` such lamps or more;
    else ((), every emitter). The light draw and the light budget each split a scene's emitters so."""
    lamps = tuple(e for e in emitters if is_lamp(e) and e.emits())
    if len(lamps) < minimum:
        return (), tuple(emitters)
    taken = {id(lamp) for lamp in lamps}
    return lamps, tuple(e for e in emitters if id(e) not in taken)


def soft_lamp(lamp) -> bool:
    """Whether ``lamp`` has a soft shadow: an area light, or a point or spot light with a radius."""
    if isinstance(lamp, AreaLight):
        return True
    return isinstance(lamp, (PointLight, SpotLight)) and float(lamp.radius) > 0.0


def lamp_probabilities(lamps, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K, m) the probability of drawing each of K lamps at points p (m, 3) facing unit n (m, 3); each column
    sums to 1, or is 0 where no lamp can light the point."""
    weight = np.stack([unoccluded(lamp, p, n) for lamp in lamps])
    soft = np.array([soft_lamp(lamp) for lamp in lamps])
    total = weight.sum(axis=0)
    pdf = np.divide(weight, total, out=np.zeros_like(weight), where=total > 0)
    if soft.any():
        even = soft[:, None] / soft.sum()
        pdf = np.where(total > 0, (1.0 - SELECTION_DEFENSIVE) * pdf + SELECTION_DEFENSIVE * even, even)
    return pdf


def unoccluded(lamp, p: np.ndarray, n: np.ndarray) -> np.ndarray:
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
