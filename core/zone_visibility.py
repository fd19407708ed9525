"""Zone visibility: photons of a zone sector the record cannot see lend no virtual ray (pass 3).

deviation: zone-visibility, docs/DEVIATIONS.md (switch ``Deviations.zone_visibility``).

The paper assumes visibility barely changes across a zone of influence. It fails where a wall
separates the record from part of its zone (a record on the floor inside a box without a bottom,
beside a wall), and light leaks through. For each record the zone photons are split into
VISIBILITY_SECTORS azimuth sectors around n_k; one occlusion ray tests the farthest photon of
each sector, and a blocked sector's photons are dropped (their cells then cast real rays).
Cost: at most VISIBILITY_SECTORS rays per record, against hundreds of cells.
"""
from __future__ import annotations

import numpy as np

from .constants import VISIBILITY_LIFT, VISIBILITY_SECTORS


def zone_visibility(caster, photon_p: np.ndarray, photon_n: np.ndarray, p_k, n, t1, t2, rec, ph, B: int,
                    d: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, int]:
    """((m,) bool visible, rays cast) for m virtual rays (record ``rec``, photon ``ph``).

    photon_p, photon_n : (N, 3) photon positions and normals.
    p_k, n, t1, t2 : (B, 3) records and their frames.
    d, dist : (m, 3) offsets photon - record and their lengths (the caller has them).
    """
    if len(rec) == 0:
        return np.ones(0, bool), 0
    angle = np.arctan2(np.einsum("ij,ij->i", d, t2[rec]), np.einsum("ij,ij->i", d, t1[rec]))
    sector = rec * VISIBILITY_SECTORS + np.minimum(
        ((angle + np.pi) / (2 * np.pi) * VISIBILITY_SECTORS).astype(np.int64), VISIBILITY_SECTORS - 1)
    # The farthest photon of each sector, without sorting all of them.
    farthest = np.full(B * VISIBILITY_SECTORS, -1.0)
    np.maximum.at(farthest, sector, dist)
    candidates = np.flatnonzero((dist == farthest[sector]) & (dist > 0))
    _, first = np.unique(sector[candidates], return_index=True)
    probe = candidates[first]
    # Both ends lie on (nearly) the same surface: a segment a hair above it grazes it and float32
    # reports hits on the surface itself (measured: 60 % of sectors falsely blocked on a flat floor).
    # Lifting both ends by a fraction of the segment's length keeps it clear of its own surface
    # while any wall between them, which rises far higher, still blocks it.
    lift = (VISIBILITY_LIFT * dist[probe])[:, None]
    a_end = p_k[rec[probe]] + lift * n[rec[probe]]
    b_end = photon_p[ph[probe]] + lift * photon_n[ph[probe]]
    seen = caster.visible_between(a_end, None, b_end, None)
    blocked = np.zeros(B * VISIBILITY_SECTORS, bool)
    blocked[sector[probe[~seen]]] = True
    return ~blocked[sector], len(probe)
