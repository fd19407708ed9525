"""Nearest-photon fallback for gathering hits no record accepts (pass 3).

deviation: nearest-photon-fallback, docs/DEVIATIONS.md (switch
``Deviations.nearest_photon_fallback``; off: such hits get no indirect light).

The paper reads indirect light at a gathering ray's hit from the nearest photon ([Chr99]);
this bake interpolates pass 2's records there instead (they respect record walls) and falls
back to the nearest photon only where no record accepts the hit: pass 2's final neighbour clamp
shrinks zones after placement, walls and Ward's test leave gaps.
"""
from __future__ import annotations

import numpy as np

from .constants import FALLBACK_EMPTY_DISC, FALLBACK_SAME_SIDE_COS, HOLE_NEIGHBOURS, VISIBILITY_LIFT
from .density import PhotonDensity
from .photons import PhotonLighting
from .vectors import norms


class NearestPhotons:
    """kd-tree answers for a batch of points, each point asked at most once per query: its nearest
    photon and its k nearest. The hit grid asks for the same cell centroids on both sides of every
    triangle; a point's neighbours do not depend on the side."""

    def __init__(self, density: PhotonDensity, q: np.ndarray):
        self.density, self.q = density, q
        self.k = min(HOLE_NEIGHBOURS, len(density.p))
        self._tables = {}  # k -> (len(q), k) answers, -1 until asked: most batches of hits have no hole

    def nearest(self, rows: np.ndarray) -> np.ndarray:
        """(r,) int64 the nearest photon of each point ``rows`` (r,) indexes."""
        return self._answers(rows, 1)[:, 0]

    def k_nearest(self, rows: np.ndarray) -> np.ndarray:
        """(r, k) int64 the k nearest photons of each point ``rows`` indexes, nearest first."""
        return self._answers(rows, self.k)

    def expect_k(self, rows: np.ndarray):
        """Points ``rows`` (r,) distinct get their k nearest now, which answers their nearest too (the first
        column): one query where a point would ask for its nearest and then for its k nearest. A point asked
        on both sides of a surface is queried once."""
        if len(rows) and self.k > 1:
            near = self._answers(rows, self.k)
            table = self._tables.get(1)
            if table is None:
                table = self._tables[1] = np.full((len(self.q), 1), -1, np.int64)
            table[rows] = near[:, :1]

    def _answers(self, rows: np.ndarray, k: int) -> np.ndarray:
        """(r, k) the k nearest photons of points ``rows``, querying the tree for those not asked yet."""
        table = self._tables.get(k)
        if table is None:
            table = self._tables[k] = np.full((len(self.q), k), -1, np.int64)
        ask = np.unique(rows[table[rows, 0] < 0])
        if len(ask):
            _, found = self.density.tree.query(self.q[ask], k=k)
            table[ask] = np.asarray(found, np.int64).reshape(len(ask), k)
        return table[rows]


NOT_ASKED = -2
"""A fallback pick no one asked for yet (-1: asked, no photon on that side is seen; >= 0: the photon)."""


def photon_irradiance(lighting: PhotonLighting, pick: np.ndarray) -> np.ndarray:
    """(h, 3) float64 pass 2's indirect irradiance of photons ``pick`` (h,), 0 where pick < 0."""
    E = np.zeros((len(pick), 3))
    some = np.flatnonzero(pick >= 0)
    E[some] = lighting.E_indirect(pick[some])
    return E


def lent_irradiance(density: PhotonDensity, lighting: PhotonLighting, pick: np.ndarray, q: np.ndarray,
                    empty_disc: bool) -> np.ndarray:
    """(h, 3) float64 what the fallback lends hits q (h, 3): :func:`photon_irradiance` of ``pick`` (h,),
    with ``empty_disc`` (deviation: fallback-empty-disc) at most FALLBACK_EMPTY_DISC times the photon's
    power over pi d^2, d its distance from the hit.

    The photon is the nearest on the hit's side that the hit sees, so none landed nearer: an
    irradiance above the bound would rarely leave that disc empty. Its own E is pass 2's estimate
    where it landed, which may be lit where the hit is not: on Sponza's upper arches a moulding's
    underside (E/pi 0.01-0.05 by a path tracer) found its nearest photon up to 33 cm away on the
    edge's chamfer, lit from the atrium (E/pi 1.16).
    """
    E = photon_irradiance(lighting, pick)
    some = np.flatnonzero(pick >= 0)
    if not empty_disc or len(some) == 0:
        return E
    offset = np.take(density.p, pick[some], axis=0) - q[some]
    area = np.pi * np.einsum("ij,ij->i", offset, offset)
    power = np.take(density.power, pick[some], axis=0).astype(np.float64).mean(axis=1)
    level = E[some].mean(axis=1)
    # A photon at the hit itself (area 0) or no light lent (level 0) bounds nothing.
    over = (area > 0) & (level * area > FALLBACK_EMPTY_DISC * power)
    E[some[over]] *= (FALLBACK_EMPTY_DISC * power[over] / (area[over] * level[over]))[:, None]
    return E


