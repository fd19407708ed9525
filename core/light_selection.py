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

from .constants import SELECTION_LAMPS
from .direct import DirectResult, direct_irradiance
from .lamp_weights import lamp_probabilities, split_lamps, weight_chunks
from .lights import AreaLight, PointLight, SpotLight


LAMP_TYPES = (PointLight, SpotLight, AreaLight)
"""The emitters a gathering hit draws among: lamps, not suns, emissive triangles or the world."""


def selectable_lamps(scene) -> tuple[tuple, tuple]:
    """(lamps drawn among, the other emitters): the point, spot and area lights that emit, when there are
    SELECTION_LAMPS or more; else nothing is drawn among, ((), every emitter)."""
    return split_lamps(scene.emitters(), lambda e: isinstance(e, LAMP_TYPES), SELECTION_LAMPS)


def gathering_direct(scene, caster, p: np.ndarray, n: np.ndarray, rng: np.random.Generator, select: bool
                     ) -> DirectResult:
    """Direct irradiance at gathering hits p (h, 3) facing n (h, 3), one shadow sample per emitter, or with
    ``select`` one shadow ray among the lamps (:func:`selectable_lamps`): E and the rays cast."""
    lamps, others = selectable_lamps(scene) if select else ((), None)
    if not lamps:
        return direct_irradiance(scene, caster, p, n, n, 1, rng)
    out = direct_irradiance(scene, caster, p, n, n, 1, rng, emitters=others)
    for rows in weight_chunks(len(p), len(lamps)):
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