def nearest_photon_seen(caster, density: PhotonDensity, q: np.ndarray, n: np.ndarray,
                        neighbours: NearestPhotons | None = None, rows: np.ndarray | None = None
                        ) -> tuple[np.ndarray, int]:
    """(pick (h,) int64, rays cast): the nearest photon on the side ``n`` faces that the hit sees, -1
    where none of the HOLE_NEIGHBOURS nearest is on that side and seen (its light:
    :func:`photon_irradiance`). q, n : (h, 3) hit points and unit normals facing the ray.

    One visibility ray (both ends lifted as in :mod:`core.zone_visibility`) keeps a photon
    behind a thin wall from lending its light (tests/test_stability.py). Each point's pick depends
    on that point alone (not on the records or the photons' lighting), so a later lookup at the
    same points may reuse it. neighbours, rows : the kd-tree answers to reuse and which of its
    points q are (h,); by default the points' own.
    """
    out = np.full(len(q), -1, np.int64)
    if len(q) == 0 or len(density.p) == 0:
        return out, 0
    if neighbours is None:
        neighbours, rows = NearestPhotons(density, q), np.arange(len(q))
    # Most go on to the k nearest: at Sponza 16/m 3.2 M of the 4.4 M points asked have their nearest photon on
    # the wrong side, and half of the rest do not see it. So all ask for the k nearest at once, whose first
    # answers the nearest (1.38 us a point, against a nearest query's 0.76 us and then, for most, the k
    # nearest); where two photons lie at exactly the same distance the two queries may order them otherwise.
    neighbours.expect_k(rows)
    pick = _nearest_on_side(density, neighbours, rows, n)
    found = np.flatnonzero(pick >= 0)
    seen = _sees(caster, density, q[found], n[found], pick[found])
    out[found[seen]] = pick[found[seen]]
    # The nearest photon on the hit's side is often just round a corner (a column's flank, a
    # moulding's lip): at Sponza 16/m 1.0 M of the 2.0 M points with one do not see it. The nearest of the k
    # nearest that agree and are seen lends its light instead. (Hits with no agreeing photon among
    # the k have nothing more to try.)
    hidden = found[~seen]
    out[hidden], more = _nearest_seen(caster, density, q[hidden], n[hidden], neighbours.k_nearest(rows[hidden]),
                                      pick[hidden])
    return out, len(found) + more


def _sees(caster, density: PhotonDensity, q: np.ndarray, n: np.ndarray, photon: np.ndarray) -> np.ndarray:
    """(h,) bool: does each hit see its photon? Both ends lifted as in :mod:`core.zone_visibility`."""
    p_ph, n_ph = np.take(density.p, photon, axis=0), np.take(density.n, photon, axis=0).astype(np.float64)
    lift = VISIBILITY_LIFT * norms(p_ph - q)[:, None]
    start, segment = q + lift * n, p_ph + lift * n_ph - (q + lift * n)
    dist = norms(segment)
    directions = np.divide(segment, dist[:, None], out=np.zeros_like(segment), where=dist[:, None] > 0)
    # An epsilon past the lifted photon, not short of it: a photon on the edge where its face meets
    # another (the inside of a closed box's bottom at its side) is lifted onto that other face, which
    # must hide it from a floor point outside the box.
    return (dist > 0) & ~caster.occluded(start, directions, dist + caster.epsilon, unit=True)


def _nearest_seen(caster, density: PhotonDensity, q: np.ndarray, n: np.ndarray, near: np.ndarray,
                  hidden: np.ndarray) -> tuple[np.ndarray, int]:
    """(pick (h,) int64, rays): the nearest of the k nearest photons ``near`` (h, k) that agree with n
    and are seen from q (-1 where none is); one visibility ray per agreeing candidate other than
    ``hidden`` (h,), the photon each hit already failed to see."""
    pick = np.full(len(q), -1, np.int64)
    if len(q) == 0:
        return pick, 0
    agree = np.einsum("hkj,hj->hk", np.take(density.n, near, axis=0).astype(np.float64), n) > FALLBACK_SAME_SIDE_COS
    agree &= near != hidden[:, None]
    row, col = np.nonzero(agree)
    seen = np.zeros_like(agree)
    seen[row, col] = _sees(caster, density, q[row], n[row], near[row, col])
    has = np.flatnonzero(seen.any(axis=1))
    pick[has] = near[has, np.argmax(seen, axis=1)[has]]
    return pick, len(row)


def _nearest_on_side(density: PhotonDensity, neighbours: NearestPhotons, rows: np.ndarray, n: np.ndarray
                     ) -> np.ndarray:
    """(h,) int64 the nearest of the k nearest photons of points ``rows`` whose normal agrees with n, -1
    if none does.

    The points the fallback asks about lie where no record accepts them, often on a surface's other side than
    the photons round them: at Sponza 16/m 3.2 M of 4.4 M have their nearest photon on the wrong side.
    """
    pick = neighbours.nearest(rows).copy()
    n_pick = np.take(density.n, pick, axis=0).astype(np.float64)
    wrong = np.flatnonzero(np.einsum("hj,hj->h", n_pick, n) <= FALLBACK_SAME_SIDE_COS)
    if len(wrong) and neighbours.k > 1:
        near = neighbours.k_nearest(rows[wrong])
        n_near = np.take(density.n, near, axis=0).astype(np.float64)
        same = np.einsum("hkj,hj->hk", n_near, n[wrong]) > FALLBACK_SAME_SIDE_COS
        pick[wrong] = np.where(same.any(axis=1), near[np.arange(len(wrong)), np.argmax(same, axis=1)], -1)
    else:
        pick[wrong] = -1
    return pick
